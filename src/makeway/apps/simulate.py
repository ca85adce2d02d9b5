"""``makeway simulate``: one closed-loop scenario run with its report."""

from __future__ import annotations

from pathlib import Path

from makeway.apps.closed_loop_report import write_closed_loop_report
from makeway.atomic import check_writable
from makeway.decide import DUTY_PRESETS, YieldConfig
from makeway.errors import InputError
from makeway.pipeline.closed_loop import PERCEPTIONS, ClosedLoopResult, run_scenario
from makeway.plan.path import load_path_csv
from makeway.sim.scenarios import SCENARIOS, Scenario, on_recorded_path

__all__ = ["simulate"]


def simulate(
    name: str = "seed003",
    *,
    controller: str = "ffb",
    perception: str = "simulated",
    seed: int = 0,
    siren: str = "synth",
    noise: str = "generated",
    duty: str = "audible_and_visual",
    path: str | Path | None = None,
    out: str | Path | None = None,
    mcap: str | Path | None = None,
) -> tuple[ClosedLoopResult, Scenario, dict[str, str]]:
    """Run the built-in scenario ``name`` (or seed 003's situation on the recorded x,y ``path``, a
    CSV in metres) in closed loop and, with ``out``, write its plots and metrics there.

    ``perception`` names a kind of :data:`~makeway.pipeline.closed_loop.PERCEPTIONS` (``simulated``,
    ``siren``, ``vision``, ``v2x`` or ``fused``); ``seed`` seeds its noise (the siren's scene too);
    ``siren`` and ``noise`` choose the siren stack's sources; ``duty`` names the duty to yield
    (:data:`~makeway.decide.duty.DUTY_PRESETS`). Returns the run, the scenario and the files written
    (name → path). With ``mcap`` the run is also written there as a Foxglove MCAP file (the cars,
    the belief, the yield state, the planned and driven paths;
    :func:`makeway.viz.foxglove.write_simulate_mcap`).

    Raises:
        InputError: the recorded path cannot be read, or ``out`` or ``mcap`` cannot be written
            (checked first).
        UnknownNameError: an unknown scenario, controller, perception or duty preset (lists the known
            ones).
    """
    if out is not None:
        check_writable(out, folder=True)
    if mcap is not None:
        check_writable(mcap, folder=False)
    spec = PERCEPTIONS[perception](seed=seed, siren=siren, noise=noise)
    law = DUTY_PRESETS[duty]
    if path is not None:
        try:
            scenario = on_recorded_path(load_path_csv(path))
        except ValueError as exc:
            raise InputError(path, str(exc)) from None
    else:
        scenario = SCENARIOS[name]()
    result = run_scenario(
        scenario, controller=controller, perception=spec, yield_config=YieldConfig(duty=law)
    )
    files = write_closed_loop_report(result, scenario, out) if out is not None else {}
    if mcap is not None:
        from makeway.viz.foxglove import write_simulate_mcap

        write_simulate_mcap(mcap, result, scenario)
        files["mcap"] = str(mcap)
    return result, scenario, files
