"""A camera's intrinsics from chessboard images (OpenCV's calibration, fisheye or pinhole).

Each image shows a flat chessboard; ``board`` counts its **inner** corners (columns × rows, e.g.
9×6 for a board of 10×7 squares) and ``square_m`` is a square's side in metres. The corners are found
(``cv2.findChessboardCorners``, refined to sub-pixel accuracy), and the intrinsics fitted to all
images at once: ``cv2.fisheye.calibrate`` for ``kannala_brandt`` (fx, fy, cx, cy, k1..k4; no skew),
``cv2.calibrateCamera`` for ``pinhole`` (fx, fy, cx, cy; distortion held at zero, as the pinhole
model has none). The RMS reprojection error (pixels) says how well the model fits the corners.

Pixel coordinates follow OpenCV (the centre of the top-left pixel is ``(0, 0)``), as in
:mod:`makeway.sense.camera`. The fisheye fit starts from an equidistant lens whose image width spans
180° (``f = width / π``) and the image centre, then from OpenCV's own start; the better fit is kept.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from makeway.errors import InputError
from makeway.sense.camera import CAMERA_MODELS, Camera

__all__ = ["MIN_VIEWS", "ChessboardCalibration", "calibrate_chessboards", "find_chessboard"]

#: Images with a found board needed for a fit.
MIN_VIEWS = 3


@dataclass(frozen=True)
class ChessboardCalibration:
    """The fitted ``camera``, its RMS reprojection error (pixels), the images whose board was used
    and those without a board found."""

    camera: Camera
    rms_px: float
    used: list[Path]
    rejected: list[Path] = field(default_factory=list)


def find_chessboard(gray: np.ndarray, board: tuple[int, int]) -> np.ndarray | None:
    """The board's inner corners ``(N, 2)`` (pixels, row by row) in a grey image, or ``None``."""
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(gray, board, flags=flags)
    if not found:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    corners = cv2.cornerSubPix(gray, corners, (7, 7), (-1, -1), criteria)
    return np.asarray(corners, dtype=np.float64).reshape(-1, 2)


def calibrate_chessboards(
    images: Sequence[str | Path],
    board: tuple[int, int] = (9, 6),
    square_m: float = 0.025,
    model: str = "kannala_brandt",
) -> ChessboardCalibration:
    """Fit ``model``'s intrinsics to the chessboards in ``images`` (module docstring).

    Raises:
        InputError: an image cannot be read or differs in size from the first, or fewer than
            :data:`MIN_VIEWS` images show the board.
        ValueError: a bad ``board``, ``square_m`` or ``model`` (the model's name is checked first).
    """
    factory = CAMERA_MODELS[model]
    if len(board) != 2 or min(board) < 2:
        raise ValueError(f"the board needs at least 2×2 inner corners, not {board}")
    if not (square_m > 0 and math.isfinite(square_m)):
        raise ValueError(f"the square size must be positive, not {square_m}")
    if not images:
        raise ValueError("no images given")
    cols, rows = board
    grid = np.array([[c * square_m, r * square_m, 0.0] for r in range(rows) for c in range(cols)])
    size: tuple[int, int] | None = None
    corners: list[np.ndarray] = []
    used: list[Path] = []
    rejected: list[Path] = []
    for item in images:
        path = Path(item)
        if not path.is_file():
            raise InputError(path, "image not found")
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            raise InputError(path, "cannot be read as an image")
        h, w = gray.shape
        if size is None:
            size = (w, h)
        elif size != (w, h):
            raise InputError(
                path, f"is {w}×{h} px, the first image {size[0]}×{size[1]}; one camera, one size"
            )
        found = find_chessboard(gray, board)
        if found is None:
            rejected.append(path)
        else:
            corners.append(found)
            used.append(path)
    assert size is not None
    if len(used) < MIN_VIEWS:
        raise InputError(
            Path(images[0]).parent,
            f"a {cols}×{rows} chessboard was found in {len(used)} of {len(images)} images; "
            f"at least {MIN_VIEWS} are needed (check --board: inner corners, columns×rows)",
        )
    if model == "kannala_brandt":
        rms, K, k = _fit_fisheye(grid, corners, size, used[0].parent)
    else:
        rms, K, k = _fit_pinhole(grid, corners, size)
    w, h = size
    k1, k2, k3, k4 = (float(c) for c in k)
    camera = factory(w, h, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), (k1, k2, k3, k4))
    return ChessboardCalibration(camera, float(rms), used, rejected)


def _fit_fisheye(
    grid: np.ndarray, corners: list[np.ndarray], size: tuple[int, int], where: Path
) -> tuple[float, np.ndarray, np.ndarray]:
    obj = [grid.reshape(1, -1, 3)] * len(corners)
    img = [c.reshape(1, -1, 2) for c in corners]
    w, h = size
    base = cv2.fisheye.CALIB_RECOMPUTE_EXTRINSIC | cv2.fisheye.CALIB_FIX_SKEW
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    starts = [
        (
            base | cv2.fisheye.CALIB_USE_INTRINSIC_GUESS,
            np.array([[w / math.pi, 0, (w - 1) / 2], [0, w / math.pi, (h - 1) / 2], [0, 0, 1.0]]),
        ),
        (base, np.eye(3)),
    ]
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    problem = ""
    for flags, K0 in starts:
        try:
            rms, K, D, _, _ = cv2.fisheye.calibrate(
                obj, img, size, K0.copy(), np.zeros(4), flags=flags, criteria=criteria
            )
        except cv2.error as exc:
            problem = str(exc).strip().splitlines()[-1]
            continue
        if K[0, 0] > 0 and K[1, 1] > 0 and (best is None or rms < best[0]):
            best = (float(rms), K, D.ravel())
    if best is None:
        raise InputError(
            where,
            f"the fisheye fit failed ({problem or 'no positive focal length'}); use more varied board poses",
        )
    return best


def _fit_pinhole(
    grid: np.ndarray, corners: list[np.ndarray], size: tuple[int, int]
) -> tuple[float, np.ndarray, np.ndarray]:
    obj = [grid.astype(np.float32)] * len(corners)
    img = [c.astype(np.float32).reshape(-1, 1, 2) for c in corners]
    flags = cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
    rms, K, _, _, _ = cv2.calibrateCamera(obj, img, size, None, np.zeros(5), flags=flags)
    return float(rms), K, np.zeros(4)
