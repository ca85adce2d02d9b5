"""Augmentation of (image, light boxes) pairs for the lit-light detector: geometry that moves the boxes
with the pixels, and photometric changes that leave them alone.

Images are BGR ``uint8`` ``(H, W, 3)``; boxes are ``(n, 4)`` float arrays ``x1, y1, x2, y2`` in pixels of
the image (the frame of :mod:`makeway.messages`: origin at the top-left corner, ``x2``/``y2`` the far
edges). Every geometric transform maps a box through its outline (points sampled along the four
edges) and returns the axis-parallel box of the mapped outline, clipped to the image; a box that
leaves the image (less than ``min_visible`` of its mapped area inside) or shrinks under 1 px is
dropped, and ``keep`` tells which input boxes survive so that per-box attributes (colour, vehicle)
can follow.

Transforms (each takes a :class:`numpy.random.Generator` so runs are reproducible):

* :func:`fisheye` — renders the image as a Kannala–Brandt fisheye camera would see it: the input is
  taken as a pinhole image whose horizontal half field of view is drawn from ``half_fov_deg``; the
  fisheye's coefficients are the default rig's (``src/makeway/data/rig_default.yaml``, front camera)
  each scaled by ``1 + U(-jitter, jitter)`` (``jitter`` < 0.1), and its focal length is chosen so the
  left and right edges of the output are the input's edges (barrel distortion filling the width).
* :func:`affine` — rotation (degrees), isotropic scale (0.8–1.2 by default) about the image centre and
  a shift (fraction of the size).
* :func:`perspective` — each corner moved by up to ``strength`` of the image size.
* :func:`photometric` — contrast and brightness (``out = a·img + b``), then Gaussian noise (σ in
  grey levels); boxes unchanged.
* :func:`night` — a gamma curve ``255·(img/255)^γ``, γ ∈ [1.5, 3]: mid-tones go dark while clipped
  lamps stay bright, the look of a night camera; boxes unchanged.
* :func:`night_lamps` — day → night: the frame darkened (gain 0.2–0.6 after a gamma 1.3–2.2) while
  the labelled lamps (a soft ellipse 1.6× their box) and every clipped pixel (V ≥ 230, dilated:
  headlights, tail lights, reflections stay bright at night too) keep or raise their brightness,
  plus a halo (the lamps blurred and added); boxes unchanged.
* :func:`paste_lamps` — copies real lit-lamp patches (a labelled box with its halo, from
  :func:`lamp_patches`) onto the image with a feathered "lighten" blend, scaled 0.6–1.5×, the red
  and blue channels swapped with probability 0.3; returns the new boxes appended.
* :func:`swap_red_blue` — exchanges the red and blue channels, so a lit red lamp becomes a lit blue
  one (and the reverse) with its glow and clipped core; for a one-class lit-light detector this
  carries lamps of one colour to the other; boxes unchanged.

:func:`augment` chains them with probabilities (:class:`AugmentConfig`). numpy and OpenCV only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from makeway.sense.camera import KannalaBrandtCamera

__all__ = [
    "AugmentConfig",
    "affine",
    "augment",
    "default_fisheye_k",
    "fisheye",
    "lamp_patches",
    "map_boxes",
    "night",
    "night_lamps",
    "paste_lamps",
    "perspective",
    "photometric",
    "swap_red_blue",
]

_OUTLINE_POINTS = 8  # samples per box edge


@lru_cache(maxsize=1)
def default_fisheye_k() -> tuple[float, float, float, float]:
    """k1..k4 of the default rig's front camera (the lens the augmentation imitates)."""
    from makeway.sense.rig import load_rig

    rig = load_rig("default")
    cam = rig.cameras[0].camera
    return tuple(float(c) for c in cam.k)  # type: ignore[return-value]


def _as_boxes(boxes: np.ndarray) -> np.ndarray:
    b = np.asarray(boxes, dtype=np.float64)
    if b.size == 0:
        return np.zeros((0, 4))
    if b.ndim != 2 or b.shape[1] != 4:
        raise ValueError(f"boxes must be (n, 4) x1, y1, x2, y2; got shape {b.shape}")
    return b


def _check_image(image: np.ndarray) -> None:
    if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        got = f"{image.dtype} {image.shape}" if isinstance(image, np.ndarray) else type(image).__name__
        raise ValueError(f"expected a uint8 BGR image H×W×3, got {got}")


def _outline(boxes: np.ndarray) -> np.ndarray:
    """``(n, 4·P, 2)`` points along each box's edges."""
    t = np.linspace(0.0, 1.0, _OUTLINE_POINTS)
    x1, y1, x2, y2 = (boxes[:, i : i + 1] for i in range(4))
    top = np.stack([x1 + (x2 - x1) * t, np.broadcast_to(y1, (len(boxes), len(t)))], -1)
    bottom = np.stack([x1 + (x2 - x1) * t, np.broadcast_to(y2, (len(boxes), len(t)))], -1)
    left = np.stack([np.broadcast_to(x1, (len(boxes), len(t))), y1 + (y2 - y1) * t], -1)
    right = np.stack([np.broadcast_to(x2, (len(boxes), len(t))), y1 + (y2 - y1) * t], -1)
    return np.concatenate([top, bottom, left, right], axis=1)


def map_boxes(
    boxes: np.ndarray,
    forward: object,
    width: int,
    height: int,
    *,
    min_visible: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Map boxes through a point transform: ``forward`` takes ``(m, 2)`` source pixels and returns
    ``(m, 2)`` output pixels (NaN where a point has no image). Returns the axis-parallel boxes of the
    mapped outlines clipped to ``width × height`` and the boolean ``keep`` mask of the input boxes that
    survive (see the module docstring)."""
    b = _as_boxes(boxes)
    if len(b) == 0:
        return np.zeros((0, 4)), np.zeros(0, bool)
    pts = _outline(b)
    mapped = np.asarray(forward(pts.reshape(-1, 2)), dtype=np.float64).reshape(pts.shape)  # type: ignore[operator]
    bad = ~np.isfinite(mapped).all(axis=(1, 2))
    mapped = np.nan_to_num(mapped)
    out = np.stack(
        [mapped[..., 0].min(1), mapped[..., 1].min(1), mapped[..., 0].max(1), mapped[..., 1].max(1)], -1
    )
    area = np.clip(out[:, 2] - out[:, 0], 0, None) * np.clip(out[:, 3] - out[:, 1], 0, None)
    clipped = out.copy()
    clipped[:, [0, 2]] = np.clip(out[:, [0, 2]], 0, width)
    clipped[:, [1, 3]] = np.clip(out[:, [1, 3]], 0, height)
    w = clipped[:, 2] - clipped[:, 0]
    h = clipped[:, 3] - clipped[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        visible = np.where(area > 0, w * h / area, 0.0)
    keep = ~bad & (visible >= min_visible) & (w >= 1) & (h >= 1)
    return clipped[keep], keep


def fisheye(
    image: np.ndarray,
    boxes: np.ndarray,
    rng: np.random.Generator,
    *,
    jitter: float = 0.09,
    half_fov_deg: tuple[float, float] = (45.0, 70.0),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The image seen through a Kannala–Brandt fisheye (module docstring): ``(image, boxes, keep)``.

    ``jitter`` (< 0.1) is the largest relative change of each of the rig's k1..k4; the output keeps
    the input's size and principal point at its centre; pixels outside the input are black."""
    _check_image(image)
    if not 0 <= jitter < 0.1:
        raise ValueError(f"jitter must be in [0, 0.1), got {jitter}")
    h, w = image.shape[:2]
    k = tuple(c * (1.0 + rng.uniform(-jitter, jitter)) for c in default_fisheye_k())
    half = math.radians(rng.uniform(*half_fov_deg))
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    f_pin = (w / 2.0) / math.tan(half)
    probe = KannalaBrandtCamera(w, h, 1.0, 1.0, 0.0, 0.0, k)  # type: ignore[arg-type]
    f_fish = (w / 2.0) / float(probe.theta_d(half))
    cam = KannalaBrandtCamera(w, h, f_fish, f_fish, cx, cy, k)  # type: ignore[arg-type]
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = cam.unproject(np.stack([uu, vv], -1))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = rays[..., 2]
        ok = z > 1e-6
        map_x = np.where(ok, f_pin * rays[..., 0] / z + cx, -1.0).astype(np.float32)
        map_y = np.where(ok, f_pin * rays[..., 1] / z + cy, -1.0).astype(np.float32)
    map_x = np.nan_to_num(map_x, nan=-1.0)
    map_y = np.nan_to_num(map_y, nan=-1.0)
    out = cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def forward(p: np.ndarray) -> np.ndarray:
        pts = np.stack([(p[:, 0] - cx) / f_pin, (p[:, 1] - cy) / f_pin, np.ones(len(p))], -1)
        return cam.project(pts)

    new, keep = map_boxes(boxes, forward, w, h)
    return out, new, keep


def _warp_points(matrix: np.ndarray) -> object:
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape == (2, 3):
        m = np.vstack([m, [0.0, 0.0, 1.0]])

    def forward(p: np.ndarray) -> np.ndarray:
        q = np.c_[p, np.ones(len(p))] @ m.T
        return q[:, :2] / q[:, 2:3]

    return forward


def affine(
    image: np.ndarray,
    boxes: np.ndarray,
    rng: np.random.Generator,
    *,
    max_rotation_deg: float = 5.0,
    scale: tuple[float, float] = (0.8, 1.2),
    max_shift: float = 0.05,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotation ±``max_rotation_deg``, scale ×U(``scale``) about the centre and a shift of up to
    ``max_shift`` of the size: ``(image, boxes, keep)``; uncovered pixels are black."""
    _check_image(image)
    h, w = image.shape[:2]
    m = cv2.getRotationMatrix2D(
        ((w - 1) / 2.0, (h - 1) / 2.0),
        float(rng.uniform(-max_rotation_deg, max_rotation_deg)),
        float(rng.uniform(*scale)),
    )
    m[0, 2] += rng.uniform(-max_shift, max_shift) * w
    m[1, 2] += rng.uniform(-max_shift, max_shift) * h
    out = cv2.warpAffine(image, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    new, keep = map_boxes(boxes, _warp_points(m), w, h)
    return out, new, keep


def perspective(
    image: np.ndarray, boxes: np.ndarray, rng: np.random.Generator, *, strength: float = 0.06
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random homography moving each image corner by up to ``strength`` of the image size:
    ``(image, boxes, keep)``."""
    _check_image(image)
    h, w = image.shape[:2]
    src = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], np.float32)
    dst = src + rng.uniform(-strength, strength, (4, 2)).astype(np.float32) * np.array([w, h], np.float32)
    m = cv2.getPerspectiveTransform(src, dst.astype(np.float32))
    out = cv2.warpPerspective(image, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    new, keep = map_boxes(boxes, _warp_points(m), w, h)
    return out, new, keep


def photometric(
    image: np.ndarray,
    rng: np.random.Generator,
    *,
    contrast: tuple[float, float] = (0.7, 1.3),
    brightness: tuple[float, float] = (-30.0, 30.0),
    noise_sigma: tuple[float, float] = (0.0, 6.0),
) -> np.ndarray:
    """``a·image + b`` with ``a`` ~ U(``contrast``), ``b`` ~ U(``brightness``) grey levels, plus Gaussian
    noise of σ ~ U(``noise_sigma``) grey levels; clipped to 0–255, ``uint8``."""
    _check_image(image)
    a = rng.uniform(*contrast)
    b = rng.uniform(*brightness)
    x = image.astype(np.float32) * a + b
    sigma = rng.uniform(*noise_sigma)
    if sigma > 0:
        x += rng.normal(0.0, sigma, image.shape).astype(np.float32)
    return np.clip(x, 0, 255).astype(np.uint8)


def night(
    image: np.ndarray, rng: np.random.Generator, *, gamma: tuple[float, float] = (1.5, 3.0)
) -> np.ndarray:
    """``255·(image/255)^γ`` with γ ~ U(``gamma``): darker mid-tones, bright lamps kept (``uint8``)."""
    _check_image(image)
    g = rng.uniform(*gamma)
    lut = np.clip(255.0 * (np.arange(256) / 255.0) ** g + 0.5, 0, 255).astype(np.uint8)
    out: np.ndarray = cv2.LUT(image, lut)
    return out


def _soft_box_mask(shape: tuple[int, int], boxes: np.ndarray, grow: float) -> np.ndarray:
    """``float32`` mask ``(h, w)``: 1 inside ellipses ``grow`` times each box, feathered by a blur."""
    h, w = shape
    m = np.zeros((h, w), np.float32)
    for x1, y1, x2, y2 in boxes:
        cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
        ax, ay = max(1.5, grow * (x2 - x1) / 2), max(1.5, grow * (y2 - y1) / 2)
        cv2.ellipse(m, (round(cx), round(cy)), (round(ax), round(ay)), 0, 0, 360, 1.0, -1)
    if len(boxes):
        blurred: np.ndarray = cv2.GaussianBlur(m, (0, 0), 1.5)
        return blurred
    return m


def night_lamps(
    image: np.ndarray,
    boxes: np.ndarray,
    rng: np.random.Generator,
    *,
    gain: tuple[float, float] = (0.2, 0.6),
    gamma: tuple[float, float] = (1.3, 2.2),
) -> np.ndarray:
    """Day → night (module docstring): everything darkened except the lamps in ``boxes`` and the
    clipped pixels, which keep (×1–1.3) their brightness and get a blurred halo. ``uint8``."""
    _check_image(image)
    b = _as_boxes(boxes)
    x = image.astype(np.float32)
    g = rng.uniform(*gamma)
    dark = 255.0 * rng.uniform(*gain) * (x / 255.0) ** g
    v = image.max(axis=2)
    bright = cv2.dilate((v >= 230).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(np.float32)
    m = np.maximum(_soft_box_mask(image.shape[:2], b, 1.6), cv2.GaussianBlur(bright, (0, 0), 1.0))
    lit = np.minimum(x * rng.uniform(1.0, 1.3), 255.0) * m[..., None]
    out = dark * (1.0 - m[..., None]) + lit
    if len(b):
        size = float(np.median(np.maximum(b[:, 2] - b[:, 0], b[:, 3] - b[:, 1])))
        halo = cv2.GaussianBlur(lit, (0, 0), max(1.0, 0.6 * size))
        out = out + rng.uniform(0.2, 0.6) * halo
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def lamp_patches(
    images: list[np.ndarray], boxes: list[np.ndarray], *, margin: float = 0.75, max_side: int = 64
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Lit-lamp patches for :func:`paste_lamps`: each labelled box of each image grown by ``margin``
    times its size per side (at least 3 px: the halo), as ``(patch BGR uint8, box in the patch)``;
    boxes whose patch would exceed ``max_side`` px or leave the image are skipped."""
    out: list[tuple[np.ndarray, np.ndarray]] = []
    for img, bs in zip(images, boxes, strict=True):
        h, w = img.shape[:2]
        for x1, y1, x2, y2 in _as_boxes(bs):
            mx, my = max(3.0, margin * (x2 - x1)), max(3.0, margin * (y2 - y1))
            a, c = int(np.floor(x1 - mx)), int(np.ceil(x2 + mx))
            b_, d = int(np.floor(y1 - my)), int(np.ceil(y2 + my))
            if (
                a < 0
                or b_ < 0
                or c > w
                or d > h
                or max(c - a, d - b_) > max_side
                or min(x2 - x1, y2 - y1) < 2
            ):
                continue
            out.append((img[b_:d, a:c].copy(), np.array([x1 - a, y1 - b_, x2 - a, y2 - b_], np.float64)))
    return out


def paste_lamps(
    image: np.ndarray,
    boxes: np.ndarray,
    patches: list[tuple[np.ndarray, np.ndarray]],
    rng: np.random.Generator,
    *,
    count: tuple[int, int] = (1, 3),
    scale: tuple[float, float] = (0.6, 1.5),
) -> tuple[np.ndarray, np.ndarray]:
    """``count`` random patches of ``patches`` pasted onto ``image`` (module docstring). Half of the
    pastes go beside an existing lamp (same height ± its size, 1–4 of its widths left or right, as
    on a light bar), the rest anywhere. Returns ``(image, boxes with the pasted lamps appended)``."""
    _check_image(image)
    b = _as_boxes(boxes).copy()
    if not patches:
        return image, b
    img = image.astype(np.float32)
    h, w = image.shape[:2]
    new: list[np.ndarray] = []
    for _ in range(int(rng.integers(count[0], count[1] + 1))):
        patch, pbox = patches[int(rng.integers(len(patches)))]
        f = rng.uniform(*scale)
        ph, pw = max(3, round(patch.shape[0] * f)), max(3, round(patch.shape[1] * f))
        if ph >= h or pw >= w:
            continue
        p = cv2.resize(patch, (pw, ph), interpolation=cv2.INTER_LINEAR)
        if rng.random() < 0.3:
            p = p[..., ::-1]
        pb = pbox * np.array([pw / patch.shape[1], ph / patch.shape[0]] * 2)
        if len(b) and rng.random() < 0.5:
            ref = b[int(rng.integers(len(b)))]
            rw = max(2.0, ref[2] - ref[0])
            cx = (ref[0] + ref[2]) / 2 + rng.choice([-1.0, 1.0]) * rng.uniform(1.0, 4.0) * rw
            cy = (ref[1] + ref[3]) / 2 + rng.uniform(-1.0, 1.0) * (ref[3] - ref[1])
            x0, y0 = round(cx - pw / 2), round(cy - ph / 2)
        else:
            x0, y0 = int(rng.integers(0, w - pw + 1)), int(rng.integers(0, h - ph + 1))
        x0, y0 = int(np.clip(x0, 0, w - pw)), int(np.clip(y0, 0, h - ph))
        yy, xx = np.mgrid[0:ph, 0:pw].astype(np.float32)
        r = np.sqrt(((xx + 0.5) / pw - 0.5) ** 2 + ((yy + 0.5) / ph - 0.5) ** 2) * 2.0
        alpha = np.clip((1.0 - r) / 0.4, 0.0, 1.0)[..., None]
        region = img[y0 : y0 + ph, x0 : x0 + pw]
        img[y0 : y0 + ph, x0 : x0 + pw] = region * (1 - alpha) + np.maximum(region, p) * alpha
        new.append(pb + np.array([x0, y0, x0, y0], np.float64))
    if new:
        b = np.concatenate([b.reshape(-1, 4), np.stack(new)])
    return np.clip(img + 0.5, 0, 255).astype(np.uint8), b


def swap_red_blue(image: np.ndarray) -> np.ndarray:
    """The image with its red and blue channels exchanged (BGR → RGB order)."""
    _check_image(image)
    return np.ascontiguousarray(image[..., ::-1])


@dataclass(frozen=True)
class AugmentConfig:
    """Probabilities of each transform in :func:`augment` (0 turns one off)."""

    p_fisheye: float = 0.3
    p_affine: float = 0.6
    p_perspective: float = 0.3
    p_photometric: float = 0.8
    p_flip: float = 0.5
    p_swap_red_blue: float = 0.0
    p_night: float = 0.0
    p_night_lamps: float = 0.0


def augment(
    image: np.ndarray, boxes: np.ndarray, rng: np.random.Generator, config: AugmentConfig | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One random augmentation: horizontal flip, fisheye, affine, perspective (each with its
    probability), then red↔blue swap, night gamma, night with lamps kept and photometric (each with
    its probability).
    Returns ``(image, boxes, keep)``, ``keep`` indexing the input boxes that survive."""
    cfg = config or AugmentConfig()
    _check_image(image)
    b = _as_boxes(boxes)
    keep = np.ones(len(b), bool)
    idx = np.arange(len(b))
    img = image
    w = img.shape[1]
    if rng.random() < cfg.p_flip:
        img = np.ascontiguousarray(img[:, ::-1])
        b = b.copy()
        b[:, [0, 2]] = w - b[:, [2, 0]]
    for p, fn in ((cfg.p_fisheye, fisheye), (cfg.p_affine, affine), (cfg.p_perspective, perspective)):
        if rng.random() < p:
            img, b, k = fn(img, b, rng)
            idx = idx[k]
    if cfg.p_swap_red_blue > 0 and rng.random() < cfg.p_swap_red_blue:  # no draw when off
        img = swap_red_blue(img)
    if cfg.p_night > 0 and rng.random() < cfg.p_night:
        img = night(img, rng)
    if cfg.p_night_lamps > 0 and rng.random() < cfg.p_night_lamps:
        img = night_lamps(img, b, rng)
    if rng.random() < cfg.p_photometric:
        img = photometric(img, rng)
    keep[:] = False
    keep[idx] = True
    return img, b, keep
