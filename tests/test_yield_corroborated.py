"""Two senses that agree on one EV let the car yield sooner (issue 26: EV on → stopped within
0.5 s of the modelled perception): the yield decision skips its confirmation dwell for a belief two
independent senses support, and a siren counts as "siren and lights" while its track's lights were
seen moments ago. The guards against false yields stay: one sense keeps the dwell, lights alone
still need 2 s of unbroken sight, a siren alone far away is still only prepared for.

Every input is constructed (beliefs at the decision's 20 Hz), so each outcome follows from the rule
under test."""

from __future__ import annotations

import math

import pytest

from makeway.decide import YieldConfig, YieldStateMachine
from makeway.decide.duty import DutyToYield, duty_of
from makeway.messages import EVBelief, EVRelation, RoadContext, VehicleState, YieldState
from makeway.perceive.audio.siren_model import SirenModel
from makeway.perceive.audio.windows import LISTEN_SMOOTH
from makeway.pipeline.fused_perception import FusedPerceptionConfig
from makeway.pipeline.siren_perception import SirenPerception, SirenPerceptionConfig

DT = 0.05
ROAD = RoadContext(s_m=0.0, speed_limit_mps=13.4)


def belief(
    t: float,
    *,
    siren: bool = True,
    lights: bool = True,
    sources: tuple[str, ...] = ("siren", "light"),
    track: int | None = 1,
    distance: float = 80.0,
    relation: EVRelation = EVRelation.BEHIND,
) -> EVBelief:
    """A fused belief of an EV ``distance`` behind, approaching."""
    return EVBelief(
        t, True, 0.95, relation, -distance, 0.0, distance, math.pi, True, lights, siren, "fused",
        sources, track,
    )  # fmt: skip


def run(fsm: YieldStateMachine, beliefs) -> list[tuple[float, YieldState, str]]:
    """Feed ``beliefs(t)`` every 0.05 s for 1 s to an ego at 13.4 m/s; ``(t, state, action)`` each."""
    out = []
    for k in range(21):
        t = k * DT
        d = fsm.update(beliefs(t), VehicleState(t, 13.4 * t, 0.0, 0.0, 13.4), ROAD)
        out.append((t, d.state, d.action))
    return out


def first(trace: list[tuple[float, YieldState, str]], state: YieldState) -> float | None:
    return next((t for t, s, _ in trace if s is state), None)


def test_two_senses_confirm_at_once_one_sense_waits_the_dwell() -> None:
    two = run(YieldStateMachine(), lambda t: belief(t))
    assert first(two, YieldState.EV_CONFIRMED) == 0.0
    assert first(two, YieldState.MOVING_OVER) == pytest.approx(DT)
    # the modelled perception names no senses: the 0.3 s dwell as before (its anchor is unchanged)
    modelled = run(YieldStateMachine(), lambda t: belief(t, sources=(), track=None))
    assert first(modelled, YieldState.EV_CONFIRMED) == pytest.approx(0.3)
    # the dwell for two senses is configuration
    slow = run(YieldStateMachine(YieldConfig(corroborated_confirm_time_s=0.3)), lambda t: belief(t))
    assert first(slow, YieldState.EV_CONFIRMED) == pytest.approx(0.3)


def test_a_siren_whose_track_showed_lights_moments_ago_is_yielded_to() -> None:
    """Lights seen once at t = 0 on track 1, then only its siren, 80 m behind (far: a siren alone
    is only prepared for): a yield at once; the siren on another track, or after the memory, or
    with the memory off, only prepares."""

    def flash_then_siren(track: int):
        def at(t: float) -> EVBelief:
            if t == 0.0:
                return belief(t, siren=False, sources=("light",))  # lights alone, a moment: ignored
            return belief(t, lights=False, sources=("siren",), track=track)

        return at

    same = run(YieldStateMachine(), flash_then_siren(1))
    assert first(same, YieldState.MOVING_OVER) == pytest.approx(2 * DT)  # confirmed at 0.05, no dwell
    assert same[-1][2] == "pull_over_and_stop"
    other = run(YieldStateMachine(), flash_then_siren(2))
    assert first(other, YieldState.MOVING_OVER) is None and other[-1][2] == "prepare"
    assert first(other, YieldState.EV_CONFIRMED) == pytest.approx(0.35)  # one sense: the dwell
    off = YieldStateMachine(YieldConfig(duty=DutyToYield(lights_memory_s=0.0)))
    assert run(off, flash_then_siren(1))[-1][2] == "prepare"

    law = DutyToYield()
    heard = belief(10.0, lights=False, sources=("siren",))
    assert duty_of(heard, law, lights_ago_s=2.9) == "yield"
    assert duty_of(heard, law, lights_ago_s=3.1) == "prepare"
    # the memory never stands in for lights alone: they still need 2 s of unbroken sight
    seen = belief(10.0, siren=False, sources=("light",))
    assert duty_of(seen, law, lights_for_s=0.5, lights_ago_s=0.0) == "ignore"
    with pytest.raises(ValueError, match="lights_memory_s"):
        DutyToYield(lights_memory_s=-1.0)


def test_closed_loop_listener_smoothing_is_configured_by_the_perception() -> None:
    siren_model = SirenModel()
    fused = FusedPerceptionConfig(model=siren_model)
    assert fused.siren_smooth < LISTEN_SMOOTH  # the fused car calls a siren sooner than one that only hears
    heard = SirenPerception(1.0, SirenPerceptionConfig(smooth=fused.siren_smooth, model=siren_model))
    assert heard.listener.smoother.window == fused.siren_smooth
    hearing_only = SirenPerception(1.0, SirenPerceptionConfig(model=siren_model))
    assert hearing_only.listener.smoother.window == LISTEN_SMOOTH
    with pytest.raises(ValueError, match="smooth"):
        SirenPerceptionConfig(smooth=0)
