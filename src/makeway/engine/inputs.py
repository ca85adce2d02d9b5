"""What the data engine mines: inputs and the registry of input kinds (issue 28, item 3).

An input is one unit of work, one task on the cluster. It is named on the command line as

* ``VIDEO`` — a whole road video (any file OpenCV/FFmpeg reads);
* ``VIDEO@START:END`` — frames ``START`` (inclusive) to ``END`` (exclusive) of it, 0-based source
  frame indices (``END`` may be left out: to the end), so a long drive splits into tasks;
* ``FOLDER`` of road images (JPEG/PNG…, e.g. a camera's dumped frames) — each image on its own;
* ``FOLDER`` holding a multichannel recording (``audio.flac`` + ``array.yaml``,
  :mod:`makeway.sense.recording`) — the siren models' input;
* ``LOG`` — a robotics log, an MCAP file or a ROS 2 bag folder (:mod:`makeway.sense.logs`): its
  camera topics are mined as videos, its audio topics (with their array description) as recordings.

:data:`INPUT_KINDS` maps a kind name to an :class:`InputKind`: ``matches(path)`` says whether a path
is of the kind (first match wins, in registration order) and ``mine`` is the task
(:mod:`makeway.engine.mine`). A new kind registers one more entry; nothing else changes.

:func:`expand_inputs` turns the command-line names into :class:`EngineInput` objects, cutting each
video into ``segment_frames``-long slices when asked. A name it cannot resolve is returned in the
list of problems (one line each), not raised, so a batch with one bad name still runs the others.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from makeway.errors import InputError
from makeway.registry import Registry
from makeway.sense.crops import IMAGE_SUFFIXES
from makeway.sense.recording import ARRAY_FILE, AUDIO_FILE

__all__ = ["INPUT_KINDS", "EngineInput", "InputKind", "expand_inputs", "parse_input"]

VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".avi", ".webm", ".m4v", ".ts", ".mpg", ".mpeg")
_SLICE = re.compile(r"^(?P<path>.+)@(?P<start>\d+):(?P<end>\d*)$")


@dataclass(frozen=True)
class EngineInput:
    """One task's input: ``kind`` (an :data:`INPUT_KINDS` name), ``path`` (absolute) and, for a
    video, the frame range ``[start, end)`` (``end=None``: to the end)."""

    kind: str
    path: Path
    start: int = 0
    end: int | None = None

    @property
    def name(self) -> str:
        """How the input is written on the command line (``clip.mp4@0:120`` for a slice)."""
        if self.start == 0 and self.end is None:
            return str(self.path)
        return f"{self.path}@{self.start}:{'' if self.end is None else self.end}"

    @property
    def input_id(self) -> str:
        """A folder-safe id, stable across runs and machines: ``<name>[_<start>-<end>]_<8 hex>``, the
        hex digest covering the file's (or, for a folder, its files') names and sizes and the frame
        range — not the folder it lies in, so mined samples keep their names when the data moves."""
        stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", self.path.name)[:40] or "input"
        if self.start or self.end is not None:
            stem += f"_{self.start}-{'end' if self.end is None else self.end}"
        if self.path.is_dir():
            entries = sorted((p.name, p.stat().st_size) for p in self.path.iterdir() if p.is_file())
        else:
            entries = [(self.path.name, self.path.stat().st_size if self.path.exists() else -1)]
        key = json.dumps([entries, self.start, self.end])
        return f"{stem}_{hashlib.sha256(key.encode('utf-8')).hexdigest()[:8]}"


@dataclass(frozen=True)
class InputKind:
    """An input kind: ``matches(path)`` recognises it, ``mine(input, config, folder)`` is the
    per-input task (returns the hard samples it wrote, :mod:`makeway.engine.mine`), ``sliceable``
    says whether ``@START:END`` frame ranges apply, ``frames(path)`` (sliceable kinds) the number of
    frames, for ``segment_frames``."""

    description: str
    matches: Callable[[Path], bool]
    mine: Callable[..., list[dict[str, Any]]]
    sliceable: bool = False
    frames: Callable[[Path], int] | None = None


def _is_video(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES


def _is_recording(path: Path) -> bool:
    return path.is_dir() and (path / AUDIO_FILE).is_file() and (path / ARRAY_FILE).is_file()


def _is_image_folder(path: Path) -> bool:
    return path.is_dir() and any(
        p.suffix.lower() in IMAGE_SUFFIXES for p in path.iterdir() if not p.name.startswith(".")
    )


def _is_log(path: Path) -> bool:
    from makeway.sense.logs import is_log

    return (path.is_file() and path.suffix.lower() == ".mcap") or (path.is_dir() and is_log(path))


def _video_frames(path: Path) -> int:
    from makeway.sense.video import probe_video

    return probe_video(path).frame_count


def _mine_video(*args: Any, **kwargs: Any) -> list[dict[str, Any]]:
    from makeway.engine.mine import mine_video

    return mine_video(*args, **kwargs)


def _mine_images(*args: Any, **kwargs: Any) -> list[dict[str, Any]]:
    from makeway.engine.mine import mine_images

    return mine_images(*args, **kwargs)


def _mine_log(*args: Any, **kwargs: Any) -> list[dict[str, Any]]:
    from makeway.engine.mine import mine_log

    return mine_log(*args, **kwargs)


def _mine_recording(*args: Any, **kwargs: Any) -> list[dict[str, Any]]:
    from makeway.engine.mine import mine_recording

    return mine_recording(*args, **kwargs)


#: Input kinds, tried in this order: ``video`` (a file with a video suffix), ``log`` (an ``.mcap``
#: file or a ROS 2 bag folder), ``recording`` (a folder with ``audio.flac`` and ``array.yaml``),
#: ``images`` (a folder with image files).
INPUT_KINDS: Registry[InputKind] = Registry("input kind")
INPUT_KINDS.register("video")(
    InputKind("road video (or a frame range of one)", _is_video, _mine_video, True, _video_frames)
)
INPUT_KINDS.register("log")(InputKind("robotics log (MCAP file or ROS 2 bag folder)", _is_log, _mine_log))
INPUT_KINDS.register("recording")(
    InputKind("multichannel recording folder (audio.flac + array.yaml)", _is_recording, _mine_recording)
)
INPUT_KINDS.register("images")(InputKind("folder of road images", _is_image_folder, _mine_images))


def _exists(path: Path) -> bool:
    """``path.exists()``, false for a name the file system refuses (too long, ...)."""
    try:
        return path.exists()
    except OSError:
        return False


def parse_input(name: str | Path) -> EngineInput:
    """One command-line name → an :class:`EngineInput` (module docstring).

    Raises:
        InputError: the path does not exist, is of no known kind, or a frame range is empty or
            given for a kind that has no frames.
    """
    text = str(name)
    if not text or "\x00" in text:
        raise InputError(text, "is not a usable file name (empty, or holds a NUL character)")
    start, end = 0, None
    m = _SLICE.match(text)
    if m is not None and not _exists(Path(text)):
        text, start = m["path"], int(m["start"])
        end = int(m["end"]) if m["end"] else None
    try:
        path = Path(text).expanduser().absolute()
    except RuntimeError:  # ``~user`` for a user that does not exist
        raise InputError(text, "names the home folder of an unknown user") from None
    if not _exists(path):
        raise InputError(path, "no such file or folder")
    for kind_name, kind in INPUT_KINDS.items():
        if kind.matches(path):
            if (start or end is not None) and not kind.sliceable:
                raise InputError(path, f"a frame range @START:END applies to videos, not to a {kind_name}")
            if end is not None and end <= start:
                raise InputError(path, f"empty frame range @{start}:{end} (END must exceed START)")
            return EngineInput(kind_name, path, start, end)
    kinds = "; ".join(f"{k}: {v.description}" for k, v in INPUT_KINDS.items())
    raise InputError(path, f"not an input the engine knows ({kinds})")


def expand_inputs(
    names: Sequence[str | Path], *, segment_frames: int | None = None
) -> tuple[list[EngineInput], list[tuple[str, str]]]:
    """Resolve command-line names; returns ``(inputs, problems)``, ``problems`` being
    ``(name, one-line reason)`` for each name that could not be resolved.

    With ``segment_frames``, every whole video becomes slices of that many frames (the last one
    may be shorter); slices named explicitly stay as given. Duplicates are dropped (first kept).
    """
    if segment_frames is not None and segment_frames < 1:
        raise ValueError(f"segment_frames must be >= 1, got {segment_frames}")
    inputs: list[EngineInput] = []
    problems: list[tuple[str, str]] = []
    for name in names:
        try:
            inp = parse_input(name)
            kind = INPUT_KINDS[inp.kind]
            if segment_frames and kind.sliceable and kind.frames and inp.start == 0 and inp.end is None:
                total = kind.frames(inp.path)
                if total > 0:
                    inputs += [
                        EngineInput(inp.kind, inp.path, s, min(s + segment_frames, total))
                        for s in range(0, total, segment_frames)
                    ]
                    continue
            inputs.append(inp)
        except InputError as exc:
            problems.append((str(name), str(exc)))
    seen: set[str] = set()
    unique = []
    for inp in inputs:
        if inp.input_id not in seen:
            seen.add(inp.input_id)
            unique.append(inp)
    return unique, problems
