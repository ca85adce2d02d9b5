"""``makeway info``: the installation as makeway sees it."""

from __future__ import annotations

import sys

from makeway import __version__
from makeway.errors import MakewayError

__all__ = ["environment_info"]


def environment_info() -> list[tuple[str, str]]:
    """``(what, value)`` rows: the versions of makeway, Python, ONNX Runtime and OpenCV; the shared data
    folder found (or where it was looked for); the ``.onnx`` files in every model folder searched;
    and the H.264 encoder the video writer would use (or why there is none)."""
    import cv2
    import onnxruntime as ort

    from makeway.paths import data_candidates, data_dir, models_candidates
    from makeway.viz.video_writer import pick_h264_encoder

    rows = [
        ("makeway", __version__),
        ("python", sys.version.split()[0]),
        ("onnxruntime", ort.__version__),
        ("opencv", cv2.__version__),
    ]
    found = data_dir()
    rows.append(
        (
            "data",
            str(found) if found else "not found (looked in " + ", ".join(map(str, data_candidates())) + ")",
        )
    )
    for folder in models_candidates():
        models = sorted(p.name for p in folder.glob("*.onnx")) if folder.is_dir() else []
        rows.append(("models", f"{folder}: {', '.join(models) or 'none'}"))
    try:
        rows.append(("h264 encoder", pick_h264_encoder()))
    except MakewayError as exc:
        rows.append(("h264 encoder", f"none ({exc})"))
    return rows
