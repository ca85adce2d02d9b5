"""Fused EV beliefs linked to camera vehicle tracks (issue 26 item 2: the obstacle id an audio event
carries): camera tracks as vehicle-frame bearings, the gate, one vehicle per EV, stable links, and
real SORT tracks of a real clip."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from makeway.errors import InputError
from makeway.eval.actor_sweep import ClipRecord
from makeway.fuse import ObstacleLinker, ObstacleLinkerConfig
from makeway.messages import Box, EVBelief, EVState, EVTrackState, Track, VehicleBearing
from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL
from makeway.perceive.vision.track_bearings import vehicle_bearings
from makeway.pipeline.clip_record import cached_clip
from makeway.sense.rig import Rig, load_rig, read_rig

CLIP = "night_ambulance_lights"  # the ambulance is SORT track 13 from frame 15 (video_track_labels.csv)
AMBULANCE = 13


def dashcam_rig(tmp_path: Path) -> Rig:
    """The clip's camera as the rig's front camera: pinhole, 1280 × 720, 90° across (assumed: the
    clip comes without a calibration), 2 m ahead of the origin and 1.3 m up."""
    path = tmp_path / "dashcam.yaml"
    path.write_text(
        "cameras:\n"
        "  - {name: dash, model: pinhole, width: 1280, height: 720, fx: 640.0, fy: 640.0,\n"
        "     cx: 640.0, cy: 360.0, yaw_pitch_roll_deg: [0, 0, 0], translation_m: [2.0, 0.0, 1.3]}\n"
    )
    return read_rig(path)


def tracks_of(rec: ClipRecord, frame: int) -> list[Track]:
    sel = np.flatnonzero(rec.frame == frame)
    return [Track(int(rec.track_id[i]), Box(*map(float, rec.boxes[i]))) for i in sel]


def siren(bearing_deg: float, track_id: int | None = 1, t: float = 0.0, **kw: float) -> EVBelief:
    return EVBelief(
        time_s=t,
        detected=True,
        confidence=0.9,
        bearing_rad=math.radians(bearing_deg),
        siren=True,
        sources=("siren",),
        track_id=track_id,
        **kw,  # type: ignore[arg-type]
    )


def vehicle(
    track_id: int, az_deg: float, sigma_deg: float = 1.0, active: bool | None = None
) -> VehicleBearing:
    return VehicleBearing(
        "front", track_id, 0.0, math.radians(az_deg), math.radians(sigma_deg), active=active
    )


@pytest.fixture(scope="module")
def night60(video_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> ClipRecord:
    rec, _ = cached_clip(
        video_dir / f"{CLIP}.mp4", tmp_path_factory.mktemp("obstacles"), DEFAULT_MODEL, max_frames=60
    )
    return rec


def test_a_siren_heard_at_the_ambulance_is_linked_to_its_real_track(
    night60: ClipRecord, tmp_path: Path
) -> None:
    """Real SORT tracks (YOLOX-nano, the label file's settings) of a real night clip, the ambulance
    among buses, cars and rickshaws: a siren bearing drawn around the ambulance's box with the
    siren stack's angle error (4.5° σ) is linked to the ambulance's track in nearly every frame, and
    the link holds once made; the same siren heard behind the car is linked to nothing."""
    rig = dashcam_rig(tmp_path)
    linker = ObstacleLinker()
    rng = np.random.default_rng(0)
    links, crowd = [], []
    for f in range(20, 60):
        tracks = tracks_of(night60, f)
        bearings = vehicle_bearings(rig, "dash", tracks, f / 30.0)
        by_id = {b.track_id: b for b in bearings}
        if AMBULANCE not in by_id:
            continue
        amb = by_id[AMBULANCE].azimuth_rad
        crowd.append(
            any(abs(b.azimuth_rad - amb) < math.radians(20.0) for b in bearings if b is not by_id[AMBULANCE])
        )
        heard = amb + rng.normal(0.0, math.radians(4.5))
        (b,) = linker.update([siren(math.degrees(heard), t=f / 30.0)], bearings)
        links.append(b.obstacle_id)
        (behind,) = ObstacleLinker().update([siren(178.0)], bearings)
        assert behind.obstacle_id is None
    assert len(links) >= 30 and sum(crowd) >= 10  # another vehicle within 20° (the coach, a car at 7°)
    right = sum(link == f"dash/{AMBULANCE}" for link in links)
    assert right >= 0.9 * len(links)
    first = links.index(f"dash/{AMBULANCE}")
    assert all(link == f"dash/{AMBULANCE}" for link in links[first:])


def test_vehicle_bearings_follow_the_camera_model() -> None:
    """A box at the image centre of each camera of the shipped fisheye rig points where that camera
    looks (front 0°, left +90°, right −90°, rear 180°); a wider box has a wider σ; the smoother's
    verdict becomes ``active``; an unknown camera or a negative pixel σ is refused."""
    rig = load_rig("default")
    looks = {"front": 0.0, "left": 90.0, "right": -90.0, "rear": 180.0}
    for name, az in looks.items():
        w, h = rig.camera(name).camera.width, rig.camera(name).camera.height
        narrow = Track(1, Box(w / 2 - 10, h / 2 - 10, w / 2 + 10, h / 2 + 10))
        wide = Track(2, Box(w / 2 - 200, h / 2 - 10, w / 2 + 200, h / 2 + 10))
        states = [
            EVTrackState(1, EVState.ACTIVE, 1.0, 5, 0.9),
            EVTrackState(2, EVState.WARMING_UP, 0.0, 1, 0.1),
        ]
        a, b = vehicle_bearings(rig, name, [narrow, wide], 1.0, ev_states=states)
        assert abs(math.remainder(math.radians(az) - a.azimuth_rad, math.tau)) < math.radians(1.0)
        assert b.half_width_rad > 10 * a.half_width_rad > 0 and b.azimuth_sigma_rad > a.azimuth_sigma_rad
        assert a.active is True and b.active is None and a.obstacle_id == f"{name}/1"
        assert a.camera_xy_m == pytest.approx(tuple(rig.camera(name).translation_m[:2]))
    assert vehicle_bearings(rig, "front", [], 0.0) == []
    with pytest.raises(InputError, match="no camera 'roof'"):
        vehicle_bearings(rig, "roof", [narrow], 0.0)
    with pytest.raises(ValueError, match="pixel_sigma_px"):
        vehicle_bearings(rig, "front", [narrow], 0.0, pixel_sigma_px=-1.0)


def test_one_vehicle_per_ev_and_the_gate() -> None:
    """Two EVs, three vehicles: each EV gets the vehicle on its bearing, none shares one; an EV
    with no vehicle inside the gate, one not detected and a mono siren (no bearing) get none."""
    linker = ObstacleLinker()
    vehicles = [vehicle(4, 10.0), vehicle(5, 12.0), vehicle(6, -30.0)]
    out = linker.update(
        [
            siren(11.5, track_id=1),
            siren(10.5, track_id=2),
            siren(60.0, track_id=3),
            EVBelief.nothing(0.0),
            EVBelief(0.0, True, 0.8, siren=True, sources=("siren",), track_id=5),
        ],
        vehicles,
    )
    assert {out[0].obstacle_id, out[1].obstacle_id} == {"front/4", "front/5"}
    assert out[2].obstacle_id is None and out[3].obstacle_id is None and out[4].obstacle_id is None
    assert out[3] == EVBelief.nothing(0.0)
    assert ObstacleLinker().update([siren(10.0)], []) == [siren(10.0)]


def test_links_stay_put_and_prefer_a_vehicle_that_looks_like_an_ev() -> None:
    """Two vehicles 3° apart, a siren bearing that wanders between them: once linked, the EV keeps
    its vehicle; afresh, a vehicle the crop classifier calls active wins over one it calls not."""
    linker = ObstacleLinker()
    pair = [vehicle(7, 0.0), vehicle(8, 3.0)]
    first = linker.update([siren(0.5)], pair)[0].obstacle_id
    assert first == "front/7"
    for heard in (2.0, 2.5, 1.0, 2.8, 0.2):
        assert linker.update([siren(heard)], pair)[0].obstacle_id == first
    assert linker.update([siren(2.0)], []) == [siren(2.0)]  # a frame without vehicles keeps the memory
    assert linker.update([siren(2.5)], pair)[0].obstacle_id == first
    linker.update([], pair)  # the EV track is gone: forgotten
    assert linker.update([siren(2.0)], pair)[0].obstacle_id == "front/8"
    looks = [vehicle(7, 0.0, active=False), vehicle(8, 3.0, active=True)]
    assert ObstacleLinker().update([siren(1.0)], looks)[0].obstacle_id == "front/8"


def test_a_placed_belief_is_compared_from_the_camera() -> None:
    """An EV placed 10 m ahead and 10 m to the left is at 45° from the origin but 59° from a camera
    4 m ahead of it: it is linked to the vehicle the camera sees at 59°, not the one at 45°."""
    cam = (4.0, 0.0)
    seen_59 = VehicleBearing("front", 1, 0.0, math.atan2(10.0, 6.0), math.radians(1.0), camera_xy_m=cam)
    seen_45 = VehicleBearing("front", 2, 0.0, math.radians(45.0), math.radians(1.0), camera_xy_m=cam)
    placed = siren(45.0, rel_x_m=10.0, rel_y_m=10.0, distance_m=math.hypot(10.0, 10.0))
    narrow = ObstacleLinker(ObstacleLinkerConfig(belief_bearing_sigma_rad=math.radians(2.0)))
    assert narrow.update([placed], [seen_45, seen_59])[0].obstacle_id == "front/1"
    exact = ObstacleLinker(ObstacleLinkerConfig(belief_bearing_sigma_rad=0.0))  # no σ at all: still defined
    on_it = VehicleBearing("front", 3, 0.0, math.radians(10.0), 0.0)
    assert exact.update([siren(10.0)], [on_it])[0].obstacle_id == "front/3"
    assert exact.update([siren(10.5)], [on_it])[0].obstacle_id is None
    with pytest.raises(ValueError, match="ObstacleLinkerConfig"):
        ObstacleLinkerConfig(gate_sigmas=0.0)
    with pytest.raises(ValueError, match="ObstacleLinkerConfig"):
        ObstacleLinkerConfig(keep_bonus=float("nan"))


def test_any_beliefs_and_vehicles_give_one_vehicle_per_ev_inside_the_gate() -> None:
    """Whatever the beliefs (placed or not, NaN parts, repeated track ids) and the vehicles, every
    vehicle is linked to at most one EV, every link lies inside the gate, and a belief keeps all
    its fields but ``obstacle_id``."""
    from dataclasses import replace

    from hypothesis import given, settings
    from hypothesis import strategies as st

    angle = st.floats(-4.0, 4.0) | st.just(float("nan"))
    beliefs = st.lists(
        st.builds(
            lambda t, det, brg, x, y, tid: EVBelief(
                t, det, 0.9, rel_x_m=x, rel_y_m=y, bearing_rad=brg, track_id=tid
            ),
            st.floats(0.0, 10.0),
            st.booleans(),
            angle,
            st.floats(-80.0, 80.0) | st.just(float("nan")),
            st.floats(-80.0, 80.0) | st.just(float("nan")),
            st.none() | st.integers(0, 3),
        ),
        max_size=5,
    )
    vehicles = st.lists(
        st.builds(
            lambda tid, az, sig, active: VehicleBearing("front", tid, 0.0, az, sig, active=active),
            st.integers(0, 6),
            st.floats(-3.2, 3.2),
            st.floats(0.0, 0.5),
            st.none() | st.booleans(),
        ),
        max_size=5,
        unique_by=lambda v: v.track_id,
    )
    cfg = ObstacleLinkerConfig()

    @settings(max_examples=300, deadline=None)
    @given(steps=st.lists(st.tuples(beliefs, vehicles), min_size=1, max_size=4))
    def run(steps: list[tuple[list[EVBelief], list[VehicleBearing]]]) -> None:
        linker = ObstacleLinker(cfg)
        for bs, vs in steps:
            out = linker.update(bs, vs)
            assert len(out) == len(bs)
            links = [b.obstacle_id for b in out if b.obstacle_id is not None]
            assert len(links) == len(set(links))
            by_id = {v.obstacle_id: v for v in vs}
            for b, o in zip(bs, out, strict=True):
                assert replace(o, obstacle_id=None) == replace(b, obstacle_id=None)
                if o.obstacle_id is None:
                    continue
                assert b.detected
                v = by_id[o.obstacle_id]
                seen = (
                    math.atan2(b.rel_y_m - v.camera_xy_m[1], b.rel_x_m - v.camera_xy_m[0])
                    if math.isfinite(b.rel_x_m) and math.isfinite(b.rel_y_m)
                    else b.bearing_rad
                )
                d = abs(math.remainder(seen - v.azimuth_rad, math.tau))
                assert (
                    d
                    <= cfg.gate_sigmas * math.hypot(cfg.belief_bearing_sigma_rad, v.azimuth_sigma_rad) + 1e-9
                )

    run()
