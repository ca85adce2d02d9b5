"""``makeway simulate``: one closed-loop scenario run with its report."""

from __future__ import annotations

from pathlib import Path

from makeway.apps.closed_loop_report import write_closed_loop_report
from makeway.atomic import check_writable
from makeway.decide import DUTY_PRESETS, YieldConfig
from makeway.errors import InputError
from makeway.pipeline.closed_loop import PERCEPTIONS, ClosedLoopResult, run_scenario
from makeway.plan.path import load_path_csv
from makeway.sim.cameras import CAMERA_FIGURES
from makeway.sim.localization import LOCALIZATIONS
from makeway.sim.plants import PlantSpec
from makeway.sim.scenarios import SCENARIOS, Scenario, on_recorded_path

DESIGN_STEER_DELAY_S = 0.15
"""The steering delay the controllers compensate when the car's steering is delayed: the nominal
figure of its steering spec, the middle of the 0.1–0.2 s of electric power steering behind a bus."""

__all__ = ["simulate"]


def simulate(
    name: str = "seed003",
    *,
    controller: str = "ffb",
    perception: str = "simulated",
    seed: int = 0,
    siren: str = "synth",
    noise: str = "generated",
    cameras: str = "seed004",
    duty: str = "audible_and_visual",
    path: str | Path | None = None,
    out: str | Path | None = None,
    plant: str = "linear",
    vehicle: str | None = None,
    road: str = "dry",
    steer_delay_s: float = 0.0,
    delay_compensation: bool = True,
    localization: str = "perfect",
    mcap: str | Path | None = None,
) -> tuple[ClosedLoopResult, Scenario, dict[str, str]]:
    """Run the built-in scenario ``name`` (or seed 003's situation on the recorded x,y ``path``, a
    CSV in metres) in closed loop and, with ``out``, write its plots and metrics there.

    ``perception`` names a kind of :data:`~makeway.pipeline.closed_loop.PERCEPTIONS` (``simulated``,
    ``siren``, ``vision``, ``v2x`` or ``fused``); ``seed`` seeds its noise (the siren's scene too);
    ``siren`` and ``noise`` choose the siren stack's sources; ``cameras`` names the simulated
    cameras' figures (:data:`~makeway.sim.cameras.CAMERA_FIGURES`: ``seed004`` or ``makeway``, the
    vision and fused perceptions only); ``duty`` names the duty to yield
    (:data:`~makeway.decide.duty.DUTY_PRESETS`). ``plant``, ``vehicle``, ``road`` and
    ``steer_delay_s`` pick the simulated car (:class:`~makeway.sim.plants.PlantSpec`; the default
    is today's linear model); with a steering delay and ``delay_compensation`` the controllers
    predict over :data:`DESIGN_STEER_DELAY_S` on their design model. ``localization`` names a
    :data:`~makeway.sim.localization.LOCALIZATIONS` preset of the car's own-state estimate. With
    ``mcap`` the run is also written there as a Foxglove MCAP file (the cars, the belief, the yield
    state, the planned and driven paths; :func:`makeway.viz.foxglove.write_simulate_mcap`). Returns
    the run, the scenario and the files written (name → path).

    Raises:
        InputError: the recorded path cannot be read, or ``out`` or ``mcap`` cannot be written
            (checked first).
        UnknownNameError: an unknown scenario, controller, perception, camera figures, duty preset,
            plant, vehicle, road or localization (lists the known ones).
        ValueError: a plant option that does not apply to the plant (e.g. a vehicle on ``linear``).
    """
    spec = PlantSpec(plant=plant, vehicle=vehicle, road=road, steer_delay_s=steer_delay_s)
    spec.check()
    if plant == "linear":
        spec.build()  # the linear plant's own combination checks, before any work
    loc = LOCALIZATIONS[localization]()
    if out is not None:
        check_writable(out, folder=True)
    if mcap is not None:
        check_writable(mcap, folder=False)
    CAMERA_FIGURES[cameras]  # an unknown name fails here, whichever the perception
    sensing = PERCEPTIONS[perception](seed=seed, siren=siren, noise=noise, cameras=cameras)
    law = DUTY_PRESETS[duty]
    if path is not None:
        try:
            scenario = on_recorded_path(load_path_csv(path))
        except ValueError as exc:
            raise InputError(path, str(exc)) from None
    else:
        scenario = SCENARIOS[name]()
    default_plant = spec == PlantSpec()
    result = run_scenario(
        scenario,
        controller=controller,
        perception=sensing,
        yield_config=YieldConfig(duty=law),
        plant=None if default_plant else spec,
        localization=None if loc.perfect else loc,
        localization_seed=seed,
        delay_compensation_s=DESIGN_STEER_DELAY_S if (delay_compensation and steer_delay_s > 0.0) else 0.0,
    )
    files = write_closed_loop_report(result, scenario, out) if out is not None else {}
    if mcap is not None:
        from makeway.viz.foxglove import write_simulate_mcap

        write_simulate_mcap(mcap, result, scenario)
        files["mcap"] = str(mcap)
    return result, scenario, files
