"""The multi-EV fusion step: µs per control cycle with 5 EV tracks and 3 senses (issue 26 target:
≤ 1 ms per cycle).

    .venv/bin/python benchmarks/bench_fusion_step.py [--cycles 300] [--repeats 5] [--json FILE]

Five EVs around an ego driving at 10 m/s (behind, ahead, oncoming, two on crossing roads, all
within 60 m), each heard (siren bearing and distance), seen (light azimuth and range) and
announced (verified V2X alert) every 0.1 s cycle: 15 observations per cycle. The observations are
drawn before timing; the timed loop is :meth:`makeway.fuse.MultiEVFusion.update` alone, on one core
(the process pinned to one CPU, BLAS limited to one thread). After a 20-cycle warm-up (all five
tracks confirmed), ``--cycles`` cycles (30 s of driving by default, all five EVs still observed) are
timed; the best and median of ``--repeats`` runs are
printed as µs per cycle, with the number of confirmed tracks at the end (must be 5).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from makeway.fuse import MultiEVFusion  # noqa: E402
from makeway.fuse.multi_ev import Observation  # noqa: E402
from makeway.messages import (  # noqa: E402
    LightObservation,
    SirenObservation,
    SirenSource,
    V2XObservation,
    VehicleState,
)

DT = 0.1
EVS = [  # x0, y0 (m), yaw (rad), speed (m/s)
    (-35.0, 0.0, 0.0, 15.0),
    (40.0, 0.0, 0.0, 12.0),
    (60.0, 3.5, math.pi, 10.0),
    (30.0, -35.0, math.pi / 2, 8.0),
    (25.0, 30.0, -math.pi / 2, 8.0),
]


def ego_at(t: float) -> VehicleState:
    return VehicleState(time_s=t, x_m=10.0 * t, y_m=0.0, yaw_rad=0.0, vx_mps=10.0)


def observations(t: float, rng: np.random.Generator) -> list[Observation]:
    e = ego_at(t)
    out: list[Observation] = []
    for i, (x0, y0, yaw, v) in enumerate(EVS):
        x, y = x0 + v * t * math.cos(yaw), y0 + v * t * math.sin(yaw)
        b, d = math.atan2(y - e.y_m, x - e.x_m), math.hypot(x - e.x_m, y - e.y_m)
        src = SirenSource(b + math.radians(6.0) * rng.normal(), d * (1 + 0.25 * rng.normal()))
        out.append(SirenObservation(t, True, 0.9, 0.9, (src,)))
        out.append(
            LightObservation(
                t,
                b + math.radians(1.5) * rng.normal(),
                math.radians(1.5),
                d * (1 + 0.15 * rng.normal()),
                0.15 * d,
            )
        )
        out.append(V2XObservation(t, i, x + 3 * rng.normal(), y + 3 * rng.normal(), yaw, v, True, 3.0))
    return out


def run(cycles: int, seed: int) -> tuple[float, int]:
    rng = np.random.default_rng(seed)
    n = 20 + cycles
    steps = [(k * DT, ego_at(k * DT), observations(k * DT, rng)) for k in range(n)]
    fusion = MultiEVFusion()
    for t, ego, obs in steps[:20]:
        fusion.update(t, ego, obs)
    t0 = time.perf_counter()
    beliefs = []
    for t, ego, obs in steps[20:]:
        beliefs = fusion.update(t, ego, obs)
    elapsed = time.perf_counter() - t0
    return elapsed / cycles * 1e6, len(beliefs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cycles", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    per_run = []
    tracks = 0
    for r in range(args.repeats):
        us, tracks = run(args.cycles, seed=r)
        per_run.append(us)
    result = {
        "us_per_cycle_best": round(min(per_run), 1),
        "us_per_cycle_median": round(statistics.median(per_run), 1),
        "target_us": 1000.0,
        "tracks_confirmed": tracks,
        "observations_per_cycle": 3 * len(EVS),
        "cycles": args.cycles,
        "repeats": args.repeats,
    }
    print(
        f"fusion step, {len(EVS)} tracks x 3 senses ({3 * len(EVS)} observations/cycle), one core: "
        f"best {result['us_per_cycle_best']} µs, median {result['us_per_cycle_median']} µs per cycle "
        f"(target 1000 µs); {tracks} tracks confirmed"
    )
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
