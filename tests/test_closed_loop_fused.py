"""Every scenario driven with the siren stack, the cameras and V2X fused (issue 26): the expected
action, no collision and no extra yield; a second seed where the decision is closest; two EVs; and a
V2X corridor that yields long before the onboard senses could.

Its own file so that the test processes share the slow closed-loop runs evenly (``make test`` keeps
each file on one process)."""

from __future__ import annotations

import dataclasses

import pytest

from makeway.messages import YieldState
from makeway.pipeline.closed_loop import PERCEPTIONS, ClosedLoopResult, run_scenario
from makeway.pipeline.fused_perception import FusedPerceptionConfig
from makeway.sim.scenarios import SCENARIOS

FUSED_CACHE: dict[tuple[str, int], ClosedLoopResult] = {}


def fused(name: str, seed: int = 0) -> ClosedLoopResult:
    key = (name, seed)
    if key not in FUSED_CACHE:
        FUSED_CACHE[key] = run_scenario(SCENARIOS[name](), perception=PERCEPTIONS["fused"](seed=seed))
    return FUSED_CACHE[key]


@pytest.mark.slow  # the siren stack renders and listens: ~5–45 s per scenario on 2 free cores
@pytest.mark.parametrize("name", list(SCENARIOS))
def test_every_scenario_fused_gives_the_expected_action(name: str) -> None:
    m = fused(name).metrics
    assert m["action"] == m["expected_action"], (name, fused(name).actions)
    assert not m["collision"] and m["stopped_clear_of_intersections"]
    assert m["yields"] <= 1  # no extra yields
    if m["expected_action"] == "continue":
        assert m["final_speed_mps"] > 12.0


@pytest.mark.slow
def test_second_seed_fused_at_the_crossing() -> None:
    """The crossing, where the stop before the intersection is decided on a siren not yet placed, on
    another seed (``bench_fusion_ablation.py`` drives every scenario over ten seeds)."""
    m = fused("crossing", 1).metrics
    assert m["action"] == m["expected_action"] and not m["collision"] and m["yields"] == 1


@pytest.mark.slow
def test_two_evs_seed_8_resumes_once_both_have_gone_by() -> None:
    """The oncoming EV passes close beside the stopped car, where its bearing sweeps fast. The car
    decides it has gone by within a second of stopping (it waited 13.5 s when the fusion lost that
    EV there and the state machine knew the new track only from behind), and the far receding
    sirens, read at 30–50 m, start no second yield."""
    m = fused("two_evs", 8).metrics
    assert m["action"] == m["expected_action"] and not m["collision"]
    assert m["time_stopped_waiting_s"] is not None and m["time_stopped_waiting_s"] < 1.0
    assert m["yields"] == 1


@pytest.mark.slow
def test_two_evs_waits_for_the_second() -> None:
    res = fused("two_evs")
    log = res.log
    passed = next(t for t, _, to, _ in res.transitions if to == YieldState.EV_PASSED.value)
    sc = SCENARIOS["two_evs"]()
    oncoming = sc.more_evs[0]
    # the oncoming EV (12 m/s from 150 m ahead) passes the stopped ego only after ~9 s; the first one
    # overtook long before
    ego_x = float(log["x"][int(round(passed / 0.01))])
    ev2_x = 400.0 - (oncoming.start_s_m + 12.0 * passed)
    assert ev2_x < ego_x, (passed, ego_x, ev2_x)


@pytest.mark.slow
def test_v2x_corridor_yields_ten_seconds_before_the_onboard_senses() -> None:
    """With V2X the car yields within 2 s of the EV switching on; the siren and cameras alone have not
    yielded 10 s after that (they need ~30 s: docs/results.md), so the onboard drive is cut there."""
    fused_m = fused("v2x_corridor").metrics
    assert fused_m["time_active_to_yield_s"] is not None and fused_m["time_active_to_yield_s"] < 2.0
    sc = SCENARIOS["v2x_corridor"]()
    assert sc.ev is not None
    horizon = sc.ev.signals_on_s + fused_m["time_active_to_yield_s"] + 10.0
    onboard = run_scenario(
        dataclasses.replace(sc, duration_s=horizon + 0.5),
        perception=FusedPerceptionConfig(senses=("siren", "light")),
    ).metrics
    late = onboard["time_active_to_yield_s"]
    assert late is None or late >= fused_m["time_active_to_yield_s"] + 10.0, late
