"""How fast the closed loop runs on CommonRoad's multi-body plant, against an earlier commit (issue 30).

    .venv/bin/python benchmarks/bench_closed_loop_speed.py [--baseline REV] [--rounds 3] [--quick]
                                                          [--scenarios seed003,curve_behind|all]

Target: the seed003 closed loop (feedforward + feedback, the multi-body BMW 320i on a dry road,
0.15 s steering delay compensated) ≥ 20× real time in one process on the project's 2 shared
cores, with the results unchanged: max |Δe_lat| ≤ 1e-4 m against the baseline code.

The baseline is the source tree of ``--baseline`` (a git revision; default ``131a20a``, the code
before the speed work of issue 30), unpacked with ``git archive`` into a temporary folder. Each
round runs one process on the baseline's ``src`` and one on this checkout's, alternating (so a
change in the machine's load hits both alike); each process runs every cell once, one after the
other, timing each run after the gain design and the imports; the figures are the median over the
rounds. Beside each: the CPU time (what the loop costs when the core is shared), the load average,
and the largest difference in ``e_lat`` (and in the final position) between the two codes.

Cells: each scenario of ``--scenarios`` (default seed003; ``all``: every built-in one) on the
multi-body BMW 320i, Ford Escort and VW Vanagon, dry and wet (``--quick``: the BMW dry only).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TARGET_X = 20.0
TARGET_CELL = ("seed003", "bmw320i", "dry")  # the target's run; elsewhere only Δe_lat is checked
MAX_DELTA_M = 1e-4
DELAY_S = 0.15
CARS = [(v, r) for v in ("bmw320i", "ford_escort", "vw_vanagon") for r in ("dry", "wet")]

Cell = tuple[str, str, str]  # scenario, car, road


def worker(cells: list[Cell], out_dir: Path) -> None:
    """Time ``run_scenario`` on each cell (in whatever ``makeway`` is on the path); print JSON."""
    import makeway
    from makeway.control.lateral import default_gains
    from makeway.pipeline.closed_loop import run_scenario
    from makeway.sim.plants import PlantSpec
    from makeway.sim.scenarios import SCENARIOS
    from makeway.vehicle import VehicleParams

    default_gains(VehicleParams())  # once per car, not per run
    rows = []
    for scenario, vehicle, road in cells:
        sc = SCENARIOS[scenario]()
        spec = PlantSpec(plant="multi_body", vehicle=vehicle, road=road, steer_delay_s=DELAY_S)
        t0, c0 = time.perf_counter(), time.process_time()
        result = run_scenario(sc, plant=spec, delay_compensation_s=DELAY_S)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        np.savez(out_dir / f"{scenario}_{vehicle}_{road}.npz", **result.log)
        rows.append(
            {
                "cell": [scenario, vehicle, road],
                "wall": wall,
                "cpu": cpu,
                "sim": sc.duration_s,
                "load": os.getloadavg()[0],
                "code": str(Path(makeway.__file__).resolve().parents[1]),
            }
        )
    print(json.dumps(rows))


def _unpack(rev: str, into: Path) -> Path:
    """The ``src`` tree of git revision ``rev`` under ``into``."""
    blob = subprocess.run(
        ["git", "-C", str(ROOT), "archive", "--format=tar", rev, "src"], check=True, capture_output=True
    ).stdout
    with tarfile.open(fileobj=BytesIO(blob)) as tar:
        tar.extractall(into, filter="data")
    return into / "src"


def _run(src: Path, cells: list[Cell], out_dir: Path) -> list[dict[str, Any]]:
    out_dir.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, __file__, "--worker", "--out", str(out_dir), "--cells", _cells_arg(cells)]
    env = {**os.environ, "PYTHONPATH": str(src)}
    done = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env, cwd=ROOT)
    rows: list[dict[str, Any]] = json.loads(done.stdout.strip().splitlines()[-1])
    if any(Path(r["code"]) != src.resolve() for r in rows):  # e.g. an installed makeway shadowing src
        raise RuntimeError(f"the worker imported makeway from {rows[0]['code']}, not from {src}")
    return rows


def _cells_arg(cells: list[Cell]) -> str:
    return ",".join(":".join(c) for c in cells)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", default="131a20a", help="git revision to compare against")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds (median reported)")
    ap.add_argument("--quick", action="store_true", help="the BMW on a dry road only")
    ap.add_argument("--scenarios", default="seed003", help="comma-separated scenario names, or all")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--cells", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker([(c.split(":")[0], c.split(":")[1], c.split(":")[2]) for c in args.cells.split(",")], args.out)
        return 0
    from makeway.sim.scenarios import SCENARIOS

    names = list(SCENARIOS) if args.scenarios == "all" else args.scenarios.split(",")
    for name in names:
        SCENARIOS[name]  # an unknown name fails here, before any run
    cars = CARS[:1] if args.quick else CARS
    cells = [(name, v, r) for name in names for v, r in cars]
    with tempfile.TemporaryDirectory(prefix="makeway-speed-") as tmp:
        base_src = _unpack(args.baseline, Path(tmp) / "baseline")
        codes = {"baseline": base_src, "now": ROOT / "src"}
        times: dict[str, dict[tuple[str, ...], list[dict[str, Any]]]] = {k: {} for k in codes}
        print(
            f"closed loop, multi-body, {DELAY_S} s steering delay; {args.rounds} rounds alternating "
            f"baseline {args.baseline} and this checkout (load {os.getloadavg()[0]:.2f})",
            flush=True,
        )
        for k in range(args.rounds):
            for name, src in codes.items():
                for row in _run(src, cells, Path(tmp) / name):
                    times[name].setdefault(tuple(row["cell"]), []).append(row)
            print(
                f"  round {k + 1}/{args.rounds} (load {os.getloadavg()[0]:.2f})", file=sys.stderr, flush=True
            )
        print(
            f"\nreal-time factor (simulated s per wall s; CPU: per CPU s), median of {args.rounds}; "
            f"target now ≥ {TARGET_X:.0f}×, max|Δe_lat| ≤ {MAX_DELTA_M:g} m"
        )
        print(
            f"{'scenario':16s} {'car':12s} {'road':4s} {'baseline':>8s} {'now':>6s} {'speed-up':>8s} "
            f"{'CPU base':>8s} {'CPU now':>7s} {'max|Δe_lat| m':>13s} {'|Δ end| m':>9s}"
        )
        summary: dict[str, Any] = {}
        all_ok = True
        for cell in cells:
            b, n = times["baseline"][cell], times["now"][cell]
            sim = n[0]["sim"]
            xb = sim / statistics.median(r["wall"] for r in b)
            xn = sim / statistics.median(r["wall"] for r in n)
            xn_cpu = sim / statistics.median(r["cpu"] for r in n)
            xb_cpu = sim / statistics.median(r["cpu"] for r in b)
            lb = np.load(Path(tmp) / "baseline" / f"{'_'.join(cell)}.npz")
            ln = np.load(Path(tmp) / "now" / f"{'_'.join(cell)}.npz")
            d_lat = float(np.max(np.abs(lb["e_lat"] - ln["e_lat"])))
            d_end = float(np.hypot(lb["x"][-1] - ln["x"][-1], lb["y"][-1] - ln["y"][-1]))
            ok = d_lat <= MAX_DELTA_M and (xn >= TARGET_X or cell != TARGET_CELL)
            all_ok &= ok
            print(
                f"{cell[0]:16s} {cell[1]:12s} {cell[2]:4s} {xb:7.1f}× {xn:5.1f}× {xn / xb:8.2f} "
                f"{xb_cpu:7.1f}× {xn_cpu:6.1f}× {d_lat:13.2e} {d_end:9.2e}  {'ok' if ok else 'NO'}"
            )
            summary["/".join(cell)] = {
                "baseline_x": xb,
                "now_x": xn,
                "now_cpu_x": xn_cpu,
                "baseline_cpu_x": xb_cpu,
                "speedup": xn / xb,
                "max_delta_e_lat_m": d_lat,
                "delta_end_m": d_end,
            }
        loads = [r["load"] for rows in times["now"].values() for r in rows]
        print(
            f"load average during the runs: {min(loads):.2f}–{max(loads):.2f} (2 shared cores; wall-clock "
            f"factors fall with the load, CPU ones far less)"
        )
        print(f"all targets met: {'yes' if all_ok else 'NO'}")
        summary["targets_met"] = all_ok
        print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
