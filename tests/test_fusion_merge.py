"""Merging two EV tracks of the multi-EV fusion (issue 26): two tracks on one EV become one, but a
stale track never swallows a new EV seen on another bearing (seed003, seed 7: a false light ahead,
unsupported for 1.7 s, took in the track of the EV whose lights were just seen 50 m behind).

Observations are constructed with stated geometry, so each outcome follows from the rule."""

from __future__ import annotations

import math

from makeway.fuse import MultiEVFusion
from makeway.messages import LightObservation, SirenObservation, SirenSource, VehicleState

SIGMA = math.radians(2.0)


def ego_at(t: float, speed: float = 13.4) -> VehicleState:
    return VehicleState(t, speed * t, 0.0, 0.0, speed)


def light(t: float, azimuth_deg: float) -> LightObservation:
    return LightObservation(t, math.radians(azimuth_deg), SIGMA, probability=0.9)


def test_a_stale_track_ahead_does_not_swallow_a_new_ev_behind() -> None:
    fusion = MultiEVFusion()
    for k in range(3):  # a false light 20° left ahead, three frames
        fusion.update(k * 0.1, ego_at(k * 0.1), [light(k * 0.1, 20.0)])
    stale = fusion.tracks[0].track_id
    t = 1.9  # 1.7 s later: the EV's lights 180° behind, then its siren on the same bearing
    fusion.update(t, ego_at(t), [light(t, 180.0)])
    assert len(fusion.tracks) == 2
    new = fusion.tracks[1]
    assert new.track_id != stale and new.sense_time_s["light"] == t
    assert fusion.tracks[0].sense_time_s["light"] == 0.2  # the stale track got nothing
    for k, tk in enumerate((2.07, 2.24, 2.41)):
        siren = SirenObservation(tk, True, 0.99, 0.99, (SirenSource(math.pi - 0.02 * k, 47.0, True),))
        beliefs = fusion.update(tk, ego_at(tk), [siren])
    # the new track took the siren: two senses, four scans in a row → confirmed
    assert [b.track_id for b in beliefs] == [new.track_id]
    assert set(beliefs[0].sources) == {"light", "siren"}


def test_two_tracks_on_one_bearing_still_merge() -> None:
    fusion = MultiEVFusion()
    # two detections of one light bar in one frame, 1° apart: both born, merged into one track
    fusion.update(0.0, ego_at(0.0), [light(0.0, 179.0), light(0.0, 180.0)])
    assert len(fusion.tracks) == 1
    # a configured bearing test of 0 σ merges nothing
    strict = MultiEVFusion(merge_bearing_sigmas=0.0)
    strict.update(0.0, ego_at(0.0), [light(0.0, 179.0), light(0.0, 180.0)])
    assert len(strict.tracks) == 2
