"""Opening makeway's own ONNX models (the siren networks, the approach classifier) with ONNX Runtime.

:func:`open_makeway_onnx` is the one way to do it: a CPU session whose idle worker threads sleep
instead of spinning (the feature code and other sessions share the cores), and one clear
:class:`~makeway.errors.InputError` naming the file when it is missing, is not ONNX, or is ONNX but
not the kind of makeway model asked for (the ``makeway_model`` metadata key the exporters write).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from makeway.errors import InputError


def open_makeway_onnx(
    path: str | Path, kind: str, *, threads: int | None = None, missing_hint: str = ""
) -> tuple[Any, dict[str, str]]:
    """``(session, metadata)`` of the makeway model of ``kind`` (``"siren_net"``,
    ``"siren_approach"``) at ``path``; ``threads``: ONNX Runtime intra-op threads (None: all cores);
    ``missing_hint`` ends the message when the file does not exist."""
    import onnxruntime as ort

    path = Path(path)
    if not path.is_file():
        raise InputError(
            path, f"{kind.replace('_', ' ')} model not found{f' ({missing_hint})' if missing_hint else ''}"
        )
    opts = ort.SessionOptions()
    if threads is not None:
        opts.intra_op_num_threads = int(threads)
        opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    try:
        session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types
        raise InputError(path, f"not a readable ONNX model ({str(exc).splitlines()[0][:200]})") from None
    meta = dict(session.get_modelmeta().custom_metadata_map)
    if meta.get("makeway_model") != kind:
        raise InputError(
            path, f"an ONNX model, but not a makeway {kind.replace('_', ' ')} model (no {kind} metadata)"
        )
    return session, meta
