"""Read video files frame by frame (OpenCV's FFmpeg backend).

:class:`VideoReader` checks the file when it is built (exists, is a file, opens, and a first frame
decodes), so a caller learns about a bad input before it writes any output. Problems are raised as
:class:`~makeway.errors.InputError`, naming the file. Frames come out as ``(frame_index, time_s,
frame_bgr)`` where ``frame_index`` counts source frames from 0 (strided frames keep their source
index) and ``time_s = frame_index / fps``.

Example::

    with VideoReader("clip.mp4", stride=2, max_frames=100) as reader:
        print(reader.info)
        for index, time_s, frame in reader:
            ...
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import cv2
import numpy as np

from makeway.errors import InputError

#: The frame rate assumed when a file reports none (zero, negative or NaN).
DEFAULT_FPS = 25.0


@dataclass(frozen=True)
class VideoInfo:
    """What a video file says about itself.

    ``frame_count`` is the container's (sometimes estimated) number of frames, ``-1`` when unknown;
    ``duration_s`` is ``frame_count / fps``, ``-1.0`` when the count is unknown. ``fps_assumed`` is
    true when the file gave no usable frame rate and :data:`DEFAULT_FPS` was used instead.
    """

    path: Path
    width: int
    height: int
    fps: float
    frame_count: int
    duration_s: float
    fps_assumed: bool = False


def _open_capture(path: Path, threads: int | None = None) -> cv2.VideoCapture:
    # FFmpeg's own messages about damaged input ("moov atom not found", "Invalid NAL unit size" …)
    # would be printed around the one-line InputError; OpenCV reads this when it first opens a
    # file, and a user who wants them can set OPENCV_FFMPEG_LOGLEVEL (e.g. 16 = errors) themselves.
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    # Name the FFmpeg backend explicitly: other backends would read "%03d"-style names as image
    # sequences or open devices. OpenCV's "can't be used to capture by name" warning is muted too.
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    params = [] if threads is None else [cv2.CAP_PROP_N_THREADS, int(threads)]
    try:
        return cv2.VideoCapture(str(path), cv2.CAP_FFMPEG, params)
    finally:
        cv2.utils.logging.setLogLevel(level)


class VideoReader:
    """Iterate over the frames of a video file; a context manager.

    Args:
        path: the video file.
        stride: keep every ``stride``-th frame (source indices ``0, stride, 2·stride, …``); the
            frames in between are grabbed without colour conversion.
        max_frames: stop after yielding this many frames (``None``: read to the end).
        threads: decoder threads (``None``: FFmpeg's default, one per core). A process that owns
            one core — a data-engine worker — decodes on one thread, so that workers sharing a
            machine do not compete for each other's cores.

    Raises:
        InputError: the path is missing, is a folder, cannot be opened as a video, or its first
            frame does not decode.
        ValueError: ``stride < 1``, ``max_frames < 1`` or ``threads < 1``.

    Attributes:
        info: the :class:`VideoInfo` of the file.
        frames_read: source frames decoded in the latest pass (grabbed ones included). When decoding
            fails part-way, iteration stops quietly and this tells how far it got;
            :meth:`check_complete` turns a pass that ended well short of the container's count into
            an :class:`~makeway.errors.InputError`.
        frames_yielded: frames handed out in the latest pass.
        reached_end: the latest pass ran until the decoder gave no more frames (not stopped by
            ``max_frames`` or by the caller).
        last_time_s: the container's timestamp of the last frame decoded in the latest pass
            (seconds from the first frame).

    Each ``for`` loop over the reader starts again from the first frame (the file is reopened for a
    second pass); two loops over one reader at the same time are not supported.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        stride: int = 1,
        max_frames: int | None = None,
        threads: int | None = None,
    ) -> None:
        if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
            raise ValueError(f"stride must be an integer >= 1, got {stride!r}")
        if max_frames is not None and (
            isinstance(max_frames, bool) or not isinstance(max_frames, int) or max_frames < 1
        ):
            raise ValueError(f"max_frames must be an integer >= 1 or None, got {max_frames!r}")
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
            raise ValueError(f"threads must be an integer >= 1 or None, got {threads!r}")
        self.path = Path(path)
        self.threads = threads
        self.stride = stride
        self.max_frames = max_frames
        self.frames_read = 0
        self.frames_yielded = 0
        self.reached_end = False
        self.last_time_s = 0.0
        self._cap: cv2.VideoCapture | None = None
        self._first: np.ndarray | None = None
        self._closed = False

        if not self.path.exists():
            raise InputError(self.path, "no such file")
        if self.path.is_dir():
            raise InputError(self.path, "is a folder, expected a video file")
        if not self.path.is_file():
            raise InputError(self.path, "is not a regular file")

        cap = _open_capture(self.path, threads)
        if not cap.isOpened():
            cap.release()
            raise InputError(self.path, "cannot be opened as a video (not a video file, or damaged)")
        ok, first = cap.read()
        if not ok or first is None or first.ndim != 3 or first.shape[2] != 3 or first.size == 0:
            cap.release()
            raise InputError(self.path, "opens as a video but no frame decodes (truncated or damaged file)")

        height, width = int(first.shape[0]), int(first.shape[1])
        fps = float(cap.get(cv2.CAP_PROP_FPS))
        fps_assumed = not (math.isfinite(fps) and fps > 0.0)
        if fps_assumed:
            fps = DEFAULT_FPS
        raw_count = float(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        frame_count = int(round(raw_count)) if math.isfinite(raw_count) and raw_count > 0 else -1
        duration_s = frame_count / fps if frame_count > 0 else -1.0
        self.info = VideoInfo(
            path=self.path,
            width=width,
            height=height,
            fps=fps,
            frame_count=frame_count,
            duration_s=duration_s,
            fps_assumed=fps_assumed,
        )
        self._cap = cap
        self._first = first

    # ------------------------------------------------------------------------------------ iteration

    def __iter__(self) -> Iterator[tuple[int, float, np.ndarray]]:
        if self._closed:
            raise ValueError(f"{self.path}: reader is closed")
        cap, first = self._cap, self._first
        self._first = None
        if cap is None or first is None:
            # A later pass: the capture was used up, so open the file again from the start.
            if cap is not None:
                cap.release()
            cap = _open_capture(self.path, self.threads)
            self._cap = cap
            ok, first = cap.read() if cap.isOpened() else (False, None)
            if not ok:
                first = None
        return self._frames(cap, first)

    def _frames(
        self, cap: cv2.VideoCapture, first: np.ndarray | None
    ) -> Iterator[tuple[int, float, np.ndarray]]:
        self.frames_read = 0
        self.frames_yielded = 0
        self.reached_end = False
        self.last_time_s = 0.0
        if first is None:
            self.reached_end = True
            return
        fps, stride, limit = self.info.fps, self.stride, self.max_frames
        self.frames_read = 1
        self.frames_yielded = 1
        yield 0, 0.0, first
        index = 0
        while limit is None or self.frames_yielded < limit:
            for _ in range(stride - 1):
                if not cap.grab():
                    self.reached_end = True
                    return
                self.frames_read += 1
                self.last_time_s = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
            ok, frame = cap.read()
            if not ok or frame is None:
                self.reached_end = True
                return
            self.frames_read += 1
            self.last_time_s = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
            index += stride
            self.frames_yielded += 1
            yield index, index / fps, frame

    def check_complete(self) -> None:
        """Raise when the latest pass ran out of frames well before the end the container states.

        The expected count M is ``CAP_PROP_FRAME_COUNT``: the container's own number of frames (mp4,
        mov) or FFmpeg's estimate from duration × frame rate. A clean file can decode a few frames
        fewer than it lists (``night_ambulance_lights.mp4``: 282 of 288, its last one still at
        11.48 s = (288 - 1) / 25 s), so the pass is reported only when it is short both in frames
        (more than ``max(2, 1 %)`` of M) and in time: the last decoded frame's timestamp lies more
        than ``max(2 frames, 1 %)`` of the duration before the last listed frame's,
        ``(M - 1) / fps``. A pass stopped by ``max_frames`` or by the caller, or a file whose count
        is unknown, passes.

        Raises:
            InputError: "truncated or damaged after frame N of M" (N frames decoded).
        """
        expected, fps = self.info.frame_count, self.info.fps
        if not self.reached_end or expected <= 0:
            return
        end_s = (expected - 1) / fps
        short_frames = expected - self.frames_read > max(2, expected // 100)
        short_time = end_s - self.last_time_s > max(2.0 / fps, 0.01 * expected / fps)
        if short_frames and short_time:
            raise InputError(
                self.path,
                f"truncated or damaged after frame {self.frames_read} of {expected} (decoding stopped at "
                f"{self.last_time_s:.2f} s of {end_s + 1.0 / fps:.2f} s)",
            )

    # ---------------------------------------------------------------------------------- life cycle

    def close(self) -> None:
        """Release the file; safe to call more than once."""
        self._closed = True
        if self._cap is not None:
            self._cap.release()
        self._cap = None
        self._first = None

    def __enter__(self) -> VideoReader:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        i = self.info
        return (
            f"VideoReader({str(self.path)!r}, {i.width}x{i.height} @ {i.fps:g} fps, "
            f"stride={self.stride}, max_frames={self.max_frames})"
        )


def probe_video(path: str | Path) -> VideoInfo:
    """The :class:`VideoInfo` of ``path``, after checking that a first frame decodes.

    Raises:
        InputError: as :class:`VideoReader`.
    """
    with VideoReader(path) as reader:
        return reader.info


#: H.264 encoders tried in this order; the first that FFmpeg can open wins.
ENCODER_PREFERENCE: tuple[str, ...] = ("libx264", "h264", "libopenh264")


def pick_h264_encoder() -> str:
    """The name of the H.264 encoder that :class:`~makeway.viz.video_writer.H264Writer` and the
    H.264 camera logs (:mod:`makeway.sense.log_writer`) use.

    Raises:
        RuntimeError: PyAV's FFmpeg has no H.264 encoder at all.
    """
    import av

    available = av.codecs_available
    for name in ENCODER_PREFERENCE:
        if name != "h264" and name not in available:
            continue
        try:
            codec = av.codec.Codec(name, "w")
        except Exception:  # not an encoder in this build
            continue
        return str(codec.name)
    raise RuntimeError("PyAV's FFmpeg build has no H.264 encoder (tried libx264, h264, libopenh264)")
