"""Write BGR frames to an H.264 mp4 with PyAV, atomically.

:class:`H264Writer` encodes into a hidden temporary file next to the target
(``.<name>.partial.mp4``) and renames it into place only when :meth:`H264Writer.close` finishes
cleanly. When the ``with`` block raises, the partial file is deleted, so a crashed run leaves no
half-written video behind (and an older file at the target path is left untouched).

The encoder is ``libx264`` where PyAV's FFmpeg has it, otherwise whatever FFmpeg offers for H.264
(``h264``, then ``libopenh264``). Frames are converted BGR → YUV 4:2:0 (BT.601, limited range, as
tagged in the stream) with OpenCV, which is cheaper than FFmpeg's swscale; odd sizes are padded by
one replicated row/column to even, as 4:2:0 requires.
"""

from __future__ import annotations

import contextlib
import os
from fractions import Fraction
from pathlib import Path
from types import TracebackType

import av
import cv2
import numpy as np

from makeway.sense.video import pick_h264_encoder

#: The default x264 preset: the video pipeline must run at 2× real time (20 ms per 25 fps frame for
#: everything), and only ``ultrafast`` encodes a 720p frame fast enough on 2 cores (preset timings:
#: docs/journal.md, "Video pipeline").
DEFAULT_PRESET = "ultrafast"

#: Extra x264 options applied on top of the preset (``None``: the preset as it is). Turning CABAC and
#: the deblocking filter back on (``"cabac=1:deblock=0,0"``) makes smaller files but costs CPU per
#: frame that the video pipeline's 2× real-time budget cannot spare while detection shares the cores
#: (docs/journal.md, "Video pipeline"); pass it when size matters more.
DEFAULT_X264_PARAMS: str | None = None


def default_encoder_threads() -> int:
    """Encoder threads: the CPU count, at most 8 (x264 gains little beyond that at 720p)."""
    return max(1, min(os.cpu_count() or 1, 8))


def partial_path_for(path: Path) -> Path:
    """The temporary file :class:`H264Writer` writes before renaming to ``path``."""
    return path.with_name(f".{path.name}.partial.mp4")


def _frame_rate(fps: float) -> Fraction:
    """``fps`` as a fraction, exact for NTSC rates (29.97 → 30000/1001)."""
    rate = Fraction(fps).limit_denominator(1001)
    if rate <= 0:
        raise ValueError(f"fps must be > 0, got {fps!r}")
    return rate


class H264Writer:
    """Encode BGR ``uint8`` frames of one size into an H.264 mp4; a context manager.

    Args:
        path: the mp4 to write (its folder is created if needed).
        fps: frame rate; stored as a fraction (29.97… becomes 30000/1001).
        width, height: size of the frames passed to :meth:`write`. Odd sizes are padded to even,
            so the file is then one pixel wider/taller.
        crf: x264 constant rate factor (lower = better quality, bigger file; 18–28 is sensible).
        preset: x264 speed preset (``ultrafast`` … ``veryslow``); see :data:`DEFAULT_PRESET`.
        threads: encoder threads (default :func:`default_encoder_threads`; 0 lets x264 choose).
        x264_params: ``key=value:key=value`` options passed to libx264 after the preset
            (:data:`DEFAULT_X264_PARAMS`); ``None`` for none. Ignored by other encoders.

    Attributes:
        encoder: the FFmpeg encoder in use (``libx264`` normally).
        frames_written: frames passed to :meth:`write` so far.
    """

    def __init__(
        self,
        path: str | Path,
        fps: float,
        width: int,
        height: int,
        *,
        crf: int = 23,
        preset: str = DEFAULT_PRESET,
        threads: int | None = None,
        x264_params: str | None = DEFAULT_X264_PARAMS,
    ) -> None:
        if int(width) < 1 or int(height) < 1:
            raise ValueError(f"width and height must be >= 1, got {width}x{height}")
        self.path = Path(path)
        self.width = int(width)
        self.height = int(height)
        self.enc_width = self.width + (self.width % 2)
        self.enc_height = self.height + (self.height % 2)
        self.rate = _frame_rate(float(fps))
        self.fps = float(self.rate)
        self.encoder = pick_h264_encoder()
        self.frames_written = 0
        self.partial_path = partial_path_for(self.path)
        self._closed = False

        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._container = av.open(str(self.partial_path), mode="w", format="mp4")
        try:
            stream = self._container.add_stream(self.encoder, rate=self.rate)
            if not isinstance(stream, av.VideoStream):  # pragma: no cover - an H.264 encoder is video
                raise RuntimeError(f"{self.encoder} did not give a video stream")
            stream.width = self.enc_width
            stream.height = self.enc_height
            stream.pix_fmt = "yuv420p"
            ctx = stream.codec_context
            ctx.thread_type = "AUTO"
            ctx.thread_count = default_encoder_threads() if threads is None else max(0, int(threads))
            # What cv2's BGR→I420 conversion produces: BT.601 matrix, limited (TV) range.
            with contextlib.suppress(Exception):
                ctx.colorspace = 6  # AVCOL_SPC_SMPTE170M
                ctx.color_primaries = 6
                ctx.color_trc = 6
                ctx.color_range = 1  # AVCOL_RANGE_MPEG
            if self.encoder == "libx264":
                options: dict[str, object] = {"crf": str(int(crf)), "preset": str(preset)}
                if x264_params:
                    options["x264-params"] = x264_params
                stream.options = options
            else:
                # Encoders without CRF: a bit rate about what CRF 23 gives for street footage.
                stream.bit_rate = int(0.1 * self.enc_width * self.enc_height * self.fps)
            self._stream = stream
            # Open the encoder now, so that a bad preset or option fails here and not mid-run.
            self._container.start_encoding()
        except BaseException:
            self._discard()
            raise

    # ------------------------------------------------------------------------------------- writing

    def write(self, frame_bgr: np.ndarray) -> None:
        """Encode one ``height × width × 3`` BGR ``uint8`` frame.

        Raises:
            ValueError: wrong shape or dtype, or the writer is closed.
        """
        if self._closed:
            raise ValueError(f"{self.path}: writer is closed")
        expected = (self.height, self.width, 3)
        if frame_bgr.shape != expected or frame_bgr.dtype != np.uint8:
            raise ValueError(
                f"{self.path}: frame must be uint8 {expected}, got {frame_bgr.dtype} {frame_bgr.shape}"
            )
        if self.enc_width != self.width or self.enc_height != self.height:
            frame_bgr = cv2.copyMakeBorder(
                frame_bgr,
                0,
                self.enc_height - self.height,
                0,
                self.enc_width - self.width,
                cv2.BORDER_REPLICATE,
            )
        i420 = np.ascontiguousarray(cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2YUV_I420), dtype=np.uint8)
        frame = av.VideoFrame.from_ndarray(i420, format="yuv420p")
        frame.pts = self.frames_written
        frame.time_base = 1 / self.rate
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self.frames_written += 1

    # ---------------------------------------------------------------------------------- life cycle

    def close(self) -> None:
        """Flush the encoder, finish the file and rename it into place; safe to call twice."""
        if self._closed:
            return
        self._closed = True
        try:
            for packet in self._stream.encode(None):
                self._container.mux(packet)
            self._container.close()
        except BaseException:
            self._discard()
            raise
        os.replace(self.partial_path, self.path)

    def abort(self) -> None:
        """Stop without producing a file: the partial file is deleted."""
        if self._closed:
            return
        self._closed = True
        self._discard()

    def _discard(self) -> None:
        with contextlib.suppress(Exception):
            self._container.close()
        with contextlib.suppress(FileNotFoundError):
            self.partial_path.unlink()

    def __enter__(self) -> H264Writer:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def __repr__(self) -> str:
        return (
            f"H264Writer({str(self.path)!r}, {self.width}x{self.height} @ {self.rate} fps, "
            f"encoder={self.encoder}, frames={self.frames_written})"
        )
