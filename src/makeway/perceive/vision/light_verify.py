"""Two-stage lit-light detector: rule proposals, then a learned verifier (``LIGHT_DETECTORS["verified"]``).

Stage 1 (:func:`proposals`): the rule finder :func:`~makeway.perceive.vision.light_colour.propose`
with the wide hue ranges (:data:`~makeway.perceive.vision.light_colour.WIDE_HSV`) run under the
settings of :data:`PROPOSAL_CONFIGS` (the shipped one; one without merging and with a small minimum
area, for lamps of a few pixels; one with a looser saturated core), pooled, identical boxes once.

Stage 2 (:func:`verifier_features` and :class:`LightVerifier`): each proposal becomes one feature row
— its box size, aspect and place in the frame; the frame's brightness; colour, brightness, clipping
and colour-mask statistics of the box and of its context ring (the box grown by its longer side on
every side); the context patch's value and saturation resized to 8×8; the proposal's colour, score,
cues and the settings that found it — and gradient-boosted trees (ONNX, ONNX Runtime only) give the
probability that it is a lit emergency light. A model with the output ``box_offsets`` also refines
each kept box (:func:`refine_boxes`: boosted-tree regressors on the same features predict how far each
side of the proposal lies from the lit part a person would box — the rules often box a lamp with
its glow, or only part of it, which misses IoU 0.5 on a lamp of a few pixels). Kept boxes
(probability ≥ the model's threshold, refined) pass a greedy non-maximum suppression (IoU > 0.3, or
one box at least 80 % inside a higher-scoring one).
Boxes are pixels of the input frame, ``x2``/``y2`` exclusive. Trained by
:mod:`makeway.train.light_verifier` (``makeway lights-train --verifier``).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from makeway.errors import InputError
from makeway.messages import Box, LightDetection
from makeway.onnx_models import model_metadata, smoke_run
from makeway.perceive.vision.light_colour import COLOURS, WIDE_HSV, ProposalConfig, colour_masks, propose

__all__ = [
    "BOX_OUTPUT",
    "DEFAULT_VERIFIER_MODEL",
    "FEATURE_NAMES",
    "PROPOSAL_CONFIGS",
    "LightVerifier",
    "VerifiedLightDetector",
    "nms",
    "proposals",
    "refine_boxes",
    "verifier_features",
]

DEFAULT_VERIFIER_MODEL = Path(__file__).resolve().parents[2] / "models" / "lights_verifier.onnx"

#: Proposal settings pooled by :func:`proposals` (colours are set per call).
PROPOSAL_CONFIGS: tuple[dict[str, Any], ...] = (
    {},
    {"merge_px": 0, "min_area_px": 4},
    {"merge_px": 1, "min_area_px": 6, "core_v": 230, "core_s_max": 100},
)

PATCH = 8
#: Name of the optional output of a verifier model that refines boxes (:func:`refine_boxes`).
BOX_OUTPUT = "box_offsets"
_CUES = ("colour", "core")
_STATS = ("b", "g", "r", "s", "v", "v2", "clip", "wcore", "hcos", "hsin", *(f"m_{c}" for c in COLOURS))


def _feature_names() -> list[str]:
    names = ["log_w", "log_h", "log_aspect", "cx", "cy", "w_rel", "h_rel", "frame_v", "frame_v99", "log_n"]
    for region in ("core", "ring"):
        names += [f"{region}_{s}" for s in _STATS]
    names += ["v_contrast", "s_contrast", "score"]
    names += [f"colour_{c}" for c in COLOURS] + [f"cue_{c}" for c in _CUES]
    names += [f"cfg_{i}" for i in range(len(PROPOSAL_CONFIGS))]
    names += [f"pv_{i}" for i in range(PATCH * PATCH)] + [f"ps_{i}" for i in range(PATCH * PATCH)]
    return names


#: Column names of :func:`verifier_features` (also stored in the model's metadata).
FEATURE_NAMES: tuple[str, ...] = tuple(_feature_names())


def proposals(frame_bgr: np.ndarray, colours: Sequence[str] = COLOURS) -> list[dict[str, Any]]:
    """Pooled stage-1 proposals of one BGR frame (module docstring): dicts with ``box`` (x1, y1, x2,
    y2), ``colour``, ``score``, ``cues`` and ``configs`` (indices of :data:`PROPOSAL_CONFIGS` that
    found it)."""
    out: dict[tuple[int, int, int, int], dict[str, Any]] = {}
    for i, extra in enumerate(PROPOSAL_CONFIGS):
        cfg = ProposalConfig(colours=tuple(colours), hsv=dict(WIDE_HSV), **extra)
        for p in propose(frame_bgr, cfg):
            d = out.get(p.box)
            if d is None:
                out[p.box] = {
                    "box": p.box,
                    "colour": p.colour,
                    "score": p.score,
                    "cues": set(p.cues),
                    "configs": {i},
                }
            else:
                d["score"] = max(d["score"], p.score)
                d["cues"] |= set(p.cues)
                d["configs"].add(i)
    return list(out.values())


def _box_sums(ii: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Sums of every channel of the integral image ``ii`` (H+1, W+1, C) over boxes ``b`` (n, 4)."""
    x1, y1, x2, y2 = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    return ii[y2, x2] - ii[y1, x2] - ii[y2, x1] + ii[y1, x1]


def verifier_features(frame_bgr: np.ndarray, props: Sequence[dict[str, Any]]) -> np.ndarray:
    """Feature rows ``(n, len(FEATURE_NAMES))`` float32 of the proposals of one frame (module
    docstring); values are scaled to about 0–1 (pixel statistics divided by 255)."""
    h, w = frame_bgr.shape[:2]
    n = len(props)
    if n == 0:
        return np.zeros((0, len(FEATURE_NAMES)), np.float32)
    hsv = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2HSV)
    v = hsv[..., 2].astype(np.float32) / 255.0
    s = hsv[..., 1].astype(np.float32) / 255.0
    ang = hsv[..., 0].astype(np.float32) * (np.pi / 90.0)
    masks = colour_masks(frame_bgr, WIDE_HSV)
    clip = (hsv[..., 2] >= 245).astype(np.float32)
    chans = [
        frame_bgr[..., 0].astype(np.float32) / 255.0,
        frame_bgr[..., 1].astype(np.float32) / 255.0,
        frame_bgr[..., 2].astype(np.float32) / 255.0,
        s,
        v,
        v * v,
        clip,
        clip * (hsv[..., 1] <= 80),
        np.cos(ang) * s,
        np.sin(ang) * s,
        *(masks[c].astype(np.float32) for c in COLOURS),
    ]
    ii = cv2.integral(np.dstack(chans).astype(np.float64)).reshape(h + 1, w + 1, len(chans))
    b = np.array([p["box"] for p in props], np.int64).reshape(-1, 4)
    b[:, [0, 2]] = np.clip(b[:, [0, 2]], 0, w)
    b[:, [1, 3]] = np.clip(b[:, [1, 3]], 0, h)
    bw = np.maximum(1, b[:, 2] - b[:, 0])
    bh = np.maximum(1, b[:, 3] - b[:, 1])
    grow = np.maximum(bw, bh)
    ctx = np.stack(
        [
            np.clip(b[:, 0] - grow, 0, w),
            np.clip(b[:, 1] - grow, 0, h),
            np.clip(b[:, 2] + grow, 0, w),
            np.clip(b[:, 3] + grow, 0, h),
        ],
        axis=1,
    )
    a_core = np.maximum(1, (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])).astype(np.float64)
    a_ctx = np.maximum(1, (ctx[:, 2] - ctx[:, 0]) * (ctx[:, 3] - ctx[:, 1])).astype(np.float64)
    s_core = _box_sums(ii, b)
    s_ctx = _box_sums(ii, ctx)
    core = s_core / a_core[:, None]
    ring = (s_ctx - s_core) / np.maximum(1.0, a_ctx - a_core)[:, None]
    frame_v = float(v.mean())
    frame_v99 = float(np.percentile(v, 99))
    geo = np.stack(
        [
            np.log(bw),
            np.log(bh),
            np.log(bw / bh),
            (b[:, 0] + b[:, 2]) / (2.0 * w),
            (b[:, 1] + b[:, 3]) / (2.0 * h),
            bw / w,
            bh / h,
            np.full(n, frame_v),
            np.full(n, frame_v99),
            np.full(n, np.log(n)),
        ],
        axis=1,
    )
    iv, is_ = _STATS.index("v"), _STATS.index("s")
    contrast = np.stack([core[:, iv] - ring[:, iv], core[:, is_] - ring[:, is_]], axis=1)
    meta = np.zeros((n, 1 + len(COLOURS) + len(_CUES) + len(PROPOSAL_CONFIGS)))
    for k, p in enumerate(props):
        meta[k, 0] = p["score"]
        if p["colour"] in COLOURS:
            meta[k, 1 + COLOURS.index(p["colour"])] = 1.0
        for j, c in enumerate(_CUES):
            meta[k, 1 + len(COLOURS) + j] = float(c in p["cues"])
        for i in p["configs"]:
            meta[k, 1 + len(COLOURS) + len(_CUES) + i] = 1.0
    patches = np.zeros((n, 2 * PATCH * PATCH), np.float32)
    vs = np.dstack([v, s])
    for k in range(n):
        x1, y1, x2, y2 = ctx[k]
        crop = vs[y1:y2, x1:x2]
        if crop.size == 0:
            continue
        small = cv2.resize(crop, (PATCH, PATCH), interpolation=cv2.INTER_AREA)
        patches[k] = np.concatenate([small[..., 0].ravel(), small[..., 1].ravel()])
    return np.concatenate([geo, core, ring, contrast, meta, patches], axis=1).astype(np.float32)


def refine_boxes(boxes: np.ndarray, offsets: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Proposal boxes ``(n, 4)`` moved by predicted corrections ``(n, 4)``: each corner moves by its
    offset times the box's width (x) or height (y), the result is clipped to the frame ``size``
    ``(width, height)`` and kept at least 1 px wide and high. Offsets are clipped to ±1.5 (a box
    may at most grow or shrink by 1.5× its size per side)."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    o = np.clip(np.asarray(offsets, np.float64).reshape(-1, 4), -1.5, 1.5)
    bw = np.maximum(1.0, b[:, 2] - b[:, 0])
    bh = np.maximum(1.0, b[:, 3] - b[:, 1])
    out = b + o * np.stack([bw, bh, bw, bh], axis=1)
    w, h = size
    out[:, [0, 2]] = np.clip(out[:, [0, 2]], 0, w)
    out[:, [1, 3]] = np.clip(out[:, [1, 3]], 0, h)
    out[:, 2] = np.maximum(out[:, 2], np.minimum(out[:, 0] + 1, w))
    out[:, 3] = np.maximum(out[:, 3], np.minimum(out[:, 1] + 1, h))
    out[:, 0] = np.minimum(out[:, 0], out[:, 2] - 1)
    out[:, 1] = np.minimum(out[:, 1], out[:, 3] - 1)
    return out


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float = 0.3, inside: float = 0.8) -> np.ndarray:
    """Indices kept by greedy non-maximum suppression in descending score order: a box is dropped
    when its IoU with a kept box exceeds ``iou`` or at least ``inside`` of its area lies in one."""
    order = np.argsort(-scores, kind="stable")
    keep: list[int] = []
    areas = np.maximum(1e-9, (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]))
    for i in order:
        ok = True
        for j in keep:
            iw = min(boxes[i, 2], boxes[j, 2]) - max(boxes[i, 0], boxes[j, 0])
            ih = min(boxes[i, 3], boxes[j, 3]) - max(boxes[i, 1], boxes[j, 1])
            if iw <= 0 or ih <= 0:
                continue
            inter = iw * ih
            if inter / (areas[i] + areas[j] - inter) > iou or inter / min(areas[i], areas[j]) >= inside:
                ok = False
                break
        if ok:
            keep.append(int(i))
    return np.array(keep, np.int64)


class LightVerifier:
    """The stage-2 model: ONNX gradient-boosted trees scoring feature rows of
    :func:`verifier_features` as P(lit emergency light); ``threshold`` is the model's operating point
    (metadata ``threshold``, chosen on the validation split)."""

    def __init__(self, model: str | Path | None = None, *, num_threads: int = 1) -> None:
        import onnxruntime as ort

        path = Path(model) if model is not None else DEFAULT_VERIFIER_MODEL
        if not path.is_file():
            raise InputError(path, "light verifier model not found (makeway lights-train --verifier)")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = num_threads
        opts.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own types
            raise InputError(path, f"not a readable ONNX model ({exc})") from exc
        meta = model_metadata(self.session, path)
        if meta.get("makeway_model") != "light_verifier":
            raise InputError(path, "not a light verifier model (metadata makeway_model missing)")
        try:
            names = json.loads(meta.get("feature_names", "[]"))
            threshold = float(meta.get("threshold", 0.5))
        except (ValueError, TypeError) as exc:
            raise InputError(path, f"malformed light verifier metadata ({exc})") from None
        if not isinstance(names, list) or tuple(names) != FEATURE_NAMES:
            n = len(names) if isinstance(names, list) else 0
            raise InputError(path, f"its features do not match this code's ({n} vs {len(FEATURE_NAMES)})")
        if not 0.0 <= threshold <= 1.0:
            raise InputError(path, f"malformed light verifier metadata (threshold {threshold} not in [0, 1])")
        self.path = path
        self.threshold = threshold
        self.metadata = dict(meta)
        inputs = self.session.get_inputs()
        if len(inputs) != 1:
            raise InputError(path, f"expected one input of feature rows; found {len(inputs)}")
        self._input = inputs[0].name
        outputs = [o.name for o in self.session.get_outputs()]
        #: Whether the model also predicts box corrections (output ``box_offsets``, see :meth:`refine`).
        self.refines_boxes = BOX_OUTPUT in outputs
        self._outputs = [outputs[1], *([BOX_OUTPUT] if self.refines_boxes else [])]
        smoke_run(self.session, path)
        try:  # two rows of zeros must give two probabilities
            probe = self.score(np.zeros((2, len(FEATURE_NAMES)), np.float32))
            ok = probe.shape == (2,)
        except Exception:  # onnxruntime's own types, or outputs of another layout (IndexError, …)
            ok = False
        if not ok:
            raise InputError(path, "does not give one probability per feature row")

    def score(self, features: np.ndarray) -> np.ndarray:
        """P(lit emergency light) per feature row ``(n, len(FEATURE_NAMES))``."""
        return self.score_and_offsets(features)[0]

    def score_and_offsets(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """P(lit emergency light) per feature row and, when the model refines boxes, the predicted
        corrections ``(n, 4)`` (see :func:`refine_boxes`), else None."""
        x = np.asarray(features, np.float32)
        if x.ndim != 2 or x.shape[1] != len(FEATURE_NAMES):
            raise ValueError(f"expected features (n, {len(FEATURE_NAMES)}), got {x.shape}")
        if len(x) == 0:
            return np.zeros(0, np.float64), (np.zeros((0, 4)) if self.refines_boxes else None)
        outs = self.session.run(self._outputs, {self._input: x})
        prob = outs[0]
        if isinstance(prob, list):  # ZipMap output: list of {label: p}
            p = np.array([d[1] for d in prob], np.float64)
        else:
            p = np.asarray(prob, np.float64)[:, 1]
        offsets = np.asarray(outs[1], np.float64).reshape(len(x), 4) if self.refines_boxes else None
        return p, offsets


class VerifiedLightDetector:
    """Rule proposals checked by the learned verifier (module docstring).

    ``colours`` is the jurisdiction's colour set (a preset name or colour names); only proposals of
    those colours are made and returned. ``threshold`` overrides the model's operating point (a
    low value lets an evaluation see the ranking). Scores are the verifier's probabilities (0–1).
    """

    def __init__(
        self,
        colours: str | Sequence[str] = "eu",
        *,
        model: str | Path | None = None,
        threshold: float | None = None,
        num_threads: int = 1,
    ) -> None:
        from makeway.perceive.vision.lights import colour_set

        self.colours = colour_set(colours)
        self.verifier = LightVerifier(model, num_threads=num_threads)
        self.threshold = self.verifier.threshold if threshold is None else float(threshold)

    def detect(self, frame_bgr: np.ndarray, frame: int = 0) -> list[LightDetection]:
        if frame_bgr.ndim != 3 or frame_bgr.shape[2] != 3 or frame_bgr.dtype != np.uint8:
            raise ValueError(f"expected a uint8 BGR image H×W×3, got {frame_bgr.dtype} {frame_bgr.shape}")
        props = [p for p in proposals(frame_bgr, self.colours) if p["colour"] in self.colours]
        if not props:
            return []
        prob, offsets = self.verifier.score_and_offsets(verifier_features(frame_bgr, props))
        sel = np.flatnonzero(prob >= self.threshold)
        if len(sel) == 0:
            return []
        boxes = np.array([props[i]["box"] for i in sel], np.float64)
        if offsets is not None:
            h, w = frame_bgr.shape[:2]
            boxes = refine_boxes(boxes, offsets[sel], (w, h))
        keep = nms(boxes, prob[sel])
        out = [
            LightDetection(
                Box(*(float(v) for v in boxes[k])), props[sel[k]]["colour"], float(prob[sel[k]]), frame
            )
            for k in keep
        ]
        return sorted(out, key=lambda d: (d.box.x1, d.box.y1, d.box.x2, d.box.y2))
