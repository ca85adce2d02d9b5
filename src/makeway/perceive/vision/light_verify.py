"""Two-stage lit-light detector: rule proposals, then a learned verifier (``LIGHT_DETECTORS["verified"]``).

Stage 1 (:func:`proposals`): the rule finder :func:`~makeway.perceive.vision.light_colour.propose`
with the wide hue ranges (:data:`~makeway.perceive.vision.light_colour.WIDE_HSV`) run under the
settings of :data:`PROPOSAL_CONFIGS` (the shipped one; one without merging and with a small minimum
area, for lamps of a few pixels; one with a looser saturated core), pooled, identical boxes once.

Stage 2 (:func:`verifier_features` and :class:`LightVerifier`): each proposal becomes one feature row
— its box size, aspect and place in the frame; the frame's brightness; colour, brightness, clipping
and colour-mask statistics of the box and of its context ring (the box grown by its longer side on
every side); the context patch's value and saturation resized to 8×8; the proposal's colour, score,
cues and the settings that found it — optionally followed by its **vehicle context**
(:func:`context_features`: where it sits in or near the frame's vehicle boxes, found by YOLOX-nano or
handed over by the video pipeline, and whether a red/blue partner shares the box) and, last, its
**appearance** (:class:`ProposalAppearance`: a square patch centred on the proposal, four times its
longer side, through YOLOX-nano's COCO backbone, pooled, projected on a few principal components of
the training proposals) — and gradient-boosted trees (ONNX, ONNX Runtime only) give the
probability that it is a lit emergency light. The model's metadata names the columns it reads;
the shipped model reads the context and the appearance.
A model with the output ``box_offsets`` also refines each kept box (:func:`refine_boxes`:
boosted-tree regressors on the same features predict how far each side of the proposal lies from
the lit part a person would box — the rules often box a lamp with its glow, or only part of it,
which misses IoU 0.5 on a lamp of a few pixels). Kept boxes
(probability ≥ the model's threshold, refined) pass a greedy non-maximum suppression (IoU > 0.3, or
one box at least 80 % inside a higher-scoring one).
**Small lamps.** A second verifier trained with shrunk copies of the training frames
(:data:`DEFAULT_SMALL_VERIFIER_MODEL`; metadata ``applies_below_px``) scores the proposals whose
longer side is under that size (6 px shipped): lamps of a few pixels — a vehicle 10–20 m from the
rig's fisheyes, or far from a road camera — which the main verifier, trained on lamps of about
12 px, all but rejects. Its appearance columns use its own projection; the main model's threshold
applies to both.
Boxes are pixels of the input frame, ``x2``/``y2`` exclusive. Trained by
:mod:`makeway.train.light_verifier` (``makeway lights-train --verifier``).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from makeway.errors import InputError
from makeway.messages import Box, LightDetection
from makeway.onnx_models import model_metadata, smoke_run
from makeway.perceive.vision.light_colour import COLOURS, WIDE_HSV, ProposalConfig, colour_masks, propose

#: Vehicle boxes of one frame as the vehicle detector's ``detect_arrays`` gives them: boxes ``(m, 4)``
#: (x1, y1, x2, y2, pixels), scores ``(m,)`` and 0-based COCO class ids ``(m,)``.
Vehicles = tuple[np.ndarray, np.ndarray, np.ndarray]

__all__ = [
    "APPEARANCE_PREFIX",
    "BOX_OUTPUT",
    "CONTEXT_FEATURE_NAMES",
    "DEFAULT_SMALL_VERIFIER_MODEL",
    "DEFAULT_VERIFIER_MODEL",
    "FEATURE_NAMES",
    "PROPOSAL_CONFIGS",
    "VEHICLE_DETECTOR_SETTINGS",
    "LightVerifier",
    "ProposalAppearance",
    "Vehicles",
    "VerifiedLightDetector",
    "appearance_patches",
    "context_features",
    "nms",
    "proposals",
    "refine_boxes",
    "vehicle_detector",
    "verifier_features",
]

DEFAULT_VERIFIER_MODEL = Path(__file__).resolve().parents[2] / "models" / "lights_verifier.onnx"
DEFAULT_SMALL_VERIFIER_MODEL = Path(__file__).resolve().parents[2] / "models" / "lights_verifier_small.onnx"

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


#: COCO ids of the vehicle classes (car, motorcycle, bus, truck) one-hot encoded in the context.
_VEHICLE_CLASS_IDS = {2: "car", 3: "motorcycle", 5: "bus", 7: "truck"}
#: Pairs of lamp colours of an emergency bar: a red or blue proposal's partner is the other one.
_BAR_COLOURS = ("red", "blue")

CONTEXT_FEATURE_NAMES: tuple[str, ...] = (
    "veh_any",
    "veh_inside",
    "veh_n_inside",
    "veh_dist",
    "veh_y",
    "veh_x",
    "veh_xc",
    "veh_log_w",
    "veh_log_h",
    "veh_aspect",
    "veh_score",
    *(f"veh_{c}" for c in _VEHICLE_CLASS_IDS.values()),
    "share_log_n",
    *(f"share_{c}" for c in COLOURS),
    "share_red_blue",
    "share_partner",
)
"""Columns of :func:`context_features`: how a proposal sits relative to the vehicles of its frame.

``veh_any``: the frame has a vehicle box at all (else every other column holds its "no vehicle"
value). The proposal's **host** is the smallest vehicle box holding its centre, else the nearest box.
``veh_inside``: the centre lies in a vehicle box; ``veh_n_inside``: in how many; ``veh_dist``: the
gap from the centre to the host box in host heights (0 inside; 10 without vehicles); ``veh_y``,
``veh_x``: the centre's place in the host box, 0 at its top / left edge and 1 at its bottom / right
(light bars sit high, tail and head lights low; negative above the box; clipped to −4 … 5);
``veh_xc``: distance from the host's vertical centre line in half widths (0 centred, 1 at a side);
``veh_log_w``, ``veh_log_h``: ln(host width / proposal width) and ln(host height / proposal height);
``veh_aspect``: ln(host width / height); ``veh_score``: the host's detector score; ``veh_car`` …
``veh_truck``: the host's COCO class. ``share_*`` (0 when outside every box): the proposals whose
centre lies in the host box — ln(1 + count), the fraction of each colour, whether red and blue
both occur (``share_red_blue``), and whether a proposal of the other bar colour (red for a blue one,
red or blue for the others) sits at about the same height, within 0.15 host heights
(``share_partner``: a red/blue bar pair). Nothing here says where in the frame the lamp is, or how
big the frame or the vehicle is in pixels (only ratios to the proposal).
"""
_NO_VEHICLE = {"veh_dist": 10.0, "veh_y": -5.0, "veh_x": -5.0, "veh_xc": 10.0}


def context_features(
    boxes: np.ndarray,
    colours: Sequence[str],
    vehicles: Vehicles | None,
    *,
    peer_boxes: np.ndarray | None = None,
    peer_colours: Sequence[str] | None = None,
) -> np.ndarray:
    """Vehicle-context rows ``(n, len(CONTEXT_FEATURE_NAMES))`` float32 of proposals ``boxes``
    ``(n, 4)`` with their ``colours``, given the frame's ``vehicles`` (:data:`Vehicles`, None or
    empty: no vehicle). ``peer_boxes`` / ``peer_colours`` are the proposals counted in the
    ``share_*`` columns (default: ``boxes`` / ``colours`` themselves). Pixels of one frame; see
    :data:`CONTEXT_FEATURE_NAMES` for every column."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    n = len(b)
    idx = {name: i for i, name in enumerate(CONTEXT_FEATURE_NAMES)}
    out = np.zeros((n, len(CONTEXT_FEATURE_NAMES)), np.float64)
    for name, value in _NO_VEHICLE.items():
        out[:, idx[name]] = value
    if n == 0 or vehicles is None or len(vehicles[0]) == 0:
        return out.astype(np.float32)
    vb = np.asarray(vehicles[0], np.float64).reshape(-1, 4)
    vs = np.asarray(vehicles[1], np.float64).ravel()
    vc = np.asarray(vehicles[2], np.int64).ravel()
    vw = np.maximum(1.0, vb[:, 2] - vb[:, 0])
    vh = np.maximum(1.0, vb[:, 3] - vb[:, 1])

    def centres_in(bb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        cx = (bb[:, 0] + bb[:, 2]) / 2.0
        cy = (bb[:, 1] + bb[:, 3]) / 2.0
        inside: np.ndarray = np.asarray(
            (cx[:, None] >= vb[None, :, 0])
            & (cx[:, None] < vb[None, :, 2])
            & (cy[:, None] >= vb[None, :, 1])
            & (cy[:, None] < vb[None, :, 3]),
            bool,
        )
        return cx, cy, inside

    cx, cy, inside = centres_in(b)
    dx = np.maximum(0.0, np.maximum(vb[None, :, 0] - cx[:, None], cx[:, None] - vb[None, :, 2]))
    dy = np.maximum(0.0, np.maximum(vb[None, :, 1] - cy[:, None], cy[:, None] - vb[None, :, 3]))
    dist = np.hypot(dx, dy) / vh[None, :]
    area = vw * vh
    cost = np.where(inside, area[None, :] / area.max() - 2.0, dist)  # inside: smallest box first
    host = np.argmin(cost, axis=1)
    rows = np.arange(n)
    hx1, hy1, hw, hh = vb[host, 0], vb[host, 1], vw[host], vh[host]
    bw = np.maximum(1.0, b[:, 2] - b[:, 0])
    bh = np.maximum(1.0, b[:, 3] - b[:, 1])
    inside_any: np.ndarray = np.asarray(inside.any(axis=1), bool)
    rel_x = np.clip((cx - hx1) / hw, -4.0, 5.0)
    out[:, idx["veh_any"]] = 1.0
    out[:, idx["veh_inside"]] = inside_any
    out[:, idx["veh_n_inside"]] = inside.sum(axis=1)
    out[:, idx["veh_dist"]] = np.where(inside_any, 0.0, np.minimum(10.0, dist[rows, host]))
    out[:, idx["veh_y"]] = np.clip((cy - hy1) / hh, -4.0, 5.0)
    out[:, idx["veh_x"]] = rel_x
    out[:, idx["veh_xc"]] = np.abs(rel_x - 0.5) * 2.0
    out[:, idx["veh_log_w"]] = np.log(hw / bw)
    out[:, idx["veh_log_h"]] = np.log(hh / bh)
    out[:, idx["veh_aspect"]] = np.log(hw / hh)
    out[:, idx["veh_score"]] = vs[host]
    for cid, cname in _VEHICLE_CLASS_IDS.items():
        out[:, idx[f"veh_{cname}"]] = vc[host] == cid

    pb = b if peer_boxes is None else np.asarray(peer_boxes, np.float64).reshape(-1, 4)
    pc = list(colours) if peer_colours is None else list(peer_colours)
    if len(pc) != len(pb) or len(colours) != n:
        raise ValueError("one colour per box is needed")
    if len(pb) == 0:
        return out.astype(np.float32)
    _, pcy, p_inside = centres_in(pb)
    onehot = np.array([[c == k for k in COLOURS] for c in pc], np.float64).reshape(-1, len(COLOURS))
    per_vehicle = p_inside.T.astype(np.float64) @ onehot  # (m, colours): proposals in each box
    counts = per_vehicle[host] * inside_any[:, None]
    total = counts.sum(axis=1)
    out[:, idx["share_log_n"]] = np.log1p(total)
    frac = counts / np.maximum(1.0, total)[:, None]
    for j, c in enumerate(COLOURS):
        out[:, idx[f"share_{c}"]] = frac[:, j]
    ir, ib = COLOURS.index("red"), COLOURS.index("blue")
    out[:, idx["share_red_blue"]] = (counts[:, ir] > 0) & (counts[:, ib] > 0)
    # a proposal of the other bar colour in the same host box at about the same height
    same_box = p_inside[:, host].T & inside_any[:, None]  # (n, peers)
    level = np.abs(pcy[None, :] - cy[:, None]) <= 0.15 * hh[:, None]
    p_bar = np.array([c in _BAR_COLOURS for c in pc], bool)
    own = np.array(list(colours), dtype=object)
    other = p_bar[None, :] & (np.array(pc, dtype=object)[None, :] != own[:, None])
    out[:, idx["share_partner"]] = (same_box & level & other).any(axis=1)
    return out.astype(np.float32)


#: How the verifier's vehicle boxes are found when the caller gives none (and how the training
#: rows found them): YOLOX-nano as Framework B's video pipeline runs it.
VEHICLE_DETECTOR_SETTINGS: dict[str, Any] = {"score_threshold": 0.3, "class_agnostic": True}


def vehicle_detector(num_threads: int = 1) -> Any:
    """The COCO vehicle detector whose boxes give :func:`context_features` their vehicles
    (YOLOX-nano, :data:`VEHICLE_DETECTOR_SETTINGS`); ``InputError`` when its weights are missing."""
    from makeway.perceive.vision.detectors import DETECTORS

    return DETECTORS["yolox_nano"](num_threads=num_threads, **VEHICLE_DETECTOR_SETTINGS)


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


#: Column-name prefix of the appearance features (``app_0`` … ``app_{k-1}``).
APPEARANCE_PREFIX = "app_"


def appearance_patches(
    frame_bgr: np.ndarray,
    boxes: np.ndarray,
    *,
    size: int = 64,
    context: float = 4.0,
    min_side_px: float = 32.0,
) -> np.ndarray:
    """Square BGR patches ``(n, size, size, 3)`` uint8, one per box ``(n, 4)`` (x1, y1, x2, y2,
    pixels): centred on the box, ``context`` times its longer side (at least ``min_side_px``) across,
    resampled to ``size`` pixels; what falls outside the frame is grey (114, YOLOX's padding)."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    out = np.empty((len(b), size, size, 3), np.uint8)
    for i, (x1, y1, x2, y2) in enumerate(b):
        side = max(min_side_px, context * max(x2 - x1, y2 - y1))
        k = size / side
        m = np.array([[k, 0.0, size / 2 - k * (x1 + x2) / 2], [0.0, k, size / 2 - k * (y1 + y2) / 2]])
        out[i] = cv2.warpAffine(
            frame_bgr,
            m,
            (size, size),
            flags=cv2.INTER_AREA if k < 1 else cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=(114, 114, 114),
        )
    return out


@dataclass
class ProposalAppearance:
    """What a proposal and its surroundings look like to a pretrained network, in a few numbers.

    Each proposal's patch (:func:`appearance_patches`) goes through the registered ``backbone``'s
    ``layers`` (:class:`~makeway.perceive.vision.backbone.BackboneFeatures`: per channel the global
    average and max) → a vector ``d`` long (384 for YOLOX-nano ``dark3 + dark4``); :meth:`fit`
    learns each column's mean and standard deviation and the first ``n_components`` principal
    axes of the standardised vectors, and :meth:`transform` gives each proposal's coordinates on
    them ``(n, n_components)`` float32 — the verifier's ``app_*`` columns. The fitted state travels
    in the verifier's metadata (:meth:`to_json`, :meth:`from_json`). The backbone's ONNX Runtime
    session is made on first use."""

    n_components: int = 8
    backbone: str = "yolox_nano"
    layers: tuple[str, ...] = ("dark3", "dark4")
    input_size: int = 64
    context: float = 4.0
    min_side_px: float = 32.0
    num_threads: int = 1
    mean_: np.ndarray | None = field(default=None, repr=False)
    scale_: np.ndarray | None = field(default=None, repr=False)
    components_: np.ndarray | None = field(default=None, repr=False)
    _net: Any = field(default=None, init=False, repr=False, compare=False)

    @property
    def feature_names(self) -> tuple[str, ...]:
        """The ``app_*`` column names."""
        return tuple(f"{APPEARANCE_PREFIX}{i}" for i in range(self.n_components))

    def vectors(self, frame_bgr: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """The backbone's pooled vectors ``(n, d)`` float32 of the patches around ``boxes``."""
        if self._net is None:
            from makeway.perceive.vision.backbone import BackboneFeatures

            self._net = BackboneFeatures(
                layers=self.layers,
                input_size=self.input_size,
                num_threads=self.num_threads,
                backbone=self.backbone,
            )
        b = np.asarray(boxes, np.float64).reshape(-1, 4)
        if len(b) == 0:
            return np.zeros((0, self._net.dim), np.float32)
        patches = appearance_patches(
            frame_bgr, b, size=self.input_size, context=self.context, min_side_px=self.min_side_px
        )
        return np.asarray(self._net.transform(patches), np.float32)

    def fit(self, vectors: np.ndarray, *, max_rows: int = 50_000, seed: int = 0) -> ProposalAppearance:
        """Learn the standardisation from every row of ``vectors`` ``(n, d)`` and the principal axes
        from at most ``max_rows`` of them (drawn with ``seed``)."""
        v = np.asarray(vectors, np.float64)
        if v.ndim != 2 or len(v) < self.n_components or v.shape[1] < self.n_components:
            raise ValueError(f"need at least {self.n_components} rows and columns, got {v.shape}")
        self.mean_ = v.mean(axis=0)
        self.scale_ = v.std(axis=0) + 1e-6
        z = (v - self.mean_) / self.scale_
        pick = np.random.default_rng(seed).choice(len(z), min(len(z), max_rows), replace=False)
        _, _, vt = np.linalg.svd(z[pick], full_matrices=False)
        self.components_ = vt[: self.n_components].T
        return self

    def project(self, vectors: np.ndarray) -> np.ndarray:
        """Fitted coordinates ``(n, n_components)`` float32 of backbone vectors ``(n, d)``."""
        if self.mean_ is None or self.scale_ is None or self.components_ is None:
            raise ValueError("ProposalAppearance is not fitted")
        v = np.asarray(vectors, np.float64)
        if v.ndim != 2 or v.shape[1] != len(self.mean_):
            raise ValueError(f"expected backbone vectors (n, {len(self.mean_)}), got {v.shape}")
        return (((v - self.mean_) / self.scale_) @ self.components_).astype(np.float32)

    def transform(self, frame_bgr: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """The ``app_*`` columns ``(n, n_components)`` of the proposals ``boxes`` of one frame."""
        return self.project(self.vectors(frame_bgr, boxes))

    def to_json(self) -> str:
        """The settings and fitted state as JSON (the verifier model's ``appearance`` metadata)."""
        if self.mean_ is None or self.scale_ is None or self.components_ is None:
            raise ValueError("ProposalAppearance is not fitted")
        return json.dumps(
            {
                "backbone": self.backbone,
                "layers": list(self.layers),
                "input_size": self.input_size,
                "context": self.context,
                "min_side_px": self.min_side_px,
                "mean": [float(x) for x in self.mean_],
                "scale": [float(x) for x in self.scale_],
                "components": [[float(x) for x in row] for row in self.components_],
            }
        )

    @classmethod
    def from_json(cls, text: str, *, num_threads: int = 1) -> ProposalAppearance:
        """The fitted object :meth:`to_json` wrote; ``ValueError`` when it is malformed."""
        try:
            d = json.loads(text)
            mean = np.asarray(d["mean"], np.float64)
            scale = np.asarray(d["scale"], np.float64)
            comp = np.asarray(d["components"], np.float64)
            out = cls(
                n_components=int(comp.shape[1]),
                backbone=str(d["backbone"]),
                layers=tuple(str(x) for x in d["layers"]),
                input_size=int(d["input_size"]),
                context=float(d["context"]),
                min_side_px=float(d["min_side_px"]),
                num_threads=num_threads,
                mean_=mean,
                scale_=scale,
                components_=comp,
            )
        except (ValueError, TypeError, KeyError, IndexError) as exc:
            raise ValueError(f"malformed appearance settings ({exc})") from None
        from makeway.perceive.vision.backbone import BACKBONES

        spec = BACKBONES.get(out.backbone)
        ok = (
            spec is not None
            and all(layer in spec.layers for layer in out.layers)
            and out.input_size >= 32
            and out.input_size % 32 == 0
            and out.context > 0
            and out.min_side_px > 0
            and mean.ndim == 1
            and scale.shape == mean.shape
            and comp.ndim == 2
            and comp.shape[0] == len(mean)
            and np.isfinite(comp).all()
            and np.isfinite(mean).all()
            and bool((scale > 0).all())
        )
        if not ok:
            raise ValueError("malformed appearance settings (backbone, layers, sizes, shapes or values)")
        return out


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


def _same_patches(a: ProposalAppearance, b: ProposalAppearance) -> bool:
    """Whether two appearance extractors feed the same patches through the same backbone layers
    (their vectors are then interchangeable; only the fitted projections differ)."""
    keys = ("backbone", "layers", "input_size", "context", "min_side_px")
    return all(getattr(a, k) == getattr(b, k) for k in keys)


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
        with_context = FEATURE_NAMES + CONTEXT_FEATURE_NAMES
        #: The appearance columns' extractor (:class:`ProposalAppearance`, from the metadata
        #: ``appearance``) when the model reads them, else None.
        self.appearance: ProposalAppearance | None = None
        if "appearance" in meta:
            try:
                self.appearance = ProposalAppearance.from_json(meta["appearance"], num_threads=num_threads)
            except ValueError as exc:
                raise InputError(path, f"light verifier metadata: {exc}") from None
        with_appearance = with_context + (self.appearance.feature_names if self.appearance else ())
        known = (FEATURE_NAMES, with_context, with_appearance)
        if not isinstance(names, list) or tuple(names) not in known:
            n = len(names) if isinstance(names, list) else 0
            raise InputError(
                path,
                f"its features do not match this code's ({n} vs "
                f"{' or '.join(str(len(k)) for k in dict.fromkeys(known))})",
            )
        #: Column names of the feature rows the model reads.
        self.feature_names: tuple[str, ...] = tuple(names)
        #: Whether the model reads the vehicle-context columns (:func:`context_features`) after the
        #: proposal's own (:func:`verifier_features`).
        self.uses_vehicles = len(names) > len(FEATURE_NAMES)
        #: Whether the model reads the appearance columns (:attr:`appearance`) after the context.
        self.uses_appearance = len(names) > len(with_context)
        if not self.uses_appearance:
            self.appearance = None  # settings in the metadata that no column reads
        if not 0.0 <= threshold <= 1.0:
            raise InputError(path, f"malformed light verifier metadata (threshold {threshold} not in [0, 1])")
        #: For a small-lamp verifier, the size (px, a proposal's longer side) under which it scores
        #: proposals (metadata ``applies_below_px``); None for a main verifier.
        self.applies_below_px: float | None = None
        if "applies_below_px" in meta:
            try:
                below = float(meta["applies_below_px"])
            except ValueError:
                below = float("nan")
            if not below > 0:
                raise InputError(
                    path, f"malformed light verifier metadata (applies_below_px {meta['applies_below_px']!r})"
                )
            self.applies_below_px = below
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
            probe = self.score(np.zeros((2, len(self.feature_names)), np.float32))
            ok = probe.shape == (2,)
        except Exception:  # onnxruntime's own types, or outputs of another layout (IndexError, …)
            ok = False
        if not ok:
            raise InputError(path, "does not give one probability per feature row")

    def score(self, features: np.ndarray) -> np.ndarray:
        """P(lit emergency light) per feature row ``(n, len(self.feature_names))``."""
        return self.score_and_offsets(features)[0]

    def score_and_offsets(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """P(lit emergency light) per feature row and, when the model refines boxes, the predicted
        corrections ``(n, 4)`` (see :func:`refine_boxes`), else None."""
        x = np.asarray(features, np.float32)
        if x.ndim != 2 or x.shape[1] != len(self.feature_names):
            raise ValueError(f"expected features (n, {len(self.feature_names)}), got {x.shape}")
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

    A verifier that reads the vehicle context (:attr:`uses_vehicles`) needs the frame's vehicle
    boxes: pass those the pipeline already found as ``detect(..., vehicles=...)``, else the
    detector runs its own YOLOX-nano (:func:`vehicle_detector`, created on first use). A verifier
    that also reads the proposals' appearance runs YOLOX-nano's backbone on a 64-px patch per
    proposal (:class:`ProposalAppearance`).

    ``small_model`` is the small-lamp verifier (module docstring): by default the shipped one
    beside the shipped main verifier, none beside another main verifier given as ``model``;
    ``False`` turns it off. It must read the same columns as the main verifier but for its appearance
    projection, and carry ``applies_below_px``.
    """

    def __init__(
        self,
        colours: str | Sequence[str] = "eu",
        *,
        model: str | Path | None = None,
        small_model: str | Path | bool | None = None,
        threshold: float | None = None,
        num_threads: int = 1,
    ) -> None:
        from makeway.perceive.vision.lights import colour_set

        self.colours = colour_set(colours)
        self.verifier = LightVerifier(model, num_threads=num_threads)
        if small_model is None:  # the shipped pair, or a main verifier alone
            shipped = model is None or Path(model).resolve() == DEFAULT_VERIFIER_MODEL.resolve()
            small_model = DEFAULT_SMALL_VERIFIER_MODEL if shipped else False
        #: The small-lamp verifier, or None.
        self.small: LightVerifier | None = None
        if small_model is not False and small_model is not True:
            self.small = LightVerifier(small_model, num_threads=num_threads)
            if self.small.applies_below_px is None:
                raise InputError(
                    self.small.path, "not a small-lamp verifier (metadata applies_below_px missing)"
                )
            if len(self.small.feature_names) != len(self.verifier.feature_names) or (
                self.small.uses_appearance != self.verifier.uses_appearance
            ):
                raise InputError(self.small.path, "its feature columns do not match the main verifier's")
        elif small_model is True:
            raise ValueError("small_model must be a model path, None (the default) or False")
        self.threshold = self.verifier.threshold if threshold is None else float(threshold)
        self.num_threads = num_threads
        #: Whether :meth:`detect` uses vehicle boxes (given, or found by its own vehicle detector).
        self.uses_vehicles = self.verifier.uses_vehicles
        self._vehicle_detector: Any = None
        if self.uses_vehicles:  # the appearance columns come after the context: same weights
            # fail at construction, not on the first frame, when the vehicle detector's weights are
            # missing; the detector itself is made on first use (a pipeline passes its own boxes)
            from makeway.perceive.vision.detectors import DETECTORS, resolve_model_path

            resolve_model_path(DETECTORS["yolox_nano"].default_filename, None)

    def vehicles(self, frame_bgr: np.ndarray) -> Vehicles:
        """The frame's vehicle boxes found by this detector's own vehicle detector."""
        if self._vehicle_detector is None:
            self._vehicle_detector = vehicle_detector(self.num_threads)
        boxes, scores, classes = self._vehicle_detector.detect_arrays(frame_bgr)
        return boxes, scores, classes

    def detect(
        self, frame_bgr: np.ndarray, frame: int = 0, *, vehicles: Vehicles | None = None
    ) -> list[LightDetection]:
        """Lit emergency lights in one BGR frame; ``vehicles`` (boxes, scores, COCO class ids of the
        frame, as the vehicle detector's ``detect_arrays`` returns them) spare a context-reading
        verifier its own vehicle detection; other verifiers ignore them."""
        if frame_bgr.ndim != 3 or frame_bgr.shape[2] != 3 or frame_bgr.dtype != np.uint8:
            raise ValueError(f"expected a uint8 BGR image H×W×3, got {frame_bgr.dtype} {frame_bgr.shape}")
        # the context counts the proposals of every colour in a vehicle box (as in training)
        pool = proposals(frame_bgr, COLOURS if self.uses_vehicles else self.colours)
        props = [p for p in pool if p["colour"] in self.colours]
        if not props:
            return []
        x = verifier_features(frame_bgr, props)
        prop_boxes = np.array([p["box"] for p in props], np.float64)
        if self.uses_vehicles:
            veh = vehicles if vehicles is not None else self.vehicles(frame_bgr)
            ctx = context_features(
                prop_boxes,
                [p["colour"] for p in props],
                veh,
                peer_boxes=np.array([p["box"] for p in pool], np.float64),
                peer_colours=[p["colour"] for p in pool],
            )
            x = np.concatenate([x, ctx], axis=1)
        small = np.zeros(len(props), bool)
        if self.small is not None and self.small.applies_below_px is not None:
            side = np.maximum(prop_boxes[:, 2] - prop_boxes[:, 0], prop_boxes[:, 3] - prop_boxes[:, 1])
            small = side < self.small.applies_below_px
        x_small = x[small]
        main_app = self.verifier.appearance
        raw = None
        if main_app is not None:
            raw = main_app.vectors(frame_bgr, prop_boxes)
            x = np.concatenate([x, main_app.project(raw)], axis=1)
        prob, offsets = self.verifier.score_and_offsets(x)
        if self.small is not None and small.any():
            small_app = self.small.appearance
            if small_app is not None:
                # the backbone's vectors are shared when both models cut the same patches
                if raw is not None and main_app is not None and _same_patches(main_app, small_app):
                    extra = small_app.project(raw[small])
                else:
                    extra = small_app.transform(frame_bgr, prop_boxes[small])
                x_small = np.concatenate([x_small, extra], axis=1)
            prob = prob.copy()
            prob[small] = self.small.score(x_small)
            if offsets is not None:  # the small verifier's boxes stay as proposed
                offsets = offsets.copy()
                offsets[small] = 0.0
        sel = np.flatnonzero(prob >= self.threshold)
        if len(sel) == 0:
            return []
        boxes = prop_boxes[sel]
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
