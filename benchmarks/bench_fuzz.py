"""Fuzzing of every reader: generated inputs per reader and uncaught exceptions (issue 29, item 1,
target "0 uncaught exceptions over ≥ 100,000 generated inputs across the readers").

    .venv/bin/python benchmarks/bench_fuzz.py [--profile long|ci] [--json FILE] [-k EXPR]

Runs ``tests/test_fuzz_*.py`` (and the fuzzed commands of ``tests/test_cli_contract.py``) under the
hypothesis profile ``--profile`` (``long``: 6,000 examples per reader, weighted down for the readers
that decode video, audio or models; ``ci``: the fixed budget the test suite runs) in a child pytest,
which counts every reader call (:mod:`tests/fuzzing`, ``MAKEWAY_FUZZ_COUNTS``): inputs, accepted,
refused with one ``InputError`` (or the documented error type), and uncaught — another exception
type, or no answer within 20 s. Prints one row per reader, the total beside the target, the
failing tests if any, the wall time and the load average (the machine is shared).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_INPUTS = 100_000


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", default="long", choices=["long", "ci"], help="hypothesis profile")
    ap.add_argument("--json", type=Path, help="also write the counts here")
    ap.add_argument("-k", default=None, help="pytest -k expression (a subset of the fuzz tests)")
    ap.add_argument("--log", type=Path, help="write pytest's whole output here (the failing inputs)")
    ap.add_argument(
        "--max-minutes",
        type=float,
        default=None,
        help="stop pytest (Ctrl-C) after this long and report the inputs generated so far",
    )
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        counts_file = Path(tmp) / "counts.json"
        env = {
            **os.environ,
            "MAKEWAY_FUZZ_PROFILE": args.profile,
            "MAKEWAY_FUZZ_COUNTS": str(counts_file),
            "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]),
        }
        # the quick text readers first, the decoders of video, audio and models last
        order = {"test_fuzz_text.py": 0, "test_fuzz_files.py": 1}
        found = (ROOT / "tests").glob("test_fuzz_*.py")
        tests = [str(p) for p in sorted(found, key=lambda p: (order.get(p.name, 2), p.name))]
        tests.append(str(ROOT / "tests" / "test_cli_contract.py") + "::test_fuzz_track_through_the_cli")
        tests.append(str(ROOT / "tests" / "test_cli_contract.py") + "::test_fuzz_v2x_verify_through_the_cli")
        cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rf", *tests]
        if args.k:
            cmd += ["-k", args.k]
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        limit = None if args.max_minutes is None else 60.0 * args.max_minutes
        try:
            out, err = proc.communicate(timeout=limit)
            stopped = False
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGINT)  # pytest stops; the harness writes its counts at exit
            try:
                out, err = proc.communicate(timeout=60)
            except subprocess.TimeoutExpired:  # still busy: the counts written every 500 inputs remain
                proc.kill()
                out, err = proc.communicate()
            stopped = True
        wall = time.perf_counter() - t0
        counts: dict[str, dict[str, int]] = (
            json.loads(counts_file.read_text()) if counts_file.is_file() else {}
        )

    print(f"fuzzing, hypothesis profile {args.profile!r}: {len(counts)} readers")
    print(f"{'reader':44s} {'inputs':>8s} {'accepted':>9s} {'refused':>8s} {'uncaught':>9s}")
    total = {"inputs": 0, "accepted": 0, "rejected": 0, "uncaught": 0}
    for name, c in counts.items():
        for k in total:
            total[k] += c.get(k, 0)
        print(
            f"{name:44s} {c.get('inputs', 0):8d} {c.get('accepted', 0):9d} {c.get('rejected', 0):8d} "
            f"{c.get('uncaught', 0):9d}"
        )
    print(
        f"{'total':44s} {total['inputs']:8d} {total['accepted']:9d} {total['rejected']:8d} "
        f"{total['uncaught']:9d}"
    )
    met = total["uncaught"] == 0 and total["inputs"] >= TARGET_INPUTS
    print(
        f"target: 0 uncaught over >= {TARGET_INPUTS:,} inputs -> {total['uncaught']} uncaught over "
        f"{total['inputs']:,} inputs ({'met' if met else 'NOT met'})"
    )
    failed = [line for line in out.splitlines() if line.startswith(("FAILED", "ERROR"))]
    summary = out.strip().splitlines()[-1] if out.strip() else err.strip()[-300:]
    print(f"pytest: {summary}" + (f" (stopped after {args.max_minutes:g} min)" if stopped else ""))
    for line in failed:
        print(f"  {line}")
    if args.log:
        args.log.write_text(out + err)
    elif proc.returncode != 0 and not stopped:
        print(out[-20000:])
    print(f"wall {wall:.0f} s, load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f}")
    if args.json:
        args.json.write_text(
            json.dumps({"profile": args.profile, "readers": counts, "total": total, "wall_s": wall}, indent=1)
        )
    return 0 if proc.returncode == 0 or (stopped and total["uncaught"] == 0 and not failed) else 1


if __name__ == "__main__":
    raise SystemExit(main())
