"""Where the time from "EV on" to "stopped" goes on seed003 (an EV 50 m behind switches lights and
siren on), fused perception against the modelled one (SPEC §7; issue 26 target: EV on → stopped
within 0.5 s of the modelled-perception figure).

    .venv/bin/python benchmarks/bench_seed003_timeline.py [--seeds 8] [--first-seed 0] [--trace SEED]

Per scene seed, every time in seconds after the EV's signals switched on:

* ``net`` — the first window (its end) in which the siren network alone is sure (probability at or
  above its stored threshold);
* ``call`` — the listener's first siren call (the smoothed decision, ``is_siren``); with 0.5 s
  windows every 0.17 s, a siren 50 m away reaches the array 0.15 s after it starts, so the earliest
  window that can hold enough of it ends about 0.2–0.4 s after switch-on;
* ``light`` — the first light observation that supported an EV track (the cameras: by day, 50 m is
  at the edge of their reach);
* ``born`` / ``conf`` — the first EV track's birth and the first confirmed belief;
* ``placed`` / ``rel`` — the confirmed belief first has a distance, and first a road relation;
* ``ev_conf`` / ``yield`` / ``brake`` / ``stopped`` — the yield decision confirms the EV, starts
  the manoeuvre (MOVING_OVER), the first braking command (below −0.3 m/s²), STOPPED_WAITING.

Then the modelled perception (:class:`~makeway.sim.perception.PerceptionConfig`) on the same seeds,
its EV on → yield / stopped, and the fused figure against the target (modelled + 0.5 s). The load
average is printed beside the wall time (the machine is shared). The last line is one JSON object.

``--trace SEED`` runs that one seed only and prints, per listener window from 0.5 s before
switch-on to just after the stop, why it is early or late: the listener's siren call (smoothed
probability, the network's distance), the approach estimator's siren windows in its history, its
P(approaching) and call (``A`` approaching, ``R`` receding, ``r`` a receding call withheld, ``-``
none; :class:`~makeway.perceive.audio.motion.TrendApproach`), then the fused belief once that window
is published (confidence, relation, approaching, lights, siren, distance) and the yield state.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from makeway.decide.yield_fsm import YieldState
from makeway.fuse.multi_ev import LIGHT
from makeway.messages import EVBelief, VehicleState
from makeway.perceive.audio.motion import TrendApproach
from makeway.perceive.audio.siren_model import SirenModel
from makeway.pipeline.closed_loop import run_scenario
from makeway.pipeline.fused_perception import FusedPerception, FusedPerceptionConfig
from makeway.sim.live_array import LiveAudioConfig
from makeway.sim.perception import PerceptionConfig
from makeway.sim.scenarios import SCENARIOS, Scenario
from makeway.sim.world import SimWorld

TARGET_MARGIN_S = 0.5


@dataclass
class Recorder:
    """A fused perception that notes when each stage first did something (the module's columns)."""

    inner: FusedPerception
    times: dict[str, list[float]] = field(default_factory=dict)
    steps: list[tuple[float, EVBelief]] | None = None
    """With a trace: the belief handed to the yield decision at every control step."""

    def _mark(self, key: str, t: float) -> None:
        seen = self.times.setdefault(key, [])
        if not seen or seen[-1] != t:
            seen.append(t)

    def update(self, time_s: float, ego: VehicleState) -> EVBelief:
        belief = self.inner.update(time_s, ego)
        if self.steps is not None:
            self.steps.append((time_s, belief))
        fusion = self.inner.source.fusion
        for track in fusion.tracks:
            self._mark("born", track.born_s)
            if LIGHT in track.sense_time_s:
                self._mark("light", track.sense_time_s[LIGHT])
        for b in self.inner.beliefs():
            self._mark("conf", time_s)
            if math.isfinite(b.distance_m):
                self._mark("placed", time_s)
            if b.relation.value != "unknown":
                self._mark("rel", time_s)
        return belief

    def beliefs(self) -> list[EVBelief]:
        return self.inner.beliefs()

    @property
    def observations(self) -> list[Any]:
        return self.inner.observations

    def close(self) -> None:
        self.inner.close()


class ApproachTap:
    """Stands in for the listener's approach estimator and notes, per window, what it saw and said
    (``--trace``); everything else goes to the estimator itself."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.rows: list[dict[str, Any]] = []

    def update(
        self,
        window: np.ndarray,
        sample_rate: int,
        time_s: float,
        *,
        distance_m: float | None = None,
        is_siren: bool = True,
    ) -> tuple[bool | None, float | None]:
        out = self.inner.update(window, sample_rate, time_s, distance_m=distance_m, is_siren=is_siren)
        est = self.inner
        raw = None
        if isinstance(est, TrendApproach) and est.features_ is not None and est.session_ is not None:
            raw = float(est.predict_proba(est.features_[None])[0])
        self.rows.append(
            {
                "t_end": float(time_s),
                "siren_windows": len(getattr(est, "history_", ())),
                "p_approach": raw,
                "approaching": out[0],
                "withheld": bool(getattr(est, "withheld_", False)),
            }
        )
        return out

    def reset(self) -> ApproachTap:
        self.inner.reset()
        return self

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


@dataclass(frozen=True)
class RecordedFused:
    """A :class:`FusedPerceptionConfig` whose built perception is recorded (:class:`Recorder`;
    with ``trace`` also every control step's belief and the approach estimator's windows)."""

    config: FusedPerceptionConfig
    built: list[Recorder] = field(default_factory=list, compare=False)
    trace: bool = False
    taps: list[ApproachTap] = field(default_factory=list, compare=False)

    @property
    def sees_lights(self) -> bool:
        return self.config.sees_lights

    def build(self, scenario: Scenario, world: SimWorld) -> Recorder:
        rec = Recorder(self.config.build(scenario, world), steps=[] if self.trace else None)
        if self.trace and rec.inner.siren is not None:
            tap = ApproachTap(rec.inner.siren.listener.approach)
            rec.inner.siren.listener.approach = tap  # type: ignore[assignment]
            self.taps.append(tap)
        self.built.append(rec)
        return rec


def _first_transition(transitions: list[tuple[float, str, str, str]], state: str) -> float | None:
    return next((t for t, _, to, _ in transitions if to == state), None)


def timeline(seed: int, model: SirenModel, trace: bool = False) -> dict[str, Any]:
    """The fused run's timeline for one scene seed (times after switch-on, s); with ``trace`` also
    its per-window trace under ``"trace"`` (module docstring)."""
    spec = RecordedFused(
        FusedPerceptionConfig(audio=LiveAudioConfig(seed=seed), seed=seed, model=model), trace=trace
    )
    res = run_scenario(SCENARIOS["seed003"](), perception=spec)
    log = res.log
    on = float(log["t"][np.flatnonzero(log["ev_on"] > 0.5)[0]])
    marks: dict[str, float | None] = {}
    heard = [o for o, _ in res.siren if o.t_end > on]
    marks["net"] = next((o.t_end for o in heard if o.probability >= model.threshold), None)
    marks["call"] = next((o.t_end for o in heard if o.is_siren), None)
    times = spec.built[0].times
    for key in ("light", "born", "conf", "placed", "rel"):
        marks[key] = min((t for t in times.get(key, []) if t >= on - 1e-9), default=None)
    marks["ev_conf"] = _first_transition(res.transitions, "ev_confirmed")
    marks["yield"] = _first_transition(res.transitions, "moving_over")
    brake = np.flatnonzero((log["t"] >= on) & (log["accel_cmd"] < -0.3))
    marks["brake"] = float(log["t"][brake[0]]) if brake.size else None
    marks["stopped"] = _first_transition(res.transitions, "stopped_waiting")
    out: dict[str, Any] = {k: (round(v - on, 2) if v is not None else None) for k, v in marks.items()}
    out["action_ok"] = res.metrics["action_ok"]
    out["collision"] = res.metrics["collision"]
    if trace:
        out["trace"] = _trace(spec, res, on, marks["stopped"])
    return out


def _trace(spec: RecordedFused, res: Any, on: float, stopped: float | None) -> list[dict[str, Any]]:
    """One row per listener window from 0.5 s before switch-on to 0.3 s after the stop (module
    docstring), times after switch-on."""
    log = res.log
    states = list(YieldState)
    steps = spec.built[0].steps or []
    step_t = np.array([t for t, _ in steps])
    heard = {round(o.t_end, 6): o for o, _ in res.siren}
    latency = spec.config.siren_latency_s
    end = (stopped if stopped is not None else float(log["t"][-1])) + 0.3
    rows = []
    for a in spec.taps[0].rows if spec.taps else []:
        t = a["t_end"]
        if not on - 0.5 <= t <= end:
            continue
        o = heard.get(round(t, 6))
        src = o.sources[0] if o is not None and o.sources else None
        k = int(np.searchsorted(step_t, t + latency - 1e-9))
        b = steps[k][1] if k < len(steps) else None
        j = min(int(np.searchsorted(log["t"], t + latency - 1e-9)), len(log["t"]) - 1)
        rows.append(
            {
                "t": round(t - on, 2),
                "is_siren": None if o is None else bool(o.is_siren),
                "p_smooth": None if o is None else round(float(o.smoothed_probability), 3),
                "distance_m": None if src is None or src.distance_m is None else round(src.distance_m, 1),
                "siren_windows": a["siren_windows"],
                "p_approach": None if a["p_approach"] is None else round(a["p_approach"], 3),
                "call": "r" if a["withheld"] else {True: "A", False: "R", None: "-"}[a["approaching"]],
                "reported": None if src is None else src.approaching,
                "fused": None if b is None or not b.detected else _belief_row(b),
                "state": states[int(log["state"][j])].value,
            }
        )
    return rows


def _belief_row(b: EVBelief) -> dict[str, Any]:
    return {
        "conf": round(float(b.confidence), 2),
        "relation": b.relation.value,
        "approaching": b.approaching,
        "lights": b.lights,
        "siren": b.siren,
        "distance_m": round(b.distance_m, 1) if math.isfinite(b.distance_m) else None,
    }


def print_trace(seed: int, row: dict[str, Any]) -> None:
    """The ``--trace`` table of one seed."""
    print(f"seed {seed}, per listener window (times s after switch-on; call: A/R, r = receding withheld):")
    print(
        f"{'t':>6s} {'siren':>5s} {'p_sm':>5s} {'dist':>6s} {'nwin':>4s} {'P(app)':>6s} {'call':>4s}  "
        f"{'fused: conf':>11s} {'relation':>9s} {'appr':>5s} {'lt':>2s} {'sr':>2s} {'dist':>6s}  state"
    )

    def cell(v: Any, width: int, fmt: str = "") -> str:
        if v is None:
            return f"{'—':>{width}s}"
        if isinstance(v, bool):
            return f"{'y' if v else 'n':>{width}s}"
        return f"{v:>{width}{fmt}}"

    for r in row["trace"]:
        f = r["fused"]
        fused = (
            f"{cell(f['conf'], 11, '.2f')} {f['relation']:>9s} {cell(f['approaching'], 5)} "
            f"{cell(f['lights'], 2)} {cell(f['siren'], 2)} {cell(f['distance_m'], 6, '.1f')}"
            if f is not None
            else f"{'—':>11s} {'':>9s} {'':>5s} {'':>2s} {'':>2s} {'':>6s}"
        )
        print(
            f"{r['t']:6.2f} {cell(r['is_siren'], 5)} {cell(r['p_smooth'], 5, '.2f')} "
            f"{cell(r['distance_m'], 6, '.1f')} {r['siren_windows']:4d} {cell(r['p_approach'], 6, '.2f')} "
            f"{r['call']:>4s}  {fused}  {r['state']}"
        )
    print(
        "transitions: "
        + ", ".join(f"{k} {row[k]:.2f}" for k in ("ev_conf", "yield", "stopped") if row[k] is not None)
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=8, help="scene seeds")
    ap.add_argument("--first-seed", type=int, default=0, help="the first scene seed")
    ap.add_argument(
        "--trace", type=int, default=None, metavar="SEED", help="only this seed, with its per-window trace"
    )
    args = ap.parse_args()
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    model = SirenModel()
    if args.trace is not None:
        t0 = time.perf_counter()
        row = timeline(args.trace, model, trace=True)
        print_trace(args.trace, row)
        print(f"wall time {time.perf_counter() - t0:.0f} s, load average {os.getloadavg()[0]:.1f}")
        print(json.dumps({"seed": args.trace, **row}))
        return 0
    t0 = time.perf_counter()
    cols = ("net", "call", "light", "born", "conf", "placed", "rel", "ev_conf", "yield", "brake", "stopped")
    print("fused, s after switch-on:")
    print(f"{'seed':>4s} " + " ".join(f"{c:>7s}" for c in cols) + "  action_ok")
    fused = []
    for seed in seeds:
        row = timeline(seed, model)
        fused.append({"seed": seed, **row})
        cells = " ".join(f"{row[c]:7.2f}" if row[c] is not None else f"{'—':>7s}" for c in cols)
        print(f"{seed:>4d} {cells}  {row['action_ok']}", flush=True)
    modelled = []
    for seed in seeds:
        m = run_scenario(SCENARIOS["seed003"](), perception=PerceptionConfig(seed=seed)).metrics
        modelled.append(
            {
                "seed": seed,
                "yield": _r(m["time_active_to_yield_s"]),
                "stopped": _r(m["time_active_to_stopped_s"]),
            }
        )
    wall = time.perf_counter() - t0
    anchor = statistics.median(r["stopped"] for r in modelled if r["stopped"] is not None)
    stops = [r["stopped"] for r in fused if r["stopped"] is not None]
    within = sum(s <= anchor + TARGET_MARGIN_S + 1e-9 for s in stops)
    print(
        "modelled perception, EV on → yield / stopped: "
        + ", ".join(f"{_f(r['yield'])} / {_f(r['stopped'])}" for r in modelled)
    )
    print(
        f"EV on → stopped, fused: median {statistics.median(stops):.2f} s, range {min(stops):.2f}–"
        f"{max(stops):.2f} s; modelled {anchor:.2f} s; target ≤ {anchor + TARGET_MARGIN_S:.2f} s "
        f"(within {TARGET_MARGIN_S} s): {within}/{len(stops)} seeds"
    )
    print(f"wall time {wall:.0f} s, load average {os.getloadavg()[0]:.1f}")
    summary = {"modelled_stopped_s": anchor, "target_s": anchor + TARGET_MARGIN_S, "within": within}
    print(json.dumps({"fused": fused, "modelled": modelled, "summary": summary, "wall_s": round(wall, 1)}))
    return 0


def _r(v: float | None) -> float | None:
    return None if v is None else round(v, 2)


def _f(v: float | None) -> str:
    return "—" if v is None else f"{v:.2f}"


if __name__ == "__main__":
    raise SystemExit(main())
