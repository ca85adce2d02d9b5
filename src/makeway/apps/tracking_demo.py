"""The tracking part of ``makeway demo``: SORT and the smoother on a simulated roadside scene (SPEC §1–2).

Needs no data and no weights. :func:`run_tracking_demo` simulates a traffic scene with emergency vehicles
(:mod:`makeway.sim.traffic`), tracks the simulated detections with :class:`~makeway.track.sort.Sort`
(defaults), gives each track the simulated classifier probability of the detection it sits on (the
detection with the highest IoU ≥ 0.5 that frame), and runs one :class:`TrackSmoother` per threshold
T in :data:`THRESHOLDS` side by side; T = 0.5 (the paper's default) drives the displayed state.

It then measures, against the simulation's ground truth:

a. **Tracking**: CLEAR MOT and IDF1 of SORT (:func:`makeway.eval.mot.evaluate_mot`).
b. **Per-frame classifier**: precision / recall / F1 at 0.5, max-F1 and precision at recall 0.8 of
   every valid crop probability against the per-frame label "EV with a lit bulb in this frame".
c. **Smoother**, per T, as seed 000's Table 3: *per actor* (each ground-truth vehicle, tracks mapped
   to it by majority overlap; a track that maps to none is an actor of its own) precision / recall
   / F1 of "ever flagged active", with the change relative to T = 0; and *per frame* precision /
   recall / F1 of the smoothed state of every judged track-frame against "this track is an EV".
d. **Time to active**: from an EV entering the view (its first considered ground-truth box) to the
   first frame one of its tracks is active at T = 0.5; also from its first classifiable frame.

Outputs (in ``out_dir``, which appears all at once: everything is written into a hidden sibling
folder that is renamed into place at the end): ``summary.json``, ``report.md``, ``tracks.png``,
``ev_probability.png``, ``smoother_T_sweep.png`` and, unless ``write_video=False``, ``scene.mp4``.
"""

from __future__ import annotations

import contextlib
import json
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from makeway import __version__
from makeway.atomic import atomic_dir
from makeway.eval.scene_tracking import DISPLAY_T, THRESHOLDS, SceneTrackRecord, score_scene_tracking
from makeway.jsonable import to_jsonable
from makeway.messages import Box, EVObservation, EVTrackState, PerceptionFrame, Track
from makeway.progress import progress_bar
from makeway.sim.traffic import Scene, SceneRenderer, TrafficConfig, simulate_scene
from makeway.track.smoother import TrackSmoother
from makeway.track.sort import Sort, iou_matrix
from makeway.viz.tracking_plots import plot_ev_probability, plot_sweep, plot_tracks

#: A track takes the classifier output of the detection it overlaps with at least this IoU.
MATCH_IOU = 0.5
#: Video size relative to the 1280×720 camera (1.0: full size; x264 ultrafast keeps up).
VIDEO_SCALE = 1.0

FILES = ("summary.json", "report.md", "tracks.png", "ev_probability.png", "smoother_T_sweep.png", "scene.mp4")


@dataclass(frozen=True)
class TrackingDemoSummary:
    """What :func:`run_tracking_demo` wrote and its headline numbers (all rates as fractions).

    ``time_to_active_s`` is the worst (largest) time over the scene's EVs from entering the view to
    being confirmed active at T = 0.5; ``None`` when an EV never became active or there was none.
    """

    out_dir: Path
    files: dict[str, Path]
    mota: float
    idf1: float
    frame_precision: float
    frame_recall: float
    frame_f1: float
    actor_precision: float
    actor_recall: float
    actor_f1: float
    time_to_active_s: float | None
    num_frames: int
    elapsed_s: float
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (paths as strings, NaN as ``None``)."""
        out: dict[str, Any] = {
            "out_dir": str(self.out_dir),
            "files": {k: str(v) for k, v in self.files.items()},
        }
        for key in (
            "mota",
            "idf1",
            "frame_precision",
            "frame_recall",
            "frame_f1",
            "actor_precision",
            "actor_recall",
            "actor_f1",
            "time_to_active_s",
            "num_frames",
            "elapsed_s",
        ):
            out[key] = to_jsonable(getattr(self, key))
        out.update(to_jsonable(self.extra))
        return out


# ---------------------------------------------------------------------------------------- helpers


# ------------------------------------------------------------------------------------------ the run


def run_tracking_demo(
    out_dir: str | Path,
    *,
    seed: int = 0,
    duration_s: float = 20.0,
    write_video: bool = True,
    progress: bool = True,
) -> TrackingDemoSummary:
    """Simulate, track, classify, smooth, evaluate and write the report folder; see the module doc.

    Args:
        out_dir: the folder to create (replaced when it holds an earlier demo's output; refused
            when it is some other non-empty folder).
        seed: the simulation seed.
        duration_s: scene length in seconds.
        write_video: also write the annotated ``scene.mp4``.
        progress: show a progress bar on the terminal.
    """
    t_start = time.perf_counter()
    out = Path(out_dir).expanduser().absolute()
    with atomic_dir(out, marker="summary.json") as stage:
        return _run(out, stage, seed, duration_s, write_video, progress, t_start)


def _run(
    out: Path, stage: Path, seed: int, duration_s: float, write_video: bool, progress: bool, t_start: float
) -> TrackingDemoSummary:
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    config = TrafficConfig(seed=seed, duration_s=duration_s)
    scene = simulate_scene(config)
    timing["simulate_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    renderer = SceneRenderer(scene, scale=VIDEO_SCALE)
    records = _track_and_smooth(scene, stage, renderer if write_video else None, progress)
    timing["track_smooth_video_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    metrics = score_scene_tracking(scene, records)
    timing["evaluate_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    plot_tracks(stage / "tracks.png", scene, records, metrics["track_to_actor"], renderer)
    plot_ev_probability(stage / "ev_probability.png", scene, records, metrics)
    plot_sweep(stage / "smoother_T_sweep.png", metrics)
    timing["plots_s"] = time.perf_counter() - t0

    names = [f for f in FILES if write_video or f != "scene.mp4"]
    files = {Path(f).stem: out / f for f in names}
    timing["total_s"] = time.perf_counter() - t_start
    smoother = metrics["smoother"]
    shown = smoother["per_actor"][str(DISPLAY_T)]
    cls = metrics["classifier"]
    summary = TrackingDemoSummary(
        out_dir=out,
        files=files,
        mota=float(metrics["mot"]["mota"]),
        idf1=float(metrics["mot"]["idf1"]),
        frame_precision=float(cls["precision"]),
        frame_recall=float(cls["recall"]),
        frame_f1=float(cls["f1"]),
        actor_precision=float(shown["precision"]),
        actor_recall=float(shown["recall"]),
        actor_f1=float(shown["f1"]),
        time_to_active_s=metrics["time_to_active_s"],
        num_frames=scene.num_frames,
        elapsed_s=timing["total_s"],
        extra={"seed": seed, "duration_s": duration_s, "num_evs": len(scene.ev_ids)},
    )
    doc = {
        "makeway_version": __version__,
        "what": "SORT + per-track EV smoother on a simulated roadside scene (makeway demo)",
        "summary": summary.to_json(),
        "config": asdict(config),
        "scene": metrics["scene"],
        "mot": metrics["mot"],
        "classifier": cls,
        "smoother": smoother,
        "evs": metrics["evs"],
        "timing_s": timing,
    }
    (stage / "summary.json").write_text(json.dumps(to_jsonable(doc), indent=2) + "\n", encoding="utf-8")
    (stage / "report.md").write_text(_report(summary, doc, write_video), encoding="utf-8")
    return summary


def _track_and_smooth(
    scene: Scene, stage: Path, renderer: SceneRenderer | None, progress: bool
) -> list[list[SceneTrackRecord]]:
    """The per-frame loop: SORT, probability → track, smoothers for every T, optional video."""
    from makeway.viz import H264Writer, draw_frame

    tracker = Sort()
    smoothers = {t: TrackSmoother(threshold=t) for t in THRESHOLDS}
    records: list[list[SceneTrackRecord]] = []
    with contextlib.ExitStack() as stack:
        writer = None
        if renderer is not None:
            writer = stack.enter_context(
                H264Writer(stage / "scene.mp4", scene.fps, renderer.width, renderer.height)
            )
        advance = stack.enter_context(progress_bar("makeway demo", scene.num_frames, enabled=progress))
        for frame in scene.frames:
            tracks = tracker.update([d.detection for d in frame.detections])
            probs = _track_probabilities(tracks, frame.detections)
            obs = [
                EVObservation(t.track_id, frame.index, frame.time_s, p, source="simulated")
                for t, p in zip(tracks, probs, strict=True)
                if p is not _UNMATCHED
            ]
            live = tracker.live_ids
            states = {t: {s.track_id: s for s in sm.update(obs, live)} for t, sm in smoothers.items()}
            shown = states[DISPLAY_T]
            row = []
            for t, p in zip(tracks, probs, strict=True):
                st = shown[t.track_id]
                row.append(
                    SceneTrackRecord(
                        frame.index,
                        t.track_id,
                        (t.box.x1, t.box.y1, t.box.x2, t.box.y2),
                        p if isinstance(p, float) else None,
                        st.positive_fraction,
                        st.n_valid,
                        {thr: states[thr][t.track_id].state for thr in THRESHOLDS},
                    )
                )
            records.append(row)
            if writer is not None and renderer is not None:
                img = renderer.render(frame.index)
                pf = _perception_frame(frame.index, frame.time_s, tracks, shown, renderer.scale)
                draw_frame(
                    img,
                    pf,
                    extra_lines=(
                        f"simulated roadside camera, seed {scene.config.seed}",
                        "smoother T=0.5, N=25",
                    ),
                    copy=False,
                )
                writer.write(img)
            advance()
    return records


_UNMATCHED = object()


def _track_probabilities(tracks: Sequence[Track], detections: Sequence[Any]) -> list[Any]:
    """Per track: the classifier probability of its best detection (IoU ≥ 0.5), or ``_UNMATCHED``."""
    if not tracks:
        return []
    if not detections:
        return [_UNMATCHED] * len(tracks)
    tb = np.array([[t.box.x1, t.box.y1, t.box.x2, t.box.y2] for t in tracks])
    db = np.array([d.detection.box.as_array() for d in detections])
    iou = np.nan_to_num(iou_matrix(tb, db))
    best = iou.argmax(axis=1)
    return [
        detections[int(j)].ev_probability if iou[i, j] >= MATCH_IOU else _UNMATCHED
        for i, j in enumerate(best)
    ]


def _perception_frame(
    index: int, time_s: float, tracks: Sequence[Track], states: dict[int, EVTrackState], scale: float
) -> PerceptionFrame:
    if scale != 1.0:
        tracks = [
            Track(
                t.track_id,
                Box(t.box.x1 * scale, t.box.y1 * scale, t.box.x2 * scale, t.box.y2 * scale),
                t.score,
                t.class_id,
                t.label,
                t.hits,
                t.hit_streak,
                t.age,
            )
            for t in tracks
        ]
    return PerceptionFrame(
        index, time_s, tuple(tracks), tuple(states[t.track_id] for t in tracks if t.track_id in states)
    )


# --------------------------------------------------------------------------------------- evaluation


def _sec(v: Any) -> str:
    return "–" if v is None else f"{v:.2f} s"


def _fmt(v: Any, pct: bool = False) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, float):
        return f"{100 * v:.1f} %" if pct else f"{v:.3f}"
    return str(v)


def _report(summary: TrackingDemoSummary, doc: dict[str, Any], write_video: bool) -> str:
    mot, cls, sm, sc = doc["mot"], doc["classifier"], doc["smoother"], doc["scene"]
    lines = [
        "# makeway demo: tracking and EV smoothing on a simulated roadside camera",
        "",
        f"Seed {doc['config']['seed']}, {sc['num_frames']} frames at {sc['fps']:g} fps "
        f"({sc['width']}×{sc['height']}), {sc['vehicles_visible']} vehicles of which {sc['evs_visible']} "
        f"emergency vehicles with flashing lights. Simulated detector ({sc['detections']} detections, "
        f"{sc['false_positive_detections']} false positives) → SORT (defaults) → simulated per-frame crop "
        "classifier → per-track output smoother (window 25, ≥ 6 valid frames, positive fraction > T). "
        "Everything here is simulated; see `makeway.sim.traffic` for the models and their parameters.",
        "",
        "## Headline",
        "",
        "| metric | value |",
        "|---|---|",
        f"| MOTA / IDF1 (SORT vs ground truth) | {_fmt(summary.mota)} / {_fmt(summary.idf1)} |",
        f"| per-frame classifier P / R / F1 | {_fmt(summary.frame_precision)} / "
        f"{_fmt(summary.frame_recall)} / {_fmt(summary.frame_f1)} |",
        f"| per-actor P / R / F1 at T = {DISPLAY_T} | {_fmt(summary.actor_precision)} / "
        f"{_fmt(summary.actor_recall)} / {_fmt(summary.actor_f1)} |",
        f"| worst time from entering view to active | {_sec(summary.time_to_active_s)} |",
        f"| run time | {summary.elapsed_s:.1f} s |",
        "",
        "## Tracking (CLEAR MOT, IoU ≥ 0.5)",
        "",
        "| MOTA | MOTP | IDF1 | precision | recall | ID switches | FP | FN | GT boxes | mostly tracked |",
        "|---|---|---|---|---|---|---|---|---|---|",
        f"| {_fmt(mot['mota'])} | {_fmt(mot['motp'])} | {_fmt(mot['idf1'])} | {_fmt(mot['precision'])} | "
        f"{_fmt(mot['recall'])} | {mot['id_switches']} | {mot['fp']} | {mot['fn']} | {mot['num_gt']} | "
        f"{mot['mostly_tracked']}/{mot['gt_ids']} |",
        "",
        "![trajectories](tracks.png)",
        "",
        "## Per-frame classifier (label: EV with a lit bulb in this frame)",
        "",
        f"{cls['num_valid']} valid crops ({cls['num_skipped']} skipped as narrower than 18 px), "
        f"{cls['num_positive_labels']} positive.",
        "",
        "| precision | recall | F1 (at 0.5) | max-F1 | precision at recall 0.8 |",
        "|---|---|---|---|---|",
        f"| {_fmt(cls['precision'])} | {_fmt(cls['recall'])} | {_fmt(cls['f1'])} | {_fmt(cls['max_f1'])} | "
        f"{_fmt(cls['precision_at_recall_0.8'])} |",
        "",
        "## Output smoother (as seed 000, Table 3)",
        "",
        "Per actor: a ground-truth vehicle counts as flagged when any of its tracks was ever *active*; "
        "changes are relative to T = 0 (any positive in the buffer). Per frame: the smoothed state of "
        "every judged track-frame against *this track is an EV*.",
        "",
        "| T | actor P | actor R | actor F1 | ΔP | ΔR | ΔF1 | frame P | frame R | frame F1 |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for t in THRESHOLDS:
        pa, pf = sm["per_actor"][str(t)], sm["per_frame"][str(t)]

        def ch(k: str, pa: dict[str, Any] = pa) -> str:
            v = pa.get(f"{k}_change_pct")
            return "–" if v is None else f"{v:+.1f} %"

        lines.append(
            f"| {t:g} | {_fmt(pa['precision'])} | {_fmt(pa['recall'])} | {_fmt(pa['f1'])} | "
            f"{ch('precision')} | {ch('recall')} | {ch('f1')} | "
            f"{_fmt(pf['precision'])} | {_fmt(pf['recall'])} | {_fmt(pf['f1'])} |"
        )
    lines += ["", "![smoother threshold sweep](smoother_T_sweep.png)", "", "## Emergency vehicles", ""]
    lines += [
        "| EV | direction | lights | tracks | seen at | classifiable at | active at | time to active | "
        "from classifiable | active share |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for e in doc["evs"]:
        lines.append(
            f"| {e['kind']} {e['actor_id']} | {'approaching' if e['approaching'] else 'receding'} | "
            f"{e['flash_hz']:g} Hz | {', '.join(f'#{t}' for t in e['tracks']) or '–'} | "
            f"{_sec(e['first_seen_s'])} | {_sec(e['first_classifiable_s'])} | "
            f"{_sec(e['first_active_s'])} | "
            f"{_sec(e['time_to_active_s'])} | {_sec(e['time_to_active_from_classifiable_s'])} | "
            f"{_fmt(e['active_share_of_visible_frames'], pct=True)} |"
        )
    lines += ["", "![EV probability](ev_probability.png)", ""]
    if write_video:
        lines += [
            "## Video",
            "",
            "[scene.mp4](scene.mp4): the synthetic camera view with the tracks and their smoothed "
            "state (red: active EV, green: inactive, amber: warming up).",
            "",
        ]
    t = doc["timing_s"]
    lines += [
        "## Run",
        "",
        f"makeway {doc['makeway_version']}; simulate {t['simulate_s']:.2f} s, track + smooth"
        f"{' + video' if write_video else ''} {t['track_smooth_video_s']:.2f} s, "
        f"evaluate {t['evaluate_s']:.2f} s, "
        f"plots {t['plots_s']:.2f} s. All numbers are in `summary.json`.",
        "",
    ]
    return "\n".join(lines)
