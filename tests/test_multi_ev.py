"""Multi-EV fusion (makeway.fuse.multi_ev): EV tracks from siren, light and V2X observations.

The observations come from closed-form trajectories (an ego driving along +x at 10 m/s, EVs at
constant velocity) with Gaussian noise of the stated standard deviations, so every expected value
has a ground truth independent of the filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from makeway.fuse import BeliefSource, FusedBeliefSource, MultiEVFusion
from makeway.fuse.multi_ev import Observation, cv_predict, polar_model
from makeway.messages import (
    EVRelation,
    LightObservation,
    SirenObservation,
    SirenSource,
    V2XObservation,
    VehicleState,
)

DT = 0.1  # s, one control step
EGO_SPEED = 10.0


def ego_at(t: float) -> VehicleState:
    return VehicleState(time_s=t, x_m=EGO_SPEED * t, y_m=0.0, yaw_rad=0.0, vx_mps=EGO_SPEED)


@dataclass(frozen=True)
class EV:
    """An EV at constant velocity: at ``(x0, y0)`` at t = 0, heading ``yaw`` (rad), ``speed`` m/s."""

    x0: float
    y0: float
    yaw: float
    speed: float

    def at(self, t: float) -> tuple[float, float]:
        return self.x0 + self.speed * t * math.cos(self.yaw), self.y0 + self.speed * t * math.sin(self.yaw)


def polar(ev: EV, t: float) -> tuple[float, float]:
    """The EV's bearing (vehicle frame, rad) and distance (m) from the ego at ``t``."""
    e = ego_at(t)
    x, y = ev.at(t)
    return math.atan2(y - e.y_m, x - e.x_m) - e.yaw_rad, math.hypot(x - e.x_m, y - e.y_m)


SIREN_SIGMA = math.radians(6.0)  # the fusion's default siren bearing sigma
LIGHT_SIGMA = math.radians(1.5)


def siren(ev: EV, t: float, rng: np.random.Generator, *, ranged: bool = True) -> SirenObservation:
    b, d = polar(ev, t)
    dist = d * (1.0 + 0.25 * rng.normal()) if ranged and d < 50.0 else None  # 25 %: the default sigma
    src = SirenSource(bearing_rad=b + SIREN_SIGMA * rng.normal(), distance_m=dist)
    return SirenObservation(t, True, 0.9, 0.9, (src,))


def light(ev: EV, t: float, rng: np.random.Generator) -> LightObservation:
    b, d = polar(ev, t)
    return LightObservation(
        t,
        azimuth_rad=b + LIGHT_SIGMA * rng.normal(),
        azimuth_sigma_rad=LIGHT_SIGMA,
        range_m=d * (1.0 + 0.15 * rng.normal()),
        range_sigma_m=0.15 * d,
        probability=0.9,
    )


def v2x(ev: EV, t: float, rng: np.random.Generator, station: int, sigma_m: float = 3.0) -> V2XObservation:
    x, y = ev.at(t)
    return V2XObservation(
        t,
        station,
        x + sigma_m * rng.normal(),
        y + sigma_m * rng.normal(),
        ev.yaw,
        ev.speed,
        verified=True,
        position_sigma_m=sigma_m,
    )


def nearest(evs: list[EV], t: float, rel_x: float, rel_y: float) -> tuple[int, float]:
    """Index of the EV nearest to a belief's vehicle-frame position, and that distance (m)."""
    e = ego_at(t)
    errs = [math.hypot(ev.at(t)[0] - (e.x_m + rel_x), ev.at(t)[1] - (e.y_m + rel_y)) for ev in evs]
    i = int(np.argmin(errs))
    return i, errs[i]


def test_two_evs_behind_and_oncoming_two_tracks_no_swap() -> None:
    """One EV 80 m behind catching up, one oncoming in the other lane from 150 m: heard (bearing,
    distance within 50 m) and announced by V2X → exactly two tracks, each staying on its EV, each
    supported by both senses, with the right relation."""
    behind, oncoming = EV(-80.0, 0.0, 0.0, 20.0), EV(150.0, 3.5, math.pi, 15.0)
    evs = [behind, oncoming]
    rng = np.random.default_rng(1)
    fusion = MultiEVFusion()
    owner: dict[int, int] = {}
    for k in range(50):  # 5 s: the oncoming EV passes the ego at 6 s
        t = k * DT
        obs: list[Observation] = []
        for i, ev in enumerate(evs):
            obs += [siren(ev, t, rng), v2x(ev, t, rng, station=i)]
        beliefs = fusion.update(t, ego_at(t), obs)
        if t < 1.0:
            continue
        assert len(beliefs) == 2
        for b in beliefs:
            assert b.track_id is not None
            i, err = nearest(evs, t, b.rel_x_m, b.rel_y_m)
            assert err < 5.0  # V2X at 3 m sigma, fused: well within 5 m
            assert owner.setdefault(b.track_id, i) == i  # never swaps to the other EV
            assert b.sources == ("v2x", "siren") and b.siren and b.approaching is True
    assert sorted(owner.values()) == [0, 1]
    by_ev = {owner[b.track_id]: b for b in beliefs if b.track_id is not None}
    assert by_ev[0].relation is EVRelation.BEHIND and by_ev[1].relation is EVRelation.ONCOMING
    # the single-EV decision reads the nearer approaching one: the oncoming EV, 25 m ahead at 4.9 s
    urgent = MultiEVFusion.most_urgent(beliefs, t)
    assert urgent.track_id == by_ev[1].track_id


def _rms_error(senses: set[str], seed: int) -> tuple[float, float]:
    """RMS position error (m) of the single track over 2–8 s and the mean trace of its position
    covariance (m²), for an EV overtaking on the left, seen by ``senses``."""
    ev = EV(-40.0, 3.5, 0.0, 15.0)  # from 40 m behind to 10 m ahead in 8 s
    rng = np.random.default_rng(seed)
    fusion = MultiEVFusion()
    errs, traces = [], []
    for k in range(81):
        t = k * DT
        # every sense draws its noise every step, so each run sees the same realisation
        all_obs: list[Observation] = [siren(ev, t, rng), light(ev, t, rng), v2x(ev, t, rng, station=7)]
        kinds = {SirenObservation: "siren", LightObservation: "light", V2XObservation: "v2x"}
        beliefs = fusion.update(t, ego_at(t), [o for o in all_obs if kinds[type(o)] in senses])
        if t >= 2.0:
            assert len(beliefs) == 1
            errs.append(nearest([ev], t, beliefs[0].rel_x_m, beliefs[0].rel_y_m)[1])
            traces.append(float(np.trace(fusion.cov_[0][:2, :2])))
    return float(np.sqrt(np.mean(np.square(errs)))), float(np.mean(traces))


def test_three_senses_fuse_into_one_track_better_than_each_alone() -> None:
    """Closed-form reason: in information form the corrected information is the prior's plus every
    sense's ``HᵀR⁻¹H``; with the senses' noises independent, adding a sense adds a positive
    semi-definite term, so the fused covariance is at most each sense's alone, and with unbiased
    noise the error follows the covariance. Light (1.5°, 15 %) is precise across the line of
    sight, V2X (3 m) along it, so together they beat either clearly."""
    for seed in (3, 4):
        fused, fused_trace = _rms_error({"siren", "light", "v2x"}, seed)
        for sense in ("siren", "light", "v2x"):
            alone, alone_trace = _rms_error({sense}, seed)
            assert fused < 0.9 * alone, (sense, fused, alone)
            assert fused_trace < alone_trace
    # one track, all three senses
    rng = np.random.default_rng(5)
    ev = EV(-40.0, 3.5, 0.0, 15.0)
    fusion = MultiEVFusion()
    for k in range(20):
        t = k * DT
        beliefs = fusion.update(t, ego_at(t), [siren(ev, t, rng), light(ev, t, rng), v2x(ev, t, rng, 7)])
    assert len(fusion.tracks) == 1 and beliefs[0].sources == ("v2x", "light", "siren")
    assert beliefs[0].lights and beliefs[0].siren and beliefs[0].confidence > 0.99


@pytest.mark.parametrize("seed", [10, 11, 12])
def test_clutter_bearings_do_not_confirm_a_track(seed: int) -> None:
    """One false siren bearing per listener window (6 Hz), uniform around the car, for 30 s: a
    bearing-only track needs 7 hits in 9 scans, and a random bearing lands in a tentative track's
    gate (±2.6σ of about 8–10°) with a chance p near 0.14, so six more hits in eight scans come with
    about C(8,6)·p⁶ ≈ 2e-4 per birth, a few hundredths per run of 180 births. A real siren bearing,
    consistent from window to window, is confirmed within 9 scans (the rule is not merely broken)."""
    rng = np.random.default_rng(seed)
    fusion = MultiEVFusion()
    for k in range(180):
        t = k / 6.0
        obs = SirenObservation(t, True, 0.9, 0.9, (SirenSource(float(rng.uniform(-math.pi, math.pi))),))
        assert fusion.update(t, ego_at(t), [obs]) == []
    real = EV(-60.0, 0.0, 0.0, 15.0)
    fusion = MultiEVFusion()
    confirmed_at = None
    for k in range(12):
        t = k / 6.0
        if fusion.update(t, ego_at(t), [siren(real, t, rng, ranged=False)]):
            confirmed_at = confirmed_at if confirmed_at is not None else k
    assert confirmed_at is not None and 6 <= confirmed_at <= 8  # 7 hits: from the 7th window, within 9


def test_track_dies_after_its_sense_stops() -> None:
    """A siren heard (with distance) for 3 s, then silent: the track lives through
    ``lost_after_s`` (2 s) without support and is gone just after."""
    ev = EV(-30.0, 0.0, 0.0, 12.0)
    rng = np.random.default_rng(20)
    fusion = MultiEVFusion(lost_after_s=2.0)
    alive = {}
    for k in range(61):
        t = k * DT
        obs: list[Observation] = [siren(ev, t, rng)] if t <= 3.0 + 1e-9 else []
        alive[k] = len(fusion.update(t, ego_at(t), obs))
    assert alive[30] == 1  # last heard at 3.0 s
    assert alive[49] == 1  # 1.9 s without support
    assert alive[51] == 0 and alive[60] == 0  # 2.1 s: dropped
    assert fusion.tracks == []


@pytest.mark.parametrize(("n_sigma", "accepted"), [(5.0, False), (2.0, True)])
def test_gate_rejects_an_observation_5_sigma_away(n_sigma: float, accepted: bool) -> None:
    """A confirmed track, then one light azimuth ``n_sigma`` innovation standard deviations off the
    prediction (``S = HPHᵀ + σ²``, computed here from the track): 5σ (d² = 25) lies beyond the
    99 % gate for one degree of freedom (6.63) and leaves the track untouched (a new tentative track
    is born from it); 2σ (d² = 4) corrects the track."""
    ev = EV(-40.0, 0.0, 0.0, 15.0)
    rng = np.random.default_rng(30)
    fusion = MultiEVFusion()
    for k in range(20):
        t = k * DT
        fusion.update(t, ego_at(t), [v2x(ev, t, rng, 1), siren(ev, t, rng)])
    assert len(fusion.tracks) == 1 and fusion.tracks[0].confirmed
    t = 20 * DT
    x_pred, p_pred = cv_predict(fusion.state_[0], fusion.cov_[0], DT, fusion.accel_noise_mps2)
    e = ego_at(t)
    zhat, h = polar_model(x_pred[None], e.x_m, e.y_m, e.yaw_rad, with_range=False)
    s = float((h[0] @ p_pred @ h[0].T)[0, 0]) + LIGHT_SIGMA**2
    obs = LightObservation(t, float(zhat[0, 0]) + n_sigma * math.sqrt(s), azimuth_sigma_rad=LIGHT_SIGMA)
    fusion.update(t, e, [obs])
    moved = not np.allclose(fusion.state_[0], x_pred)
    assert moved is accepted
    assert ("light" in fusion.tracks[0].sense_time_s) is accepted
    assert len(fusion.tracks) == (1 if accepted else 2)


@pytest.mark.parametrize("max_sigma_deg", [60.0, 180.0])
def test_a_bearing_alone_does_not_join_a_track_whose_bearing_is_unknown(max_sigma_deg: float) -> None:
    """A confirmed siren track placed 7 m behind the car with a 9 m spread (its bearing from the car
    is unknown: σ ≈ 73°) and a light with no range 150° away from it, ahead (a brake light passing the
    flash check, say). The linearised gate's innovation variance is so wide that the light would fall
    inside it and drag the track ahead of the car; with the bearing test (default 60°) the light
    starts a track of its own instead. Off (180°), the old behaviour: the light joins the track."""
    ev = EV(-40.0, 0.0, 0.0, 15.0)
    rng = np.random.default_rng(31)
    fusion = MultiEVFusion(bearing_only_max_sigma_deg=max_sigma_deg)
    for k in range(20):
        t = k * DT
        fusion.update(t, ego_at(t), [siren(ev, t, rng)])
    assert len(fusion.tracks) == 1 and fusion.tracks[0].confirmed
    t = 20 * DT
    e = ego_at(t)
    fusion.state_[0] = [e.x_m - 7.0, 1.0, 15.0, 0.0]
    fusion.cov_[0] = np.diag([81.0, 81.0, 4.0, 4.0])
    fusion.update(t, e, [LightObservation(t, math.radians(20.0), azimuth_sigma_rad=LIGHT_SIGMA)])
    joined = "light" in fusion.tracks[0].sense_time_s
    assert joined is (max_sigma_deg >= 180.0)
    assert len(fusion.tracks) == (1 if joined else 2)
    if joined:  # pulled to the light's side of the car
        assert fusion.state_[0, 0] > e.x_m - 7.0 + 0.5 * 15.0 * DT
    with pytest.raises(ValueError, match="bearing_only_max_sigma_deg"):
        MultiEVFusion(bearing_only_max_sigma_deg=0.0)


def test_five_tracks_three_senses_each_found_once() -> None:
    """Five EVs around the car (behind, ahead, oncoming, two on crossing roads), each heard, seen
    and announced, 10 Hz for 3 s: five confirmed tracks, one per EV, each within 3 m, each
    supported by all three senses."""
    evs = [
        EV(-35.0, 0.0, 0.0, 15.0),
        EV(40.0, 0.0, 0.0, 12.0),
        EV(60.0, 3.5, math.pi, 10.0),
        EV(30.0, -35.0, math.pi / 2, 8.0),
        EV(25.0, 30.0, -math.pi / 2, 8.0),
    ]
    rng = np.random.default_rng(40)
    fusion = MultiEVFusion()
    for k in range(31):
        t = k * DT
        obs: list[Observation] = []
        for i, ev in enumerate(evs):
            obs += [siren(ev, t, rng), light(ev, t, rng), v2x(ev, t, rng, station=i)]
        beliefs = fusion.update(t, ego_at(t), obs)
    assert len(beliefs) == 5
    found = [nearest(evs, t, b.rel_x_m, b.rel_y_m) for b in beliefs]
    assert sorted(i for i, _ in found) == [0, 1, 2, 3, 4]
    assert max(err for _, err in found) < 3.0
    assert all(b.sources == ("v2x", "light", "siren") for b in beliefs)


def test_unverified_alerts_are_set_aside_and_the_source_is_a_belief_source() -> None:
    """An alert that failed verification makes no track; the fused source answers the
    ``BeliefSource`` call with nothing, then with the EV once verified alerts confirm it."""
    ev = EV(-50.0, 0.0, 0.0, 20.0)
    rng = np.random.default_rng(50)
    source = FusedBeliefSource()
    assert isinstance(source, BeliefSource)
    for k in range(10):
        t = k * DT
        o = v2x(ev, t, rng, 3)
        source.receive(V2XObservation(**{**{f: getattr(o, f) for f in o.__slots__}, "verified": False}))
        assert not source.update(t, ego_at(t)).detected
    assert source.fusion.unverified_ == 10 and source.fusion.tracks == []
    for k in range(10, 20):
        t = k * DT
        source.receive(v2x(ev, t, rng, 3))
        belief = source.update(t, ego_at(t))
    assert belief.detected and belief.sources == ("v2x",) and belief.relation is EVRelation.BEHIND
