"""Hand-made lit-light finder: colour, brightness and flashing cues on one BGR frame.

The rule-based detector behind ``LIGHT_DETECTORS["colour"]`` and the proposal engine of the lit-light
labelling tool. :func:`propose` boxes candidate lit emergency lights in one frame from two cues —
*colour* (HSV masks per colour, :data:`DEFAULT_HSV`) and *brightness* (a saturated near-white core
ringed by a coloured halo, how a lit bulb looks to a camera at night). :func:`lit_maps` and
:func:`flash_score` give the third cue, *flashing*: the same region's coloured brightness switching
on and off within a window of about 0.25–1 s. Boxes are integer pixels of the source frame, ``x2``
and ``y2`` exclusive.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = [
    "COLOURS",
    "DEFAULT_HSV",
    "HSV_PRESETS",
    "WIDE_HSV",
    "Proposal",
    "ProposalConfig",
    "colour_masks",
    "flash_score",
    "lit_maps",
    "propose",
]

#: Colour attribute of a light box; also the YOLO class index order of the label export.
COLOURS: tuple[str, ...] = ("blue", "red", "amber", "white")

#: HSV ranges per colour in OpenCV units (H 0–179, S and V 0–255): a list of
#: ``(h_low, h_high, s_min, v_min)``; a pixel is of the colour when it falls in any range.
#: Blue includes the violet cast of blue LEDs seen through a night-tuned camera; red wraps around 0.
DEFAULT_HSV: dict[str, list[tuple[int, int, int, int]]] = {
    "blue": [(100, 140, 90, 140)],
    "red": [(0, 7, 120, 150), (170, 179, 120, 150)],
    "amber": [(8, 28, 120, 170)],
    "white": [(0, 179, 0, 250)],
}

#: Wider hue ranges for clips whose lamps fall between the default ranges: red takes hue 0–10 and the
#: magenta/pink band 141–179 (a red or blue-red lamp blooming pink in a night camera; 141–169 is left
#: out of :data:`DEFAULT_HSV`), and amber starts at 11 so that a red lamp whose glow turns orange is
#: proposed as amber (its colour is set by eye when checked). Chosen with ``propose --hue wide``.
WIDE_HSV: dict[str, list[tuple[int, int, int, int]]] = {
    "blue": [(100, 140, 90, 140)],
    "red": [(0, 10, 120, 150), (141, 179, 120, 150)],
    "amber": [(11, 28, 120, 170)],
    "white": [(0, 179, 0, 250)],
}

#: Named hue-range presets of ``makeway light-labels propose --hue``.
HSV_PRESETS: dict[str, dict[str, list[tuple[int, int, int, int]]]] = {
    "default": DEFAULT_HSV,
    "wide": WIDE_HSV,
}


@dataclass(frozen=True)
class ProposalConfig:
    """Settings of :func:`propose`.

    Attributes:
        colours: colours proposed from their HSV mask alone; ``white`` is proposed only through the
            brightness cue (a white mask alone would box every headlight and street lamp).
        hsv: the HSV ranges per colour (:data:`DEFAULT_HSV`).
        core_v: a pixel with value ≥ this and saturation ≤ ``core_s_max`` is a saturated core.
        core_s_max: see ``core_v``.
        halo_px: width (pixels) of the ring around a core searched for a coloured halo.
        halo_fraction: a core takes a colour when at least this fraction of its ring has it.
        merge_px: coloured regions closer than this (pixels) merge into one box (one shared glow).
        min_area_px: smaller merged regions are dropped (pixels of the source frame).
        max_area_fraction: larger regions (of the frame area) are dropped: a lit light is small, and
            a big coloured patch is a sign, a wall or a reflection.
    """

    colours: tuple[str, ...] = ("blue", "red")
    hsv: dict[str, list[tuple[int, int, int, int]]] = field(default_factory=lambda: dict(DEFAULT_HSV))
    core_v: int = 245
    core_s_max: int = 80
    halo_px: int = 4
    halo_fraction: float = 0.25
    merge_px: int = 3
    min_area_px: int = 12
    max_area_fraction: float = 0.03


@dataclass(frozen=True)
class Proposal:
    """One candidate lit-light box in a frame (pixels of the source, ``x2``/``y2`` exclusive).

    ``cues`` names what found it: ``colour`` (its HSV mask), ``core`` (a saturated core with a
    coloured halo) and ``flash`` (set by :func:`flash_score` when the region toggles).
    """

    frame: int
    x1: int
    y1: int
    x2: int
    y2: int
    colour: str
    score: float
    cues: tuple[str, ...]

    @property
    def box(self) -> tuple[int, int, int, int]:
        return self.x1, self.y1, self.x2, self.y2


def colour_masks(
    frame_bgr: np.ndarray, hsv: dict[str, list[tuple[int, int, int, int]]]
) -> dict[str, np.ndarray]:
    """Colour name → boolean mask (H×W) of the pixels in that colour's HSV ranges."""
    img = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2HSV)
    h, s, v = img[..., 0], img[..., 1], img[..., 2]
    out = {}
    for name, ranges in hsv.items():
        m = np.zeros(h.shape, bool)
        for h_lo, h_hi, s_min, v_min in ranges:
            m |= (h >= h_lo) & (h <= h_hi) & (s >= s_min) & (v >= v_min)
        out[name] = m
    return out


def _components(mask: np.ndarray, merge_px: int) -> list[tuple[int, int, int, int, int]]:
    """Boxes ``(x1, y1, x2, y2, area)`` of the connected regions of ``mask`` after closing gaps up to
    ``merge_px`` pixels; the box and area are of the original mask pixels in each merged region."""
    m = mask.astype(np.uint8)
    merged = m
    if merge_px > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * merge_px + 1, 2 * merge_px + 1))
        merged = np.asarray(cv2.dilate(m, k), np.uint8)
    n, lab = cv2.connectedComponents(merged, connectivity=8)
    out: list[tuple[int, int, int, int, int]] = []
    if n <= 1:
        return out
    ys, xs = np.nonzero(m)
    ids = lab[ys, xs]
    for i in range(1, n):
        sel = ids == i
        if not sel.any():
            continue
        x, y = xs[sel], ys[sel]
        out.append((int(x.min()), int(y.min()), int(x.max()) + 1, int(y.max()) + 1, int(sel.sum())))
    return out


def propose(frame_bgr: np.ndarray, config: ProposalConfig | None = None, frame: int = 0) -> list[Proposal]:
    """Candidate lit-light boxes in one BGR frame, from the colour and brightness cues.

    Colour cue: each colour of ``config.colours`` gives a mask (saturated cores excluded); its regions,
    merged across gaps of ``merge_px``, become boxes (cue ``colour``). Brightness cue: saturated cores
    (near-white, very bright: a lit bulb's centre clips to white while its glow carries the colour)
    whose ring of ``halo_px`` pixels is at least ``halo_fraction`` of one colour take that colour. A
    core inside a small coloured region (the region's box at most 6 times the core's) joins it (cues
    ``colour`` and ``core``); a core inside a large glow, or with a glow too large to keep, is its own
    box (cue ``core``): the lit part of a bright light whose bloom fills its surroundings. A core ringed
    by nothing coloured is a ``white`` proposal only when ``white`` is in ``config.colours``. Regions
    below ``min_area_px`` or above ``max_area_fraction`` of the frame are dropped. The score is the
    mean HSV value (0–1) of the lit pixels times the fraction of the box they fill. Sorted left to
    right.
    """
    cfg = config or ProposalConfig()
    h, w = frame_bgr.shape[:2]
    masks = colour_masks(frame_bgr, cfg.hsv)
    hsv = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2HSV)
    core = (hsv[..., 2] >= cfg.core_v) & (hsv[..., 1] <= cfg.core_s_max)
    value = hsv[..., 2].astype(np.float32) / 255.0
    used = {c: masks[c] & ~core for c in cfg.colours if c != "white"}
    cue_core = {c: np.zeros((h, w), bool) for c in used}
    white_cores = np.zeros((h, w), bool)
    if core.any():
        n, lab, stats, _ = cv2.connectedComponentsWithStats(core.astype(np.uint8), connectivity=8)
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * cfg.halo_px + 1, 2 * cfg.halo_px + 1))
        for i in range(1, n):
            x, y, bw, bh, area = stats[i]
            if area * 1.0 > cfg.max_area_fraction * h * w:
                continue
            x0, y0 = max(0, x - cfg.halo_px), max(0, y - cfg.halo_px)
            x1, y1 = min(w, x + bw + cfg.halo_px), min(h, y + bh + cfg.halo_px)
            blob = (lab[y0:y1, x0:x1] == i).astype(np.uint8)
            ring = cv2.dilate(blob, k).astype(bool) & ~blob.astype(bool)
            if not ring.any():
                continue
            best, frac = "", 0.0
            for c in used:
                f = float(masks[c][y0:y1, x0:x1][ring].mean())
                if f > frac:
                    best, frac = c, f
            if best and frac >= cfg.halo_fraction:
                cue_core[best][y0:y1, x0:x1] |= blob.astype(bool)
            else:
                white_cores[y0:y1, x0:x1] |= blob.astype(bool)
    if "white" in cfg.colours:
        cue_core["white"] = white_cores
    out: list[Proposal] = []
    for c, cores in cue_core.items():
        core_boxes = [b for b in _components(cores, cfg.merge_px) if b[4] >= max(1, cfg.min_area_px // 3)]
        merged_cores: set[int] = set()
        for x1, y1, x2, y2, area in _components(used.get(c, np.zeros((h, w), bool)), cfg.merge_px):
            box_area = (x2 - x1) * (y2 - y1)
            if area < cfg.min_area_px or box_area > cfg.max_area_fraction * h * w:
                continue
            cues: tuple[str, ...] = ("colour",)
            inside = [
                i
                for i, b in enumerate(core_boxes)
                if b[0] < x2
                and b[2] > x1
                and b[1] < y2
                and b[3] > y1
                and box_area <= 6 * (b[2] - b[0]) * (b[3] - b[1])
            ]
            for i in inside:  # a small coloured ring around a core: one light, core and glow
                x1, y1 = min(x1, core_boxes[i][0]), min(y1, core_boxes[i][1])
                x2, y2 = max(x2, core_boxes[i][2]), max(y2, core_boxes[i][3])
                merged_cores.add(i)
                cues = ("colour", "core")
            lit = used[c][y1:y2, x1:x2] | cores[y1:y2, x1:x2]
            score = float(value[y1:y2, x1:x2][lit].mean()) * float(lit.mean())
            out.append(Proposal(frame, x1, y1, x2, y2, c, round(score, 4), cues))
        for i, (x1, y1, x2, y2, _area) in enumerate(core_boxes):
            if i in merged_cores:
                continue  # a core inside a large glow is its own box: the lit part of the light
            lit = cores[y1:y2, x1:x2]
            score = float(value[y1:y2, x1:x2][lit].mean()) * float(lit.mean())
            out.append(Proposal(frame, x1, y1, x2, y2, c, round(score, 4), ("core",)))
    return sorted(out, key=lambda p: (p.x1, p.y1))


def lit_maps(frame_bgr: np.ndarray, config: ProposalConfig | None = None, cell: int = 8) -> np.ndarray:
    """Per colour of ``config.colours`` (in order), the fraction of each ``cell``×``cell`` block that is
    lit in that colour: an array ``(colours, H // cell, W // cell)`` in 0–1, the input of
    :func:`flash_score`."""
    cfg = config or ProposalConfig()
    masks = colour_masks(frame_bgr, cfg.hsv)
    h, w = frame_bgr.shape[:2]
    gh, gw = h // cell, w // cell
    out = np.zeros((len(cfg.colours), gh, gw), np.float32)
    for i, c in enumerate(cfg.colours):
        m = masks[c][: gh * cell, : gw * cell].astype(np.float32)
        out[i] = m.reshape(gh, cell, gw, cell).mean(axis=(1, 3))
    return out


def flash_score(
    history: Sequence[np.ndarray],
    proposal: Proposal,
    colour_index: int,
    cell: int = 8,
    on: float = 0.15,
    off: float = 0.03,
) -> int:
    """How many times the proposal's region switched between lit and dark over ``history``.

    ``history`` is a window of :func:`lit_maps` arrays (about 0.25–1 s of consecutive frames, the
    proposal's own frame among them). The region is the proposal's box in grid cells, widened by one
    cell so a light that moves a little stays inside. Per frame, the region is *on* when its
    brightest cell has at least ``on`` of its area lit in the colour, *off* when it has at most
    ``off``; the count is the number of on↔off changes (hysteresis: in-between frames keep the last
    state). A steady light (brake light, street lamp) counts 0; a light bar flashing at 1–4 Hz counts
    at least 1 in a 0.5 s window.
    """
    gx1, gy1 = max(0, proposal.x1 // cell - 1), max(0, proposal.y1 // cell - 1)
    gx2, gy2 = proposal.x2 // cell + 2, proposal.y2 // cell + 2
    state: bool | None = None
    changes = 0
    for maps in history:
        region = maps[colour_index, gy1:gy2, gx1:gx2]
        level = float(region.max()) if region.size else 0.0
        new = True if level >= on else False if level <= off else state
        if state is not None and new is not None and new != state:
            changes += 1
        if new is not None:
            state = new
    return changes
