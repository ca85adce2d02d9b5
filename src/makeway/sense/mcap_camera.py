"""The direct path for camera topics in indexed MCAP files: chunks are read by their index and
image messages parsed in place, so a raw frame costs one decompression and no copy (issue 28).

What a camera frame costs through the general ``mcap`` reader: the chunk is decompressed, every
record in it is copied out of a ``BytesIO`` into its own ``bytes``, the CDR deserializer builds
the whole message, and the pixels are copied once more into the image. :class:`McapCameraIndex`
does the least the file format allows instead:

* only the chunks that hold the topic are read, found through the summary's chunk indexes; the
  topic's messages in them, with their log times and offsets, come from the chunk's message index
  records (so a strided read skips whole chunks, and the messages come out in log-time order
  exactly as the ``mcap`` reader orders them: by log time, then chunk, then position);
* a chunk is decompressed once, into a fresh numpy buffer of the size its record states
  (``zstandard``: one reused ``ZstdDecompressor`` reading into the buffer; ``lz4``: a
  ``bytearray``; uncompressed chunks are read from the file straight into the buffer);
* the message is parsed in place: the ROS 2 ``sensor_msgs/msg/Image`` and ``CompressedImage``
  CDR layout (OMG CDR, little- or big-endian encapsulation, the alignment rules of the ROS 2 RMW
  serialization: each primitive aligned to its size, counted from the end of the 4-byte
  encapsulation header) and the Foxglove ``RawImage`` / ``CompressedImage`` protobuf wire format
  (field numbers from the schema's own ``FileDescriptorSet``); the image bytes are a numpy view
  of the decompressed chunk;
* :meth:`McapCameraIndex.stamps` decompresses only the head of each chunk, up to the stamp.

A message this parser does not take (another CDR encapsulation, an unexpected layout) is decoded
with the general decoder the caller passes in, so the output never depends on which path read
it. A chunk that does not decompress to its stated size, or whose records do not match its index,
is an :class:`~makeway.errors.InputError` naming the log. Chunk CRCs are not checked (nor does the
``mcap`` reader by default): a CRC-32 over a 2.7 MB raw frame costs about a third of its zstd
decompression.

References: the MCAP format specification (https://mcap.dev/spec: the Chunk, Chunk Index, Message
Index and Message records); OMG Common Data Representation (DDS-XTypes 1.3, §7.4.3, plain CDR
version 1, the encoding of ROS 2's RMW); the protobuf wire format
(https://protobuf.dev/programming-guides/encoding/).
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from io import BufferedReader
from pathlib import Path
from typing import Any

import numpy as np

from makeway.errors import InputError

__all__ = ["ImageMessage", "McapCameraIndex", "camera_index", "parse_ros_image", "ros_stamp"]

_OP_MESSAGE_INDEX = 0x07
_OP_CHUNK = 0x06
_OP_MESSAGE = 0x05
_RECORD_HEAD = 9  # opcode (1) + record length (8)
_MESSAGE_HEAD = 22  # channel id (2) + sequence (4) + log time (8) + publish time (8)
_ROS_SCHEMAS = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
_FOXGLOVE_SCHEMAS = ("foxglove.RawImage", "foxglove.CompressedImage")
_MAX_RECORDS = 4 * 2**30  # the mcap reader's limit on a record's size (bytes)
_INDEX_DTYPE = np.dtype([("log_time", "<u8"), ("offset", "<u8")])


@dataclass
class ImageMessage:
    """The fields of a camera message an image is made from (ROS 2 or Foxglove, raw or
    compressed): ``stamp_ns`` the message's own stamp (0: none), ``format`` of a compressed image
    (``""`` for raw), ``encoding``, ``height``, ``width``, ``step`` (bytes per row) of a raw one,
    and ``data`` the image bytes as a uint8 view of the decompressed chunk."""

    stamp_ns: int
    format: str
    encoding: str
    height: int
    width: int
    step: int
    data: np.ndarray


class _NotParsedError(Exception):
    """The in-place parser does not take this message; the general decoder reads it."""


# ------------------------------------------------------------------------------------ ROS 2 CDR


def _cdr(buf: np.ndarray, compressed: bool) -> ImageMessage:
    """Parse a ROS 2 ``sensor_msgs/msg/Image`` (``compressed=False``) or ``CompressedImage``."""
    n = buf.shape[0]
    if n < 16 or buf[0] != 0:
        raise _NotParsedError
    kind = int(buf[1])
    if kind == 1:
        end = "<"
    elif kind == 0:
        end = ">"
    else:  # parameter lists, XCDR2: the general decoder
        raise _NotParsedError
    u32 = struct.Struct(end + "I")

    def align4(p: int) -> int:
        return p + (-(p - 4) & 3)

    def string(p: int) -> tuple[str, int]:
        p = align4(p)
        (size,) = u32.unpack_from(buf.data, p)
        p += 4
        if p + size > n:
            raise _NotParsedError
        text = bytes(buf[p : p + size]).split(b"\0", 1)[0].decode("utf-8", "replace")
        return text, p + size

    try:
        sec, nanosec = struct.unpack_from(end + "iI", buf.data, 4)
        _, p = string(12)  # header.frame_id
        fmt = encoding = ""
        height = width = step = 0
        if compressed:
            fmt, p = string(p)
        else:
            p = align4(p)
            height, width = struct.unpack_from(end + "II", buf.data, p)
            encoding, p = string(p + 8)
            p += 1  # is_bigendian (uint8: the 8-bit encodings read here have no byte order)
            p = align4(p)
            (step,) = u32.unpack_from(buf.data, p)
            p += 4
        p = align4(p)
        (size,) = u32.unpack_from(buf.data, p)
        p += 4
    except struct.error:
        raise _NotParsedError from None
    if p + size > n:
        raise _NotParsedError
    return ImageMessage(sec * 1_000_000_000 + nanosec, fmt, encoding, height, width, step, buf[p : p + size])


def _cdr_stamp(head: np.ndarray) -> int:
    """The header stamp (ns) of a ROS 2 message from its first 12 bytes."""
    if head.shape[0] < 12 or head[0] != 0 or head[1] not in (0, 1):
        raise _NotParsedError
    sec, nanosec = struct.unpack_from("<iI" if head[1] == 1 else ">iI", head.data, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)


def parse_ros_image(data: bytes | np.ndarray, compressed: bool) -> ImageMessage | None:
    """A ROS 2 ``sensor_msgs/msg/CompressedImage`` (``compressed=True``) or ``Image`` message's CDR
    bytes parsed in place (the image bytes a view of ``data``); ``None`` where this parser does not
    take the message (the caller's general deserializer reads it)."""
    try:
        return _cdr(np.frombuffer(data, dtype=np.uint8), compressed)
    except _NotParsedError:
        return None


def ros_stamp(data: bytes | np.ndarray) -> int | None:
    """The header stamp (ns) of a ROS 2 message whose first field is a ``std_msgs/Header``, read
    from its CDR bytes; ``None`` where this parser does not take the message."""
    try:
        return _cdr_stamp(np.frombuffer(data, dtype=np.uint8))
    except _NotParsedError:
        return None


# ------------------------------------------------------------------------------ protobuf (Foxglove)


def _varint(buf: np.ndarray, p: int, n: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if p >= n or shift > 63:
            raise _NotParsedError
        b = int(buf[p])
        p += 1
        value |= (b & 0x7F) << shift
        if b < 0x80:
            return value, p
        shift += 7


def _protobuf_fields(buf: np.ndarray, stop: int | None = None) -> dict[int, Any]:
    """Top-level fields of a protobuf message: number → varint (int), fixed32/64 (int) or a
    length-delimited view (uint8 array); the last occurrence wins, as in protobuf. ``stop``: end
    once that field is read."""
    n = buf.shape[0]
    p = 0
    out: dict[int, Any] = {}
    while p < n:
        key, p = _varint(buf, p, n)
        number, wire = key >> 3, key & 7
        if wire == 0:
            out[number], p = _varint(buf, p, n)
        elif wire == 2:
            size, p = _varint(buf, p, n)
            if p + size > n:
                raise _NotParsedError
            out[number] = buf[p : p + size]
            p += size
        elif wire == 5:
            if p + 4 > n:
                raise _NotParsedError
            out[number] = struct.unpack_from("<I", buf.data, p)[0]
            p += 4
        elif wire == 1:
            if p + 8 > n:
                raise _NotParsedError
            out[number] = struct.unpack_from("<Q", buf.data, p)[0]
            p += 8
        else:  # groups: not in the Foxglove schemas
            raise _NotParsedError
        if number == stop:
            break
    return out


def _signed(value: int, bits: int) -> int:
    return value - (1 << bits) if value >= 1 << (bits - 1) else value


@dataclass(frozen=True)
class _ProtoLayout:
    """Field numbers of a Foxglove image message, read from its schema."""

    timestamp: int
    data: int
    format: int | None
    encoding: int | None
    width: int | None
    height: int | None
    step: int | None

    @classmethod
    def of(cls, schema_name: str, schema_data: bytes) -> _ProtoLayout | None:
        from google.protobuf import descriptor_pb2

        try:
            fds = descriptor_pb2.FileDescriptorSet.FromString(schema_data)
        except Exception:
            return None
        package, _, name = schema_name.rpartition(".")
        for fd in fds.file:
            if fd.package != package:
                continue
            for mt in fd.message_type:
                if mt.name == name:
                    num = {f.name: f.number for f in mt.field}
                    if "timestamp" not in num or "data" not in num:
                        return None
                    raw = name == "RawImage"
                    if raw and not all(k in num for k in ("encoding", "width", "height", "step")):
                        return None
                    if not raw and "format" not in num:
                        return None
                    return cls(
                        num["timestamp"],
                        num["data"],
                        num.get("format"),
                        num.get("encoding"),
                        num.get("width"),
                        num.get("height"),
                        num.get("step"),
                    )
        return None

    def stamp(self, fields: dict[int, Any]) -> int:
        ts = fields.get(self.timestamp)
        if ts is None:
            return 0
        if not isinstance(ts, np.ndarray):
            raise _NotParsedError
        sub = _protobuf_fields(ts)
        return _signed(int(sub.get(1, 0)), 64) * 1_000_000_000 + _signed(int(sub.get(2, 0)), 32)

    def parse(self, buf: np.ndarray) -> ImageMessage:
        f = _protobuf_fields(buf)

        def text(number: int | None) -> str:
            v = f.get(number) if number is not None else None
            if v is None:
                return ""
            if not isinstance(v, np.ndarray):
                raise _NotParsedError
            return bytes(v).decode("utf-8", "replace")

        def u32(number: int | None) -> int:
            v = f.get(number) if number is not None else None
            if isinstance(v, np.ndarray):
                raise _NotParsedError
            return int(v or 0) & 0xFFFFFFFF

        data = f.get(self.data, buf[:0])
        if not isinstance(data, np.ndarray):
            raise _NotParsedError
        return ImageMessage(
            self.stamp(f),
            text(self.format),
            text(self.encoding),
            u32(self.height),
            u32(self.width),
            u32(self.step),
            data,
        )


# --------------------------------------------------------------------------------------- chunks


class McapCameraIndex:
    """The messages of one camera topic of an indexed MCAP file, read chunk by chunk (use
    :func:`camera_index`, which says whether the file and topic allow it).

    ``entries`` holds, per message in log-time order, its log time (ns), the chunk it is in (an
    index into ``chunks``) and its offset in the chunk's decompressed records.
    """

    def __init__(
        self,
        path: Path,
        topic: str,
        file: BufferedReader,
        chunks: list[Any],
        entries: np.ndarray,
        channel_ids: set[int],
        parse: Callable[[np.ndarray], ImageMessage],
        stamp: Callable[[np.ndarray], int],
        fallback: Callable[[bytes], Any],
    ) -> None:
        self.path = path
        self.topic = topic
        self._file = file
        self.chunks = chunks
        self.entries = entries
        self._channel_ids = channel_ids
        self._parse = parse
        self._stamp = stamp
        self._fallback = fallback
        self._zstd: Any = None
        #: messages decoded by the general decoder because the in-place parser did not take them
        self.decoded_generally = 0

    def __len__(self) -> int:
        return int(self.entries.shape[0])

    def _damaged(self, chunk: Any, problem: str) -> InputError:
        return InputError(
            self.path, f"is truncated or damaged (chunk at byte {chunk.chunk_start_offset}: {problem})"
        )

    def _chunk_record(self, chunk: Any) -> tuple[np.ndarray, int, int, str]:
        """The chunk record's bytes as read from the file, where its records start, their stored
        length, and the compression."""
        raw = np.empty(int(chunk.chunk_length), dtype=np.uint8)
        self._file.seek(int(chunk.chunk_start_offset))
        if self._file.readinto(raw.data) != raw.shape[0]:
            raise self._damaged(chunk, "the file ends inside it")
        try:
            if raw[0] != _OP_CHUNK:
                raise self._damaged(chunk, "not a chunk record")
            (stated,) = struct.unpack_from("<Q", raw.data, _RECORD_HEAD + 16)
            if stated != chunk.uncompressed_size:
                raise self._damaged(
                    chunk, f"it states {stated} bytes of records, its index {chunk.uncompressed_size}"
                )
            (clen,) = struct.unpack_from("<I", raw.data, _RECORD_HEAD + 28)
            p = _RECORD_HEAD + 32
            compression = bytes(raw[p : p + clen]).decode("ascii")
            p += clen
            (size,) = struct.unpack_from("<Q", raw.data, p)
            p += 8
        except (struct.error, UnicodeDecodeError):
            raise self._damaged(chunk, "its header does not parse") from None
        if p + size > raw.shape[0]:
            raise self._damaged(chunk, "its records run past its end")
        return raw, p, int(size), compression

    def _decompressor(self) -> Any:
        if self._zstd is None:
            import zstandard

            self._zstd = zstandard.ZstdDecompressor()
        return self._zstd

    def records(self, chunk: Any) -> np.ndarray:
        """The chunk's records, decompressed: a uint8 array of its stated uncompressed size."""
        raw, p, size, compression = self._chunk_record(chunk)
        stored = raw[p : p + size]
        want = int(chunk.uncompressed_size)
        if compression == "":
            if size != want:
                raise self._damaged(chunk, f"{size} bytes of records where the index says {want}")
            return stored
        try:
            if compression == "zstd":
                out = np.empty(want, dtype=np.uint8)
                view = out.data
                got = 0
                with self._decompressor().stream_reader(stored, read_across_frames=True) as reader:
                    while got < want:
                        k = reader.readinto(view[got:])
                        if k <= 0:
                            break
                        got += k
                    extra = reader.read(1) if got == want else b""
                if got != want or extra:
                    raise self._damaged(chunk, f"decompresses to a size other than the stated {want} bytes")
                return out
            if compression == "lz4":
                import lz4.frame

                data = lz4.frame.decompress(stored, return_bytearray=True)
                if len(data) != want:
                    raise self._damaged(chunk, f"decompresses to {len(data)} bytes, not the stated {want}")
                return np.frombuffer(data, dtype=np.uint8)
        except InputError:
            raise
        except Exception as exc:
            text = str(exc).strip().splitlines()
            raise self._damaged(chunk, f"{compression}: {text[0] if text else type(exc).__name__}") from None
        raise self._damaged(chunk, f"unsupported compression {compression!r}")

    def _head(self, chunk: Any, length: int) -> np.ndarray:
        """The first ``length`` bytes of the chunk's decompressed records (fewer if it is shorter),
        decompressing no more than that."""
        raw, p, size, compression = self._chunk_record(chunk)
        stored = raw[p : p + size]
        if compression == "":
            return stored[:length]
        try:
            if compression == "zstd":
                with self._decompressor().stream_reader(stored, read_across_frames=True) as reader:
                    return np.frombuffer(reader.read(length), dtype=np.uint8)
            if compression == "lz4":
                import lz4.frame

                head = lz4.frame.LZ4FrameDecompressor().decompress(stored, max_length=length)
                return np.frombuffer(head, dtype=np.uint8)
        except Exception:
            pass
        return self.records(chunk)[:length]  # a damaged head: the full path says what is wrong

    def _message(
        self, chunk: Any, records: np.ndarray, offset: int, log_time: int, head: bool = False
    ) -> np.ndarray:
        """The payload of the message record at ``offset`` in the chunk's records, checked
        against the index (``head``: the records are only the chunk's head, the payload may be
        cut short)."""
        end = offset + _RECORD_HEAD + _MESSAGE_HEAD
        if end > records.shape[0] or records[offset] != _OP_MESSAGE:
            raise self._damaged(chunk, f"no message record at offset {offset} of its records")
        length, channel, _, t = struct.unpack_from("<QHIQ", records.data, offset + 1)
        stop = offset + _RECORD_HEAD + length
        if (
            channel not in self._channel_ids
            or t != log_time
            or length < _MESSAGE_HEAD
            or (stop > records.shape[0] and not head)
        ):
            raise self._damaged(chunk, f"the message at offset {offset} does not match the message index")
        return records[end:stop]

    def messages(self, select: Iterator[int] | None = None) -> Iterator[tuple[int, int, ImageMessage | Any]]:
        """``(entry index, log_time_ns, message)`` for the entries ``select`` yields (increasing;
        all: ``None``). ``message`` is an :class:`ImageMessage`, or what the general decoder made
        of a message the in-place parser does not take."""
        entries = self.entries
        wanted = list(select) if select is not None else list(range(len(self)))
        # a chunk is decompressed once and kept while messages of it are still to come (chunks
        # that overlap in time interleave their messages)
        left = np.bincount(entries[wanted, 1].astype(np.intp), minlength=len(self.chunks))
        held: dict[int, np.ndarray] = {}
        for k in wanted:
            log_time, c, offset = (int(v) for v in entries[k])
            records = held.get(c)
            if records is None:
                records = held[c] = self.records(self.chunks[c])
            left[c] -= 1
            if left[c] == 0:
                del held[c]
            payload = self._message(self.chunks[c], records, offset, log_time)
            try:
                msg: Any = self._parse(payload)
            except _NotParsedError:
                self.decoded_generally += 1
                try:
                    msg = self._fallback(payload.tobytes())
                except Exception as exc:
                    text = str(exc).strip().splitlines()
                    why = text[0] if text else type(exc).__name__
                    raise InputError(
                        self.path, f"message {k} on {self.topic} does not decode ({why})"
                    ) from None
            yield k, log_time, msg

    def stamps(self, limit: int | None = None) -> list[tuple[int, int | None]]:
        """``(log_time_ns, own stamp_ns or None)`` of the first ``limit`` messages (all: ``None``),
        decompressing each chunk only up to the stamp. ``None``: the stamp is not where the
        in-place parser looks; the caller decodes that message whole."""
        out: list[tuple[int, int | None]] = []
        n = len(self) if limit is None else min(limit, len(self))
        for k in range(n):
            log_time, c, offset = (int(v) for v in self.entries[k])
            chunk = self.chunks[c]
            head = self._head(chunk, offset + _RECORD_HEAD + _MESSAGE_HEAD + 256)
            try:
                payload = self._message(chunk, head, offset, log_time, head=True)
            except InputError:
                payload = self._message(chunk, self.records(chunk), offset, log_time)
            try:
                out.append((log_time, self._stamp(payload)))
            except _NotParsedError:
                out.append((log_time, None))
        return out


def _read_message_index(file: BufferedReader, offset: int, file_size: int) -> tuple[int, np.ndarray] | None:
    """The channel id and ``(log_time, offset)`` entries of the message index record at
    ``offset``; ``None`` if there is none."""
    if not 0 <= offset < file_size:
        return None
    file.seek(offset)
    head = file.read(_RECORD_HEAD + 6)
    if len(head) < _RECORD_HEAD + 6 or head[0] != _OP_MESSAGE_INDEX:
        return None
    channel, size = struct.unpack_from("<HI", head, _RECORD_HEAD)
    if size % _INDEX_DTYPE.itemsize:
        return None
    body = file.read(size)
    if len(body) != size:
        return None
    return channel, np.frombuffer(body, dtype=_INDEX_DTYPE)


def camera_index(
    path: Path,
    file: BufferedReader,
    summary: Any,
    topic: str,
    schema_name: str,
    fallback: Callable[[bytes], Any],
) -> McapCameraIndex | None:
    """The direct reader of the camera ``topic`` (schema ``schema_name``, as the log lists it), or
    ``None`` where the general reader must do: no summary or chunk indexes, a chunk without
    message indexes, a compression other than zstd, lz4 or none, a schema this parser does not
    take. ``fallback`` decodes one message's bytes the general way."""
    if summary is None or not summary.chunk_indexes:
        return None
    ids = {cid for cid, ch in summary.channels.items() if ch.topic == topic}
    if not ids:
        return None
    channels = [summary.channels[c] for c in ids]
    schemas = {ch.schema_id for ch in channels}
    encodings = {ch.message_encoding for ch in channels}
    if len(schemas) != 1 or len(encodings) != 1:
        return None
    schema = summary.schemas.get(schemas.pop())
    encoding = encodings.pop()
    parse: Callable[[np.ndarray], ImageMessage]
    stamp: Callable[[np.ndarray], int]
    if schema_name in _ROS_SCHEMAS and encoding == "cdr":
        compressed = schema_name.endswith("CompressedImage")

        def parse(buf: np.ndarray) -> ImageMessage:
            return _cdr(buf, compressed)

        stamp = _cdr_stamp
    elif schema_name in _FOXGLOVE_SCHEMAS and encoding == "protobuf" and schema is not None:
        layout = _ProtoLayout.of(schema.name, schema.data)
        if layout is None:
            return None
        parse = layout.parse

        def stamp(buf: np.ndarray) -> int:
            return layout.stamp(_protobuf_fields(buf, stop=layout.timestamp))

    else:
        return None
    file_size = os.fstat(file.fileno()).st_size
    chunks: list[Any] = []
    times: list[np.ndarray] = []
    offsets: list[np.ndarray] = []
    chunk_of: list[np.ndarray] = []
    for ci in summary.chunk_indexes:
        if not ci.message_index_offsets:
            return None  # topic membership unknown without message indexes
        mine = [ci.message_index_offsets[c] for c in ids if c in ci.message_index_offsets]
        if not mine:
            continue
        if ci.compression not in ("zstd", "lz4", ""):
            return None
        if (
            ci.chunk_length < _RECORD_HEAD + 40
            or ci.chunk_start_offset + ci.chunk_length > file_size
            or ci.uncompressed_size > _MAX_RECORDS
        ):
            return None  # an index that does not fit the file: the mcap reader reads the records
        for off in mine:
            read = _read_message_index(file, int(off), file_size)
            if read is None or read[0] not in ids:
                return None
            index = read[1]
            times.append(index["log_time"])
            offsets.append(index["offset"])
            chunk_of.append(np.full(index.shape[0], len(chunks), dtype=np.uint64))
        chunks.append(ci)
    if not chunks:
        entries = np.zeros((0, 3), dtype=np.uint64)
    else:
        t, c, o = np.concatenate(times), np.concatenate(chunk_of), np.concatenate(offsets)
        starts = np.array([ch.chunk_start_offset for ch in chunks], dtype=np.uint64)[c.astype(np.intp)]
        order = np.lexsort((o, starts, t))  # log time, then chunk position, then place in the chunk
        entries = np.stack([t[order], c[order], o[order]], axis=1)
    return McapCameraIndex(path, topic, file, chunks, entries, ids, parse, stamp, fallback)
