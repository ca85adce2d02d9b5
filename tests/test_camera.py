"""Camera models (makeway.sense.camera): pixel ↔ ray for the pinhole and the Kannala–Brandt fisheye.

OpenCV is the independent reference: ``cv2.fisheye.projectPoints`` implements the same fisheye model
(the shipped rig's lenses are checked against it), ``cv2.projectPoints`` the pinhole. The round trips
are judged over the whole image, rim included, where a 180° lens sees rays beyond 90° that OpenCV's
own inversion cannot reach.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from makeway.registry import UnknownNameError
from makeway.sense.camera import CAMERA_MODELS, Camera, KannalaBrandtCamera, PinholeCamera
from makeway.sense.rig import load_rig

RIG = load_rig("default")
FISHEYES = [c.camera for c in RIG.cameras]
PINHOLE = PinholeCamera(1280, 720, 910.0, 905.0, 641.0, 358.5)


def _image_grid(cam: Camera, step: int = 8) -> np.ndarray:
    """Pixels on a grid over the whole image, its four edges (the rim) included."""
    u = np.unique(np.r_[np.arange(0, cam.width, step), cam.width])
    v = np.unique(np.r_[np.arange(0, cam.height, step), cam.height])
    uu, vv = np.meshgrid(u.astype(float), v.astype(float))
    return np.stack([uu, vv], axis=-1)


def _rays(theta_max: float, n: int = 400) -> np.ndarray:
    """Unit rays on a (θ, φ) grid, θ from 0 to ``theta_max`` inclusive, φ all the way round."""
    th, ph = np.meshgrid(np.linspace(0.0, theta_max, n), np.linspace(-math.pi, math.pi, n))
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)


def test_registry_names_the_two_models() -> None:
    assert list(CAMERA_MODELS) == ["pinhole", "kannala_brandt"]
    assert CAMERA_MODELS["kannala_brandt"] is KannalaBrandtCamera
    with pytest.raises(UnknownNameError, match="pinhole, kannala_brandt"):
        CAMERA_MODELS["equidistant"]


@pytest.mark.parametrize("cam", [*FISHEYES, PINHOLE], ids=[*RIG.names, "pinhole"])
def test_project_of_unproject_returns_every_pixel_of_the_image(cam: Camera) -> None:
    px = _image_grid(cam)
    rays = cam.unproject(px)
    assert np.all(np.isfinite(rays)), "every pixel of the image has a ray, corners included"
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-12)
    assert np.abs(cam.project(rays) - px).max() < 1e-9


@pytest.mark.parametrize("cam", FISHEYES, ids=RIG.names)
def test_a_180_degree_lens_sees_past_90_degrees_at_its_rim(cam: Camera) -> None:
    """The shipped lenses cover 180° across the image: ~90° at the left and right edges, more in the
    corners (rays pointing slightly backwards, z < 0)."""
    edges = np.degrees(cam.theta_of_pixel([[0.0, cam.cy], [cam.width, cam.cy]]))
    np.testing.assert_allclose(edges, 90.0, atol=1.0)
    corner = cam.unproject([0.0, 0.0])
    assert corner[2] < 0 and math.degrees(math.acos(corner[2])) > 110


@pytest.mark.parametrize("cam", [*FISHEYES, PINHOLE], ids=[*RIG.names, "pinhole"])
def test_unproject_of_project_returns_every_ray_the_image_sees(cam: Camera) -> None:
    rays = _rays(cam.image_theta_max)
    px = cam.project(rays)
    assert np.all(np.isfinite(px))
    assert np.abs(cam.unproject(px) - rays).max() < 1e-9


@pytest.mark.parametrize("cam", FISHEYES, ids=RIG.names)
def test_unproject_of_project_holds_up_to_the_fold_of_the_polynomial(cam: KannalaBrandtCamera) -> None:
    """Past the image corners, up to theta_max itself: there dθ_d/dθ = 0, so a rounding δ of θ_d
    (~1e-16) moves θ by up to √(2δ/|θ_d''|) ≈ 1e-8 at the fold, and 1e-9 holds until just before."""
    assert cam.image_theta_max < cam.theta_max
    below = _rays(cam.theta_max * 0.999)
    assert np.abs(cam.unproject(cam.project(below)) - below).max() < 1e-9
    at_fold = _rays(cam.theta_max)
    assert np.abs(cam.unproject(cam.project(at_fold)) - at_fold).max() < 1e-7


@pytest.mark.parametrize("cam", FISHEYES, ids=RIG.names)
def test_theta_max_is_where_the_polynomial_stops_rising(cam: KannalaBrandtCamera) -> None:
    # an independent check by finite differences: rising up to theta_max, falling just after it
    th = np.linspace(0.0, cam.theta_max, 5001)
    assert np.all(np.diff(cam.theta_d(th)) > 0)
    after = cam.theta_max + np.array([1e-3, 2e-3])
    assert np.diff(cam.theta_d(after))[0] < 0
    # beyond the limit there is neither an image nor a ray
    assert np.all(np.isnan(cam.project(_rays(cam.theta_max + 0.01, 5)[:, -1])))
    far = cam.cx + cam.fx * (cam.theta_d_max + 1e-6)
    assert np.all(np.isnan(cam.unproject([far, cam.cy])))


@pytest.mark.parametrize("cam", FISHEYES, ids=RIG.names)
def test_project_agrees_with_opencv_fisheye(cam: KannalaBrandtCamera) -> None:
    rng = np.random.default_rng(4)
    # directions up to 89.9° (OpenCV works on X/Z, so only in front of the camera), depths 0.5–80 m
    rays = _rays(math.radians(89.9), 200).reshape(-1, 3)
    points = rays * rng.uniform(0.5, 80.0, size=(len(rays), 1))
    zero = np.zeros(3)
    ref, _ = cv2.fisheye.projectPoints(points[:, None, :], zero, zero, cam.matrix, np.array(cam.k))
    assert np.abs(cam.project(points) - ref[:, 0]).max() < 1e-6


def test_project_agrees_with_opencv_pinhole() -> None:
    rays = _rays(math.radians(75.0), 200).reshape(-1, 3)
    points = rays * np.random.default_rng(5).uniform(0.5, 80.0, size=(len(rays), 1))
    ref, _ = cv2.projectPoints(points[:, None, :], np.zeros(3), np.zeros(3), PINHOLE.matrix, np.zeros(5))
    assert np.abs(PINHOLE.project(points) - ref[:, 0]).max() < 1e-6
    assert np.all(np.isnan(PINHOLE.project([[0.1, 0.2, -1.0], [1.0, 0.0, 0.0]])))


@pytest.mark.parametrize("cam", FISHEYES, ids=RIG.names)
def test_unproject_agrees_with_opencv_where_opencv_inverts_and_beats_it_at_the_rim(
    cam: KannalaBrandtCamera,
) -> None:
    px = _image_grid(cam, step=16).reshape(-1, 2)
    ours = cam.unproject(px)
    und = cv2.fisheye.undistortPoints(px[:, None, :], cam.matrix, np.array(cam.k))[:, 0]
    ref = np.c_[und, np.ones(len(und))]
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    angle_deg = np.degrees(np.arccos(np.clip(np.sum(ours * ref, axis=1), -1.0, 1.0)))
    theta_deg = np.degrees(cam.theta_of_pixel(px))
    # OpenCV clamps θ_d at π/2, about 83° for these lenses: below 80° both agree to 1e-5°
    inside = theta_deg < 80.0
    assert inside.sum() > 0.5 * len(px)
    assert angle_deg[inside].max() < 1e-5
    # beyond θ_d = π/2, OpenCV's rays are wrong by degrees, while ours still project back exactly
    rim = cam.theta_d(np.radians(theta_deg)) > math.pi / 2 + 0.05
    assert rim.sum() > 0.05 * len(px)
    assert np.median(angle_deg[rim]) > 1.0
    assert np.abs(cam.project(ours[rim]) - px[rim]).max() < 1e-9


def test_bad_intrinsics_are_refused() -> None:
    with pytest.raises(ValueError, match="4 coefficients"):
        KannalaBrandtCamera(640, 480, 300.0, 300.0, 320.0, 240.0, (0.1, 0.0))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="focal"):
        PinholeCamera(640, 480, 0.0, 300.0, 320.0, 240.0)
