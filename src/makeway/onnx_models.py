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
    meta = model_metadata(session, path)
    if meta.get("makeway_model") != kind:
        raise InputError(
            path, f"an ONNX model, but not a makeway {kind.replace('_', ' ')} model (no {kind} metadata)"
        )
    smoke_run(session, path)
    return session, meta


def model_metadata(session: Any, path: str | Path) -> dict[str, str]:
    """The custom metadata of an ONNX Runtime session's model; one :class:`InputError` naming
    ``path`` when a key or value is not UTF-8 text (ONNX Runtime raises ``UnicodeDecodeError``)."""
    try:
        return dict(session.get_modelmeta().custom_metadata_map)
    except UnicodeDecodeError:
        raise InputError(path, "an ONNX model whose metadata is not UTF-8 text (damaged)") from None


_ORT_TYPES = {
    "tensor(float)": "float32",
    "tensor(double)": "float64",
    "tensor(int64)": "int64",
    "tensor(int32)": "int32",
}


def smoke_run(session: Any, path: str | Path, *, batch: int = 2) -> list[Any]:
    """Run ``session`` once on zeros shaped as its inputs declare (a named or unknown dimension
    becomes ``batch``) and return its outputs; a model that does not run — a damaged graph, weights
    cut short, a declared shape its operators reject — is one :class:`InputError` naming ``path``
    here, at load time, instead of an ONNX Runtime error on the first real input."""
    import numpy as np

    feeds = {}
    for item in session.get_inputs():
        dtype = _ORT_TYPES.get(item.type)
        if dtype is None:
            raise InputError(path, f"input {item.name!r} has type {item.type}, not a tensor of numbers")
        shape = [d if isinstance(d, int) and d >= 0 else batch for d in item.shape]
        if any(d > 100_000 for d in shape) or int(np.prod(shape)) > 50_000_000:
            raise InputError(path, f"input {item.name!r} declares an implausible shape {list(item.shape)}")
        feeds[item.name] = np.zeros(shape, dtype=dtype)
    try:
        return list(session.run(None, feeds))
    except Exception as exc:  # onnxruntime raises its own types (InvalidArgument, Fail, …)
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(path, f"is an ONNX model that does not run ({first[:200]})") from None
