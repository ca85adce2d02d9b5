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
from collections import Counter, defaultdict
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from makeway import __version__
from makeway.atomic import atomic_dir
from makeway.eval.classification import precision_recall_f1, threshold_metrics
from makeway.eval.mot import evaluate_mot
from makeway.jsonable import to_jsonable
from makeway.messages import Box, EVObservation, EVState, EVTrackState, PerceptionFrame, Track
from makeway.progress import progress_bar
from makeway.sense.motfile import MotData
from makeway.sim.traffic import Scene, SceneRenderer, TrafficConfig, simulate_scene
from makeway.track.smoother import TrackSmoother
from makeway.track.sort import Sort, iou_matrix

#: Smoother thresholds T run side by side (seed 000, Table 3); T = 0 is the unsmoothed baseline.
THRESHOLDS: tuple[float, ...] = (0.0, 0.3, 0.5, 0.7)
#: The threshold whose state is displayed and reported as the headline.
DISPLAY_T = 0.5
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


@dataclass
class _TrackRecord:
    """One reported track in one frame, with the classifier output it got and the smoothed states."""

    frame: int
    track_id: int
    box: tuple[float, float, float, float]
    probability: float | None
    positive_fraction: float
    n_valid: int
    states: dict[float, EVState]


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
    metrics = _evaluate(scene, records)
    timing["evaluate_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    _plot_tracks(stage / "tracks.png", scene, records, metrics["track_to_actor"], renderer)
    _plot_ev_probability(stage / "ev_probability.png", scene, records, metrics)
    _plot_sweep(stage / "smoother_T_sweep.png", metrics)
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
) -> list[list[_TrackRecord]]:
    """The per-frame loop: SORT, probability → track, smoothers for every T, optional video."""
    from makeway.viz import H264Writer, draw_frame

    tracker = Sort()
    smoothers = {t: TrackSmoother(threshold=t) for t in THRESHOLDS}
    records: list[list[_TrackRecord]] = []
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
                    _TrackRecord(
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


def _evaluate(scene: Scene, records: list[list[_TrackRecord]]) -> dict[str, Any]:
    fps = scene.fps
    flat = [r for row in records for r in row]
    # (a) MOT
    if flat:
        hyp = MotData(
            np.array([r.frame + 1 for r in flat], dtype=np.int64),
            np.array([r.track_id for r in flat], dtype=np.int64),
            np.array([[r.box[0], r.box[1], r.box[2] - r.box[0], r.box[3] - r.box[1]] for r in flat]),
            np.ones(len(flat)),
        )
    else:
        hyp = MotData(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 4)), np.zeros(0))
    mot = evaluate_mot(scene.gt, hyp).summary()

    # track -> actor by majority overlap (IoU >= 0.5 with the best-overlapping truth box)
    votes: dict[int, Counter[int]] = defaultdict(Counter)
    length: Counter[int] = Counter()
    for frame, row in zip(scene.frames, records, strict=True):
        if not row:
            continue
        length.update(r.track_id for r in row)
        if not frame.truth:
            continue
        iou = np.nan_to_num(
            iou_matrix(np.array([r.box for r in row]), np.array([t.box.as_array() for t in frame.truth]))
        )
        best = iou.argmax(axis=1)
        for i, r in enumerate(row):
            if iou[i, best[i]] >= 0.5:
                votes[r.track_id][frame.truth[best[i]].actor_id] += 1
    track_to_actor: dict[int, int | None] = {}
    for tid, n in length.items():
        top = votes[tid].most_common(1)
        track_to_actor[tid] = top[0][0] if top and top[0][1] >= 0.5 * n else None

    ev_ids = [a for a in scene.ev_ids if a in set(scene.visible_ids)]
    ev_set = set(ev_ids)

    # (b) per-frame classifier vs "EV with a lit bulb in this frame"
    scores, labels = [], []
    n_skipped = 0
    for frame in scene.frames:
        lit = {t.actor_id for t in frame.truth if t.lights_on}
        for d in frame.detections:
            if d.ev_probability is None:
                n_skipped += 1
                continue
            scores.append(d.ev_probability)
            labels.append(d.actor_id in lit)
    s_arr, y_arr = np.array(scores, dtype=np.float64), np.array(labels, dtype=bool)
    pred = s_arr >= 0.5
    classifier: dict[str, Any] = precision_recall_f1(
        int((pred & y_arr).sum()), int((pred & ~y_arr).sum()), int((~pred & y_arr).sum())
    )
    classifier.update(threshold_metrics(s_arr, y_arr))
    classifier.update(
        {"num_valid": len(s_arr), "num_positive_labels": int(y_arr.sum()), "num_skipped": n_skipped}
    )

    # (c) smoother, per T
    def actor_key(tid: int) -> tuple[str, int]:
        a = track_to_actor.get(tid)
        return ("actor", a) if a is not None else ("track", tid)

    per_actor: dict[str, dict[str, Any]] = {}
    per_frame: dict[str, dict[str, Any]] = {}
    ev_keys = {("actor", a) for a in ev_ids}
    for thr in THRESHOLDS:
        flagged = {actor_key(r.track_id) for r in flat if r.states[thr] is EVState.ACTIVE}
        pa = precision_recall_f1(len(flagged & ev_keys), len(flagged - ev_keys), len(ev_keys - flagged))
        pa["flagged"] = sorted(f"{k}:{v}" for k, v in flagged)
        per_actor[str(thr)] = pa
        tp = fp = fn = 0
        for r in flat:
            st = r.states[thr]
            if st is EVState.WARMING_UP:
                continue
            truth = track_to_actor.get(r.track_id) in ev_set
            act = st is EVState.ACTIVE
            tp += act and truth
            fp += act and not truth
            fn += truth and not act
        per_frame[str(thr)] = precision_recall_f1(tp, fp, fn)
    base = per_actor[str(THRESHOLDS[0])]
    for thr in THRESHOLDS:
        pa = per_actor[str(thr)]
        for k in ("precision", "recall", "f1"):
            b, v = base[k], pa[k]
            pa[f"{k}_change_pct"] = (
                100.0 * (v - b) / b if b and math.isfinite(b) and math.isfinite(v) else None
            )

    # (d) time to active, per EV
    evs: list[dict[str, Any]] = []
    for a in ev_ids:
        first_seen = first_cls = first_tracked = first_active = None
        n_seen = n_active = 0
        active_frames = {
            r.frame
            for r in flat
            if track_to_actor.get(r.track_id) == a and r.states[DISPLAY_T] is EVState.ACTIVE
        }
        tracked_frames = {r.frame for r in flat if track_to_actor.get(r.track_id) == a}
        for frame in scene.frames:
            tb = next((t for t in frame.truth if t.actor_id == a), None)
            if tb is None or not tb.considered:
                continue
            n_seen += 1
            n_active += frame.index in active_frames
            if first_seen is None:
                first_seen = frame.index
            if first_cls is None and tb.box.width >= scene.config.cls_min_width_px:
                first_cls = frame.index
        if tracked_frames:
            first_tracked = min(tracked_frames)
        if active_frames:
            first_active = min(active_frames)
        actor = scene.actors[a]

        def dt(x: int | None, y: int | None) -> float | None:
            return (x - y) / fps if x is not None and y is not None else None

        evs.append(
            {
                "actor_id": a,
                "kind": actor.kind.name,
                "approaching": actor.approaching,
                "flash_hz": actor.flash_hz,
                "tracks": sorted(t for t, v in track_to_actor.items() if v == a),
                "first_seen_s": dt(first_seen, 0),
                "first_classifiable_s": dt(first_cls, 0),
                "first_tracked_s": dt(first_tracked, 0),
                "first_active_s": dt(first_active, 0),
                "time_to_active_s": dt(first_active, first_seen),
                "time_to_active_from_classifiable_s": dt(first_active, first_cls),
                "active_share_of_visible_frames": n_active / n_seen if n_seen else None,
            }
        )
    times: list[float | None] = [e["time_to_active_s"] for e in evs]
    known = [t for t in times if t is not None]
    worst = max(known) if known and len(known) == len(times) else None

    n_tracks = len(length)
    scene_info = {
        "num_frames": scene.num_frames,
        "fps": fps,
        "width": scene.width,
        "height": scene.height,
        "vehicles_visible": len(scene.visible_ids),
        "evs_visible": len(ev_ids),
        "gt_boxes_considered": int((scene.gt.conf != 0).sum()),
        "detections": sum(len(f.detections) for f in scene.frames),
        "false_positive_detections": sum(1 for f in scene.frames for d in f.detections if d.actor_id < 0),
        "tracks": n_tracks,
        "tracks_unmapped": sum(1 for v in track_to_actor.values() if v is None),
    }
    return {
        "mot": mot,
        "classifier": classifier,
        "smoother": {
            "thresholds": list(THRESHOLDS),
            "display_T": DISPLAY_T,
            "per_actor": per_actor,
            "per_frame": per_frame,
        },
        "evs": evs,
        "time_to_active_s": worst,
        "scene": scene_info,
        "track_to_actor": track_to_actor,
    }


# -------------------------------------------------------------------------------------------- plots


def _figure(width_in: float, height_in: float) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), dpi=100, layout="constrained")


_TAB = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2",
    "#7f7f7f", "#bcbd22", "#17becf", "#aec7e8", "#ffbb78", "#98df8a",
)  # fmt: skip
_EV_COLOUR = "#d62728"
#: Per-track colours in the probability plot: none of them red, green or amber (the state colours).
_TRACK_COLOURS = ("#1f77b4", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#393b79", "#7f7f7f", "#bcbd22")


def _plot_tracks(
    path: Path,
    scene: Scene,
    records: list[list[_TrackRecord]],
    track_to_actor: dict[int, int | None],
    renderer: SceneRenderer,
) -> None:
    """Ground-truth vs SORT trajectories (box bottom centres) over the empty road."""
    fig = _figure(15, 5.3)
    axes = fig.subplots(1, 2, sharex=True, sharey=True)
    bg = renderer.background[::2, ::2, ::-1]
    s = renderer.scale
    extent = (0, renderer.width / s, renderer.height / s, 0)
    gt_paths: dict[int, list[tuple[float, float]]] = defaultdict(list)
    for frame in scene.frames:
        for t in frame.truth:
            if t.considered:
                gt_paths[t.actor_id].append((0.5 * (t.box.x1 + t.box.x2), t.box.y2))
    trk_paths: dict[int, list[tuple[float, float]]] = defaultdict(list)
    for row in records:
        for r in row:
            trk_paths[r.track_id].append((0.5 * (r.box[0] + r.box[2]), r.box[3]))
    ev_set = set(scene.ev_ids)
    ax = axes[0]
    ax.imshow(bg, extent=extent, alpha=0.45)
    for k, (aid, pts) in enumerate(sorted(gt_paths.items())):
        p = np.array(pts)
        ev = aid in ev_set
        ax.plot(p[:, 0], p[:, 1], "-", lw=2.6 if ev else 1.4, color=_EV_COLOUR if ev else _TAB[k % len(_TAB)])
        ax.annotate(
            f"{scene.actors[aid].kind.name} {aid}" if ev else str(aid),
            p[-1],
            fontsize=7,
            color=_EV_COLOUR if ev else "black",
        )
    ax.set_title(f"ground truth: {len(gt_paths)} vehicles (EVs in red)")
    ax = axes[1]
    ax.imshow(bg, extent=extent, alpha=0.45)
    for tid, pts in sorted(trk_paths.items()):
        p = np.array(pts)
        actor = track_to_actor.get(tid)
        ev = actor in ev_set
        colour = _EV_COLOUR if ev else ("black" if actor is None else _TAB[tid % len(_TAB)])
        ax.plot(p[:, 0], p[:, 1], ".-", ms=1.5, lw=2.2 if ev else 1.0, color=colour)
        if len(p) >= 50 or ev:  # label the longer tracks only; the far end is crowded
            ax.annotate(f"#{tid}", p[-1], fontsize=7, color=colour)
    n_unmapped = sum(1 for v in track_to_actor.values() if v is None)
    ax.set_title(f"SORT: {len(trk_paths)} tracks ({n_unmapped} matching no vehicle, in black)")
    for ax in axes:
        ax.set_xlim(0, scene.width)
        ax.set_ylim(scene.height, 0)
        ax.set_xlabel("u (px)")
    axes[0].set_ylabel("v (px), box bottom centre")
    fig.savefig(path)


def _strip(ax: Any, t: np.ndarray, mask: np.ndarray, y0: float, y1: float, colour: str, **kw: Any) -> None:
    ax.fill_between(t, y0, y1, where=mask, step="post", color=colour, lw=0, **kw)


def _plot_ev_probability(
    path: Path, scene: Scene, records: list[list[_TrackRecord]], metrics: dict[str, Any]
) -> None:
    """Per EV (and the most EV-like ordinary vehicle): raw probability, positive fraction, state."""
    track_to_actor: dict[int, int | None] = metrics["track_to_actor"]
    fps = scene.fps
    by_actor: dict[int, list[_TrackRecord]] = defaultdict(list)
    for row in records:
        for r in row:
            a = track_to_actor.get(r.track_id)
            if a is not None:
                by_actor[a].append(r)
    panels = [a for a in scene.ev_ids if a in by_actor]
    ev_set = set(scene.ev_ids)
    decoys = [
        (sum(1 for r in rs if r.probability is not None and r.probability >= 0.5), a)
        for a, rs in by_actor.items()
        if a not in ev_set
    ]
    decoys.sort(reverse=True)
    if decoys and decoys[0][0] > 0:
        panels.append(decoys[0][1])
    fig = _figure(13, 2.9 * max(1, len(panels)) + 0.4)
    axes = fig.subplots(max(1, len(panels)), 1, squeeze=False)[:, 0]
    t_all = np.arange(scene.num_frames + 1) / fps
    if not panels:
        axes[0].text(
            0.5,
            0.5,
            "no emergency vehicle was tracked in this scene",
            ha="center",
            transform=axes[0].transAxes,
        )
    state_colour = {EVState.ACTIVE: "#d62728", EVState.INACTIVE: "#2ca02c", EVState.WARMING_UP: "#ffbf00"}
    ev_info = {e["actor_id"]: e for e in metrics["evs"]}
    for ax, a in zip(axes, panels, strict=False):
        actor = scene.actors[a]
        rs = sorted(by_actor[a], key=lambda r: (r.frame, r.track_id))
        # truth: lights-on strip at the bottom, grey background while the vehicle is in view
        lit = np.zeros(scene.num_frames + 1, dtype=bool)
        seen = np.zeros(scene.num_frames + 1, dtype=bool)
        for f in scene.frames:
            tb = next((t for t in f.truth if t.actor_id == a), None)
            if tb is not None:
                lit[f.index] = tb.lights_on
                seen[f.index] = tb.considered
        _strip(ax, t_all, seen, -0.16, 1.16, "#000000", alpha=0.05)
        if actor.is_ev:
            _strip(ax, t_all, lit, -0.14, -0.05, "#f2b600")
        # the smoothed state (T = DISPLAY_T) as a strip at the top
        for st, col in state_colour.items():
            mask = np.zeros(scene.num_frames + 1, dtype=bool)
            for r in rs:
                if r.states[DISPLAY_T] is st:
                    mask[r.frame] = True
            _strip(ax, t_all, mask, 1.05, 1.14, col)
        for k, tid in enumerate(sorted({r.track_id for r in rs})):
            tr = [r for r in rs if r.track_id == tid]
            tt = np.array([r.frame / fps for r in tr])
            p = np.array([np.nan if r.probability is None else r.probability for r in tr])
            colour = _TRACK_COLOURS[k % len(_TRACK_COLOURS)]
            ax.plot(tt, p, ".", ms=3.5, color=colour, alpha=0.75)
            ax.plot(tt, [r.positive_fraction for r in tr], "-", lw=1.8, color=colour)
            ax.annotate(
                f"#{tid}", (tt[0], 0.9), fontsize=7, color=colour, xytext=(1, 0), textcoords="offset points"
            )
            tn = np.array([r.frame / fps for r in tr if r.probability is None])
            if len(tn):
                ax.plot(tn, np.full(len(tn), 0.02), "|", color="grey", ms=5)
        info = ev_info.get(a)
        if info is not None:
            for key, text, dx in (("first_seen_s", "in view", -9), ("first_active_s", "active", 2)):
                if info[key] is not None:
                    ax.axvline(info[key], color="black", lw=0.8, ls=":")
                    ax.annotate(
                        text,
                        (info[key], 0.6),
                        rotation=90,
                        fontsize=7,
                        xytext=(dx, 0),
                        textcoords="offset points",
                    )
        ax.axhline(DISPLAY_T, color="black", lw=0.8, ls="--")
        ax.set_ylim(-0.16, 1.16)
        ax.set_xlim(0, t_all[-1])
        ax.set_yticks([0, 0.25, 0.5, 0.75, 1.0])
        ax.set_ylabel("probability / fraction")
        what = f"EV {a}: {actor.kind.name}" if actor.is_ev else f"vehicle {a}: ordinary {actor.kind.name}"
        where = "approaching" if actor.approaching else "receding"
        if actor.is_ev:
            extra = f", lights {actor.flash_hz:g} Hz"
        elif actor.distractor:
            extra = ", brake/tail-light glints (the most EV-like ordinary vehicle)"
        else:
            extra = " (the most EV-like ordinary vehicle)"
        n_trk = len({r.track_id for r in rs})
        ax.set_title(f"{what}, {where}{extra}; {n_trk} track(s)", loc="left", fontsize=10)
    axes[-1].set_xlabel("time (s)")
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [
        Line2D([], [], marker=".", ls="", color="#1f77b4", label="per-frame P (one colour per track)"),
        Line2D([], [], ls="-", lw=1.8, color="#1f77b4", label="positive fraction of the 25-frame buffer"),
        Line2D([], [], marker="|", ls="", color="grey", label="crop < 18 px: no judgement"),
        Line2D([], [], ls="--", lw=0.8, color="black", label=f"T = {DISPLAY_T}"),
        Patch(color="#f2b600", label="truth: lights on"),
        Patch(color=state_colour[EVState.ACTIVE], label="state: active"),
        Patch(color=state_colour[EVState.INACTIVE], label="state: inactive"),
        Patch(color=state_colour[EVState.WARMING_UP], label="state: warming up"),
        Patch(color="#000000", alpha=0.08, label="vehicle in view"),
    ]
    fig.legend(handles=handles, loc="outside upper center", ncol=5, fontsize=8, frameon=False)
    fig.savefig(path)


def _plot_sweep(path: Path, metrics: dict[str, Any]) -> None:
    """Precision / recall vs smoother threshold T: per actor, per frame, and the raw classifier."""
    sm = metrics["smoother"]
    cls = metrics["classifier"]
    ts = np.array(THRESHOLDS)
    fig = _figure(7.5, 4.6)
    ax = fig.subplots()
    for key, colour in (("precision", "#1f77b4"), ("recall", "#d62728")):
        pa = [sm["per_actor"][str(t)][key] for t in THRESHOLDS]
        pf = [sm["per_frame"][str(t)][key] for t in THRESHOLDS]
        ax.plot(ts, pa, "o-", color=colour, lw=2, label=f"per actor {key} (ever active)")
        ax.plot(ts, pf, "s--", color=colour, lw=1.3, label=f"per frame smoothed {key}")
        ax.axhline(cls[key], color=colour, lw=1, ls=":", label=f"raw per-frame classifier {key}")
    ax.axvline(DISPLAY_T, color="grey", lw=0.8)
    ax.set_xticks(ts)
    ax.set_xlabel("smoother threshold T (positive fraction must exceed T)")
    ax.set_ylabel("fraction")
    ax.set_ylim(0, 1.05)
    ax.set_title("Output smoother threshold sweep (window 25, ≥ 6 valid frames)")
    ax.legend(fontsize=7.5, loc="lower right")
    ax.grid(alpha=0.3)
    fig.savefig(path)


# ------------------------------------------------------------------------------------------- report


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
