"""Linking a heard siren to the camera's vehicle track (issue 26 item 2: the obstacle id), on the
real clips' labelled SORT tracks, beside plain nearest-bearing matching.

No shared recording has both an array's sound and a calibrated camera, so the siren side is drawn:
in every frame of the three EV clips that holds an EV-labelled track
(``src/makeway/data/video_track_labels.csv``), a siren belief is placed at the azimuth of that
frame's largest EV track plus Gaussian angle noise (σ 2°, 4.5° — about the siren stack's mean
angle error on held-out scenes — and 8°), one EV track id for the whole clip. The camera side is
real: Framework B's tracks (YOLOX-nano → SORT, the label file's settings; cached under ``--cache``),
turned into bearings through a pinhole camera of the clip's size, 90° across (assumed: the clips
come without calibration; the angles between vehicles scale with the assumed field of view, the
siren's noise does not).

Per clip and noise, over 5 noise seeds: the share of frames whose siren is linked to an
EV-labelled track (**right**), to another vehicle (**wrong**), to nothing (**unlinked**), and the
number of times the link changed (SORT restarts the EV's own track several times in each clip: the
night clip's ambulance has 9 EV-labelled track ids, so a few changes are the tracker's). The same
siren turned 180° (behind the car, out of this camera's view) must link to nothing. Anchor:
``nearest``, the vehicle with the closest bearing each frame, no gate, no memory. ``linker`` is
:class:`makeway.fuse.ObstacleLinker` with its defaults, and ``linker+crop`` gives it the crop
classifier's per-frame verdict (P ≥ 0.5 active, below not, none where it gave no judgement) as
each vehicle's ``active``. Then one JSON line.

    .venv/bin/python benchmarks/bench_obstacle_links.py [--cache reports/track_probs] [--seeds 5]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import av
import numpy as np

from makeway.eval.actor_sweep import EV_CLIPS, ClipRecord, read_track_labels
from makeway.fuse import ObstacleLinker
from makeway.messages import Box, EVBelief, Track, VehicleBearing
from makeway.paths import data_dir
from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL
from makeway.perceive.vision.track_bearings import vehicle_bearings
from makeway.pipeline.clip_record import cached_clip
from makeway.sense.camera import PinholeCamera
from makeway.sense.rig import R0, Rig, RigCamera

SIGMAS_DEG = (2.0, 4.5, 8.0)
METHODS = ("nearest", "linker", "linker+crop")


def dashcam(width: int, height: int) -> Rig:
    """The clip's camera as a rig's only camera: pinhole, 90° across, 2 m ahead of the origin."""
    f = width / 2.0
    cam = PinholeCamera(width, height, f, f, width / 2.0, height / 2.0)
    return Rig((RigCamera("dash", cam, R0, np.array([2.0, 0.0, 1.3])),), Path("<dashcam>"))


def frames_of(rec: ClipRecord) -> dict[int, list[int]]:
    out: dict[int, list[int]] = {}
    for i, f in enumerate(rec.frame.tolist()):
        out.setdefault(int(f), []).append(i)
    return out


def nearest(heard: float, vehicles: list[VehicleBearing]) -> str | None:
    if not vehicles:
        return None
    best = min(vehicles, key=lambda v: abs(math.remainder(heard - v.azimuth_rad, math.tau)))
    return best.obstacle_id


def run_clip(
    rec: ClipRecord, rig: Rig, ev_ids: set[int], sigma_deg: float, seed: int
) -> dict[str, dict[str, float]]:
    rng = np.random.default_rng(seed)
    linkers = {"linker": ObstacleLinker(), "linker+crop": ObstacleLinker()}
    counts = {m: {"right": 0, "wrong": 0, "unlinked": 0, "switches": 0, "behind_linked": 0} for m in METHODS}
    last: dict[str, str | None] = dict.fromkeys(METHODS)
    frames = 0
    for f, rows in sorted(frames_of(rec).items()):
        tracks = [Track(int(rec.track_id[i]), Box(*map(float, rec.boxes[i]))) for i in rows]
        ev_tracks = [t for t in tracks if t.track_id in ev_ids]
        if not ev_tracks:
            continue
        bearings = vehicle_bearings(rig, "dash", tracks, f / rec.fps)
        by_id = {b.track_id: b for b in bearings}
        target = max((t for t in ev_tracks if t.track_id in by_id), key=lambda t: t.box.area, default=None)
        if target is None:
            continue
        frames += 1
        heard = by_id[target.track_id].azimuth_rad + rng.normal(0.0, math.radians(sigma_deg))
        belief = EVBelief(
            f / rec.fps, True, 0.9, bearing_rad=heard, siren=True, sources=("siren",), track_id=1
        )
        behind = EVBelief(
            f / rec.fps, True, 0.9, bearing_rad=heard + math.pi, siren=True, sources=("siren",), track_id=2
        )
        prob = {int(rec.track_id[i]): float(rec.probability[i]) for i in rows}
        cropped = [
            replace(b, active=None if math.isnan(prob[b.track_id]) else prob[b.track_id] >= 0.5)
            for b in bearings
        ]
        links = {
            "nearest": (nearest(heard, bearings), None),
            "linker": tuple(x.obstacle_id for x in linkers["linker"].update([belief, behind], bearings)),
            "linker+crop": tuple(
                x.obstacle_id for x in linkers["linker+crop"].update([belief, behind], cropped)
            ),
        }
        for m, (link, behind_link) in links.items():
            c = counts[m]
            if link is None:
                c["unlinked"] += 1
            elif int(link.split("/")[1]) in ev_ids:
                c["right"] += 1
            else:
                c["wrong"] += 1
            if link is not None and last[m] is not None and link != last[m]:
                c["switches"] += 1
            last[m] = link if link is not None else last[m]
            c["behind_linked"] += behind_link is not None
    return {
        m: {k: v / max(frames, 1) if k != "switches" else v for k, v in c.items()} | {"frames": frames}
        for m, c in counts.items()
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, default=Path("reports/track_probs"), help="track record cache")
    ap.add_argument("--seeds", type=int, default=5, help="noise seeds per clip and σ")
    args = ap.parse_args()
    t0 = time.perf_counter()
    labels = read_track_labels()
    video_dir = data_dir() / "video"
    results: dict[str, dict[str, dict[str, dict[str, float]]]] = {}
    print(
        f"{'clip':28s} {'σ':>5s} {'method':12s} {'frames':>6s} {'right':>6s} {'wrong':>6s} {'none':>6s} "
        f"{'switches':>8s} {'behind':>6s}"
    )
    for clip in EV_CLIPS:
        rec, _ = cached_clip(video_dir / f"{clip}.mp4", args.cache, DEFAULT_MODEL)
        with av.open(str(video_dir / f"{clip}.mp4")) as c:
            s = c.streams.video[0]
            rig = dashcam(int(s.width), int(s.height))
        ev_ids = {t for t in rec.track_ids if labels.label(clip, t) == 1}
        results[clip] = {}
        for sigma in SIGMAS_DEG:
            per_seed = [run_clip(rec, rig, ev_ids, sigma, seed) for seed in range(args.seeds)]
            agg = {
                m: {k: float(np.mean([r[m][k] for r in per_seed])) for k in per_seed[0][m]} for m in METHODS
            }
            results[clip][f"{sigma:g}"] = agg
            for m in METHODS:
                a = agg[m]
                print(
                    f"{clip:28s} {sigma:4.1f}° {m:12s} {a['frames']:6.0f} {a['right']:6.3f} "
                    f"{a['wrong']:6.3f} {a['unlinked']:6.3f} {a['switches']:8.1f} {a['behind_linked']:6.3f}"
                )
    worst = {
        f"{s:g}": {m: min(results[c][f"{s:g}"][m]["right"] for c in EV_CLIPS) for m in METHODS}
        for s in SIGMAS_DEG
    }
    for s, w in worst.items():
        print(f"worst clip, σ {s}°: right " + ", ".join(f"{m} {v:.3f}" for m, v in w.items()))
    print(f"wall time {time.perf_counter() - t0:.0f} s")
    print(
        json.dumps(
            {"sigmas_deg": list(SIGMAS_DEG), "seeds": args.seeds, "worst_right": worst, "clips": results}
        )
    )


if __name__ == "__main__":
    main()
