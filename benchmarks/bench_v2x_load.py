"""V2X load on loopback: 20 roadside units × 10 Hz to 50 subscribed cars over zenoh (issue 27, target
"Load": no loss, flat memory).

    .venv/bin/python benchmarks/bench_v2x_load.py [--minutes 10] [--units 20] [--cars 50] [--car-procs 5]
        [--rate-hz 10] [--relevance-m 1000] [--unit-spacing-m 800] [--json FILE]

Layout (all zenoh peers on 127.0.0.1, TCP, scouting off):

* **one publisher process** with all units: it listens on one port; each unit has its own identity
  (key and certificate from one local root) and publishes on its own segment ``load-UU``; every
  ``1/rate`` s each unit stamps, signs and publishes one alert (units staggered evenly over the
  period);
* **``--car-procs`` subscriber processes** with ``cars / car-procs`` cars each: every car has its own
  zenoh session (connected to the publisher), its own :class:`~makeway.v2x.transport.AlertSubscriber`
  on all unit segments, its own :class:`~makeway.v2x.security.Verifier` (replay cache included) and
  its own thread that verifies every payload — so each car does the verification work a real car
  would. ``--no-verify`` has each car read its payloads only (the 1609.2 envelope and the DENM, no
  signature check): the transport's share of the load alone, for a host with too few cores for
  every car's signature checks (each real car has its own CPU: 200 alerts/s at 120–160 µs is
  2.4–3.2 % of one core).

Where: the units stand on a grid ``--unit-spacing-m`` apart (5 × 4 for 20 units; a district with a
unit at every main intersection), each reporting an EV at its own position; car ``i`` stands at a
random point of the grid's area (seeded, the same in every run). ``--relevance-m R`` has each car
verify on demand (:class:`~makeway.v2x.belief.RelevanceArea`): every payload is read and put
through every check that needs no signature, and only alerts whose EV is within ``R`` m of the car
have their signature checked; the others count as received, "not relevant". Without it (the
default) every car checks every signature.

Per car: alerts lost (published by the units minus distinct (unit, sequence) verified — or, verifying
on demand, found not relevant — by the car; an alert still queued unread at the end counts as lost),
relevant alerts lost (from the units within ``R``: published minus verified), verification failures
(by reason), duplicates, and payloads taken off the queue; per process: resident memory (VmRSS, MiB) sampled
every 10 s. Memory is called flat when the mean of the last minute's samples exceeds the first
minute's by less than ``FLAT_MIB`` in every process (a steady leak of one cached alert per car per
verification would grow a car process by tens of MiB per minute). Also the lag from an alert's
generation time to its arrival (zenoh's callback) and to its verification at the car (p50/p99/max,
wall clock shared by the processes): a gap between the two is the car's verification queue.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from makeway.v2x.belief import LocalFrame, RelevanceArea
from makeway.v2x.message import Alert, MalformedAlertError
from makeway.v2x.security import (
    DEFAULT_SIGNER_FORM,
    NOT_RELEVANT,
    SIGNER_FORMS,
    TrustStore,
    Verifier,
    keygen,
    load_identity,
    parse_signed,
    sign_alert,
)
from makeway.v2x.transport import AlertPublisher, AlertSubscriber, free_loopback_port, open_peer

FLAT_MIB = 5.0
FLAT_PCT = 5.0  # every RSS sample after the first minute within ± this % of the first minute's mean
RSS_EVERY_S = 10.0
SETTLE_S = 3.0  # after the last alert, how long cars keep listening
LAT0, LON0 = 48.137, 11.575  # the grid's south-west corner (WGS-84 degrees)
M_PER_DEG_LAT = 111_200.0  # metres per degree of latitude near 48° (placement only; distances use LocalFrame)
CAR_SEED = 27


def unit_positions(units: int, spacing_m: float) -> list[tuple[float, float]]:
    """(lat, lon) of each unit: a grid of ``ceil(sqrt(units))`` columns, ``spacing_m`` apart."""
    cols = int(np.ceil(np.sqrt(units)))
    m_per_deg_lon = M_PER_DEG_LAT * np.cos(np.radians(LAT0))
    return [
        (LAT0 + (u // cols) * spacing_m / M_PER_DEG_LAT, LON0 + (u % cols) * spacing_m / m_per_deg_lon)
        for u in range(units)
    ]


def car_positions(n_cars: int, units: int, spacing_m: float) -> list[tuple[float, float]]:
    """(lat, lon) of each car: uniform over the units' grid (seeded; the same in every process)."""
    grid = np.array(unit_positions(units, spacing_m))
    rng = np.random.default_rng(CAR_SEED)
    lo, hi = grid.min(axis=0), grid.max(axis=0)
    return [(float(a), float(b)) for a, b in rng.uniform(lo, hi, size=(n_cars, 2))]


def rss_mib() -> float:
    """This process's resident set size (MiB), from /proc/self/status."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS in /proc/self/status")


class RssSampler(threading.Thread):
    """Samples :func:`rss_mib` every ``RSS_EVERY_S`` s as (seconds since start, MiB)."""

    def __init__(self, t0: float) -> None:
        super().__init__(daemon=True)
        self.t0 = t0
        self.samples: list[tuple[float, float]] = []
        self.stop = threading.Event()

    def run(self) -> None:
        while True:
            self.samples.append((time.time() - self.t0, rss_mib()))
            if self.stop.wait(RSS_EVERY_S):
                return


class CpuMeter:
    """This process's CPU time (every thread, user + system) over a stretch of wall time: the mean
    number of cores it kept busy."""

    def __init__(self) -> None:
        t = os.times()
        self.cpu0, self.wall0 = t.user + t.system, time.monotonic()

    def cores(self) -> float:
        t = os.times()
        return (t.user + t.system - self.cpu0) / max(time.monotonic() - self.wall0, 1e-9)


def _wait_file(path: Path, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        if time.monotonic() > deadline:
            raise SystemExit(f"timed out waiting for {path}")
        time.sleep(0.05)


def publisher(
    keys: Path,
    port: int,
    units: int,
    rate_hz: float,
    duration_s: float,
    work: Path,
    spacing_m: float,
    signer: str = DEFAULT_SIGNER_FORM,
) -> None:
    """All units in one process: listen, wait for ``go`` (its content: the start time, Unix s), then
    publish until start + ``duration_s``; write the per-unit counts and RSS samples to ``pub.json``."""
    idents = [load_identity(keys / f"rsu{u:02d}.key") for u in range(units)]
    where = unit_positions(units, spacing_m)
    session = open_peer(listen=[f"tcp/127.0.0.1:{port}"])
    pubs = [AlertPublisher(session, f"load-{u:02d}") for u in range(units)]
    (work / "pub.ready").touch()
    _wait_file(work / "go", 120.0)
    t0 = float((work / "go").read_text())
    sampler = RssSampler(t0)
    published = [0] * units
    period = 1.0 / rate_hz
    ticks = round(duration_s * rate_hz)
    while time.time() < t0:
        time.sleep(0.01)
    sampler.start()
    cpu = CpuMeter()
    late = 0
    for k in range(ticks):
        for u in range(units):
            at = t0 + k * period + u * period / units
            wait = at - time.time()
            if wait > 0:
                time.sleep(wait)
            elif wait < -period:
                late += 1
            alert = Alert.from_physical(
                station_id=idents[u].station_id,
                generation_time_s=time.time(),
                sequence=k,
                lat_deg=where[u][0],
                lon_deg=where[u][1],
                heading_deg=30.0,
                speed_mps=16.7,
            )
            pubs[u].publish(sign_alert(alert, idents[u], signer=signer))
            published[u] += 1
    cores = cpu.cores()
    sampler.stop.set()
    sampler.join()
    time.sleep(SETTLE_S)
    (work / "pub.json").write_text(
        json.dumps(
            {"published": published, "late_over_one_period": late, "rss": sampler.samples, "cpu_cores": cores}
        )
    )
    session.close()


def cars(
    keys: Path,
    port: int,
    units: int,
    n_cars: int,
    proc: int,
    rate_hz: float,
    duration_s: float,
    work: Path,
    verify: bool = True,
    relevance_m: float = 0.0,
    spacing_m: float = 800.0,
    first_car: int = 0,
    total_cars: int = 0,
) -> None:
    """``n_cars`` cars in one process, each its own session, subscriber, verifier and thread; write
    per-car counts and this process's RSS samples to ``cars-P.json``. With ``verify`` off a car only
    decodes each payload (the transport's share of the work, without the signature check); with
    ``relevance_m`` > 0 it verifies on demand (module docstring). Cars ``first_car`` … of
    ``total_cars`` (their positions)."""
    store = TrustStore.load(keys / "trust")
    where = car_positions(total_cars, units, spacing_m)[first_car : first_car + n_cars]
    segments = [f"load-{u:02d}" for u in range(units)]
    sessions = [open_peer(connect=[f"tcp/127.0.0.1:{port}"]) for _ in range(n_cars)]
    subs = [AlertSubscriber(s, segments, queue="fifo") for s in sessions]  # counts every alert lost
    time.sleep(1.0)
    (work / f"cars-{proc}.ready").touch()
    _wait_file(work / "go", 120.0)
    t0 = float((work / "go").read_text())
    sampler = RssSampler(t0)
    end = t0 + duration_s + SETTLE_S
    results: list[dict[str, Any]] = [{} for _ in range(n_cars)]
    ticks = round(duration_s * rate_hz)
    # the bookkeeping is allocated and touched before the run (np.full writes every page), so the
    # RSS samples see only what the transport, the verifiers and the queues add
    got_seq = [np.full((units, ticks), False) for _ in range(n_cars)]
    lags = [np.full(units * ticks, np.nan, dtype=np.float32) for _ in range(n_cars)]
    arrivals = [np.full(units * ticks, np.nan, dtype=np.float32) for _ in range(n_cars)]

    def car(i: int) -> None:
        area = RelevanceArea(relevance_m, *where[i]) if relevance_m > 0 else None
        verifier = Verifier(store, relevant=area)
        by_station: dict[int, int] = {}
        failures: Counter[str] = Counter()
        duplicates = 0
        handled = 0
        verified = 0
        for got in subs[i].receive(max(0.0, end - time.time())):
            now = time.time()
            handled += 1
            checked = False
            if verify:
                v = verifier.verify(got.payload, now)
                if v.alert is None or not (v.valid or v.reason == NOT_RELEVANT):
                    failures[v.reason.split(":")[0]] += 1
                    continue
                alert, checked = v.alert, v.valid
                verified += checked
            else:
                try:
                    alert = parse_signed(got.payload, check_certificate=False).alert
                except MalformedAlertError as exc:
                    failures[f"malformed: {exc}"] += 1
                    continue
            u = by_station.setdefault(alert.station_id, int(got.key.rsplit("-", 1)[1]))
            k = alert.sequence
            duplicates += bool(got_seq[i][u, k])
            got_seq[i][u, k] = True
            if checked or not verify or area is None:
                lags[i][u * ticks + k] = now - alert.generation_time_s
            arrivals[i][u * ticks + k] = got.time_s - alert.generation_time_s
        results[i] = {
            "received": got_seq[i].sum(axis=1).tolist(),
            "verified": verified,
            "failures": dict(failures),
            "duplicates": duplicates,
            "handled": handled,
        }

    threads = [threading.Thread(target=car, args=(i,)) for i in range(n_cars)]
    while time.time() < t0:
        time.sleep(0.01)
    sampler.start()
    cpu = CpuMeter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    cores = cpu.cores()
    sampler.stop.set()
    sampler.join()
    all_lags = np.concatenate(lags).astype(np.float64) * 1000
    all_lags = all_lags[np.isfinite(all_lags)]
    all_arrivals = np.concatenate(arrivals).astype(np.float64) * 1000
    all_arrivals = all_arrivals[np.isfinite(all_arrivals)]
    (work / f"cars-{proc}.json").write_text(
        json.dumps(
            {
                "cars": results,
                "rss": sampler.samples,
                "cpu_cores": cores,
                "lag_ms": [float(np.percentile(all_lags, q)) for q in (50, 99, 100)] if all_lags.size else [],
                "arrival_ms": [float(np.percentile(all_arrivals, q)) for q in (50, 99, 100)]
                if all_arrivals.size
                else [],
            }
        )
    )
    for sub, s in zip(subs, sessions, strict=True):
        sub.close()
        s.close()


def _flat(samples: list[tuple[float, float]], duration_s: float) -> tuple[float, float]:
    """Mean RSS (MiB) over the first minute and over the last minute of the run."""
    first = [m for t, m in samples if t < 60.0]
    last = [m for t, m in samples if t >= duration_s - 60.0]
    return float(np.mean(first)), float(np.mean(last))


def _spread_pct(samples: list[tuple[float, float]]) -> tuple[float, float]:
    """Lowest and highest RSS sample after the first minute, in % of the first minute's mean."""
    first = float(np.mean([m for t, m in samples if t < 60.0]))
    later = [m for t, m in samples if t >= 60.0] or [first]
    return 100.0 * (min(later) / first - 1.0), 100.0 * (max(later) / first - 1.0)


def relevant_units(n_cars: int, units: int, spacing_m: float, relevance_m: float) -> list[list[bool]]:
    """Per car, per unit: is the unit's EV within ``relevance_m`` of the car (every unit when
    ``relevance_m`` is 0: verify everything)."""
    ev = unit_positions(units, spacing_m)
    out = []
    for lat, lon in car_positions(n_cars, units, spacing_m):
        frame = LocalFrame(lat, lon)
        out.append([relevance_m <= 0 or float(np.hypot(*frame.to_local(*p))) <= relevance_m for p in ev])
    return out


def run(
    minutes: float,
    units: int,
    n_cars: int,
    car_procs: int,
    rate_hz: float,
    verify: bool = True,
    relevance_m: float = 0.0,
    spacing_m: float = 800.0,
    signer: str = DEFAULT_SIGNER_FORM,
) -> dict[str, Any]:
    duration_s = minutes * 60.0
    if duration_s * rate_hz > 65536:
        raise SystemExit("at most 65536 alerts per unit: DENM sequence numbers are 16 bits")
    if n_cars % car_procs:
        raise SystemExit(f"--cars {n_cars} is not a multiple of --car-procs {car_procs}")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        keys, work = root / "keys", root / "work"
        work.mkdir()
        for u in range(units):
            keygen(keys, f"rsu{u:02d}")
        port = free_loopback_port()
        common = ["--keys", str(keys), "--port", str(port), "--work", str(work), "--units", str(units)]
        common += ["--minutes", str(minutes), "--rate-hz", str(rate_hz), "--unit-spacing-m", str(spacing_m)]
        common += ["--relevance-m", str(relevance_m), "--cars-total", str(n_cars), "--signer", signer]
        procs = [subprocess.Popen([sys.executable, __file__, "--role", "publisher", *common])]
        _wait_file(work / "pub.ready", 60.0)
        per = n_cars // car_procs
        for p in range(car_procs):
            procs.append(
                subprocess.Popen(
                    [
                        sys.executable,
                        __file__,
                        "--role",
                        "cars",
                        "--proc",
                        str(p),
                        "--cars",
                        str(per),
                        "--first-car",
                        str(p * per),
                        "--verify" if verify else "--no-verify",
                        *common,
                    ]
                )
            )
        for p in range(car_procs):
            _wait_file(work / f"cars-{p}.ready", 120.0)
        time.sleep(1.0)  # let the last subscriptions propagate to the publisher
        (work / "go").write_text(repr(time.time() + 1.0))
        for proc in procs:
            if proc.wait(timeout=duration_s + 120.0) != 0:
                raise SystemExit(f"a child process failed: {proc.args!r}")
        pub = json.loads((work / "pub.json").read_text())
        car_out = [json.loads((work / f"cars-{p}.json").read_text()) for p in range(car_procs)]
    published = pub["published"]
    lost_per_car = [
        sum(p - r for p, r in zip(published, c["received"], strict=True))
        for co in car_out
        for c in co["cars"]
    ]
    per_car = [c for co in car_out for c in co["cars"]]
    relevant = relevant_units(n_cars, units, spacing_m, relevance_m)
    relevant_published = [sum(p for p, r in zip(published, rel, strict=True) if r) for rel in relevant]
    relevant_lost = [
        sum(p - got for p, got, r in zip(published, c["received"], rel, strict=True) if r)
        for c, rel in zip(per_car, relevant, strict=True)
    ]
    failures: Counter[str] = Counter()
    for co in car_out:
        for c in co["cars"]:
            failures.update(c["failures"])
    rss = {"publisher": _flat(pub["rss"], duration_s)}
    spread = {"publisher": _spread_pct(pub["rss"])}
    for p, co in enumerate(car_out):
        rss[f"cars-{p}"] = _flat(co["rss"], duration_s)
        spread[f"cars-{p}"] = _spread_pct(co["rss"])
    return {
        "minutes": minutes,
        "units": units,
        "cars": n_cars,
        "car_processes": car_procs,
        "rate_hz": rate_hz,
        "verify": verify,
        "published": sum(published),
        "expected_per_car": sum(published),
        "lost_total": sum(lost_per_car),
        "lost_max_per_car": max(lost_per_car),
        "cars_with_loss": sum(x > 0 for x in lost_per_car),
        "relevance_m": relevance_m,
        "signer": signer,
        "unit_spacing_m": spacing_m,
        "relevant_published_total": sum(relevant_published),
        "relevant_lost_total": sum(relevant_lost),
        "relevant_units_per_car_min_median_max": [
            int(min(map(sum, relevant))),
            float(np.median([sum(r) for r in relevant])),
            int(max(map(sum, relevant))),
        ],
        "verified_total": sum(c.get("verified", 0) for c in per_car),
        "verification_failures": dict(failures),
        "duplicates": sum(c["duplicates"] for co in car_out for c in co["cars"]),
        "handled_total": sum(c["handled"] for co in car_out for c in co["cars"]),
        "publisher_late_over_one_period": pub["late_over_one_period"],
        "rss_first_last_min_mib": rss,
        "rss_flat": all(last - first < FLAT_MIB for first, last in rss.values()),
        "rss_after_first_min_pct_low_high": spread,
        "rss_samples_s_mib": {
            "publisher": pub["rss"],
            **{f"cars-{p}": co["rss"] for p, co in enumerate(car_out)},
        },
        "rss_flat_pct": all(lo >= -FLAT_PCT and hi <= FLAT_PCT for lo, hi in spread.values()),
        "lag_ms_p50_p99_max_per_proc": [co["lag_ms"] for co in car_out],
        "cpu_cores_publisher": pub["cpu_cores"],
        "cpu_cores_per_car_proc": [co["cpu_cores"] for co in car_out],
        "arrival_ms_p50_p99_max_per_proc": [co["arrival_ms"] for co in car_out],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--units", type=int, default=20)
    ap.add_argument("--cars", type=int, default=50)
    ap.add_argument("--car-procs", type=int, default=5)
    ap.add_argument("--rate-hz", type=float, default=10.0)
    ap.add_argument(
        "--verify",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="each car checks every signature (default); --no-verify: decode only (the transport)",
    )
    ap.add_argument(
        "--relevance-m",
        type=float,
        default=0.0,
        help="verify on demand: each car checks the signatures of alerts whose EV is within this many m "
        "(0, the default: every signature)",
    )
    ap.add_argument("--unit-spacing-m", type=float, default=800.0, help="the units' grid spacing (m)")
    ap.add_argument(
        "--signer",
        choices=SIGNER_FORMS,
        default=DEFAULT_SIGNER_FORM,
        help="how each alert names its unit: its certificate (default) or its 8-byte digest",
    )
    ap.add_argument("--json", type=Path)
    ap.add_argument("--role", default="main", help=argparse.SUPPRESS)
    ap.add_argument("--keys", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--port", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--work", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--proc", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--first-car", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--cars-total", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    duration_s = args.minutes * 60.0
    if args.role == "publisher":
        publisher(
            args.keys,
            args.port,
            args.units,
            args.rate_hz,
            duration_s,
            args.work,
            args.unit_spacing_m,
            args.signer,
        )
        return
    if args.role == "cars":
        cars(
            args.keys,
            args.port,
            args.units,
            args.cars,
            args.proc,
            args.rate_hz,
            duration_s,
            args.work,
            verify=args.verify,
            relevance_m=args.relevance_m,
            spacing_m=args.unit_spacing_m,
            first_car=args.first_car,
            total_cars=args.cars_total,
        )
        return
    r = run(
        args.minutes,
        args.units,
        args.cars,
        args.car_procs,
        args.rate_hz,
        verify=args.verify,
        relevance_m=args.relevance_m,
        spacing_m=args.unit_spacing_m,
        signer=args.signer,
    )
    if not r["verify"]:
        how = "decodes each (--no-verify: no signature check)"
    elif r["relevance_m"] > 0:
        lo, med, hi = r["relevant_units_per_car_min_median_max"]
        how = (
            f"reads each and verifies on demand: the signatures of alerts whose EV is within "
            f"{r['relevance_m']:g} m (units {r['unit_spacing_m']:g} m apart; {lo}/{med:g}/{hi} units "
            f"in range per car, min/median/max)"
        )
    else:
        how = "checks every signature"
    print(
        f"load: {r['units']} units × {r['rate_hz']:g} Hz → {r['cars']} cars ({r['car_processes']} car "
        f"processes), {r['minutes']:g} min: {r['published']:,} alerts published (the signer named by its "
        f"{r['signer']}), each car expects all and {how}"
    )
    if r["verify"] and r["relevance_m"] > 0:
        print(
            f"  relevant alerts: {r['relevant_published_total']:,} (summed over cars), lost "
            f"{r['relevant_lost_total']}; signatures checked {r['verified_total']:,}"
        )
    print(
        f"  lost: {r['lost_total']} in total, at most {r['lost_max_per_car']} per car, "
        f"{r['cars_with_loss']} cars with any loss; verification failures {r['verification_failures'] or 0}; "
        f"duplicates {r['duplicates']}; publisher ticks > 1 period late {r['publisher_late_over_one_period']}"
    )
    for name, (first, last) in r["rss_first_last_min_mib"].items():
        print(f"  RSS {name:9s} first min {first:7.1f} MiB, last min {last:7.1f} MiB ({last - first:+.1f})")
    print(f"  memory flat (every process grew < {FLAT_MIB:g} MiB): {r['rss_flat']}")
    for name, (lo, hi) in r["rss_after_first_min_pct_low_high"].items():
        print(f"  RSS {name:9s} after the first minute: {lo:+.1f} % … {hi:+.1f} % of the first minute's mean")
    print(f"  memory flat (every sample after the first minute within ± {FLAT_PCT:g} %): {r['rss_flat_pct']}")
    lags = r["lag_ms_p50_p99_max_per_proc"]
    print(
        f"  generated → {'verified' if r['verify'] else 'decoded'} lag per car process, p50/p99/max ms: "
        + "; ".join("/".join(f"{x:.1f}" for x in lag) for lag in lags)
    )
    print(
        "  generated → arrived (zenoh callback) per car process, p50/p99/max ms: "
        + "; ".join("/".join(f"{x:.1f}" for x in lag) for lag in r["arrival_ms_p50_p99_max_per_proc"])
    )
    print(f"  payloads taken off the cars' queues (verified or rejected): {r['handled_total']:,}")
    car_cores = r["cpu_cores_per_car_proc"]
    print(
        f"  CPU (cores kept busy, mean over the run): publisher {r['cpu_cores_publisher']:.2f}, "
        "car processes "
        + ", ".join(f"{c:.2f}" for c in car_cores)
        + f"; in all {r['cpu_cores_publisher'] + sum(car_cores):.2f} of {os.cpu_count()}"
    )
    if args.json:
        args.json.write_text(json.dumps(r, indent=1) + "\n")


if __name__ == "__main__":
    main()
