"""Per-actor EV metrics on real videos and the smoother-threshold sweep (SPEC §1, seed 000 Table 3).

Seed 000 is the Aurora paper on a per-frame EV crop CNN with a per-track output smoother
(``../shared/seeds/000_…``, digested in SPEC §1).

Framework B (detector → SORT → per-track crop classifier) runs over a clip once and every per-frame
probability of every track is **recorded** (:func:`makeway.pipeline.clip_record.record_clip`,
cached as ``.npz`` by :func:`makeway.pipeline.clip_record.cached_clip`) as a :class:`ClipRecord`,
so that the smoother can then be replayed for any setting at no cost.

*Actors* are SORT tracks. Each track of a clip gets a label from a committed file
(:data:`TRACK_LABELS`, see :func:`read_track_labels`): 1 when the box follows an emergency vehicle
(police, fire, ambulance), 0 otherwise. Track ids are deterministic for the recording configuration
:data:`RECORD_CONFIG` (detector, score threshold, class-agnostic NMS, one detector thread, SORT
defaults); the label file is only valid for that configuration.

Per-actor decision (seed 000 §3.1 and §4 — the smoother "infers the final overall state" of the actor
and exists "to mitigate FPs"): an actor is **predicted positive when the smoother marks it active on
at least one frame** of its life (:func:`actor_predictions`). With ``T = 0`` that is "any positive
frame once ≥ ``min_frames`` judgements are buffered", the baseline row of Table 3; raising ``T``
can only remove actors from the positive set. The row "no smoother" calls an actor positive when any
single frame's probability reaches the decision threshold. A per-frame row scores every judged
(track, frame) pair against its track's label.

:func:`sweep` returns one :class:`SweepRow` per setting; :func:`relative_change` gives the "% change"
figures seed 000 reports (relative to the ``T = 0`` row).
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from makeway.atomic import atomic_path
from makeway.errors import InputError
from makeway.eval.classification import precision_recall_f1, threshold_metrics
from makeway.messages import EVObservation, EVState
from makeway.track.smoother import TrackSmoother

__all__ = [
    "EV_CLIPS",
    "NO_EV_CLIPS",
    "RECORD_CONFIG",
    "SEED000_TABLE3",
    "TRACK_LABELS",
    "ClipRecord",
    "SweepRow",
    "TrackLabels",
    "actor_predictions",
    "read_track_labels",
    "relative_change",
    "sweep",
]

#: The committed per-track labels of the real clips (see the file's header).
TRACK_LABELS = Path(__file__).resolve().parents[1] / "data" / "video_track_labels.csv"

#: Clips with emergency vehicles, and clips without any (every track negative).
EV_CLIPS = ("night_ambulance_lights", "fire_trucks_red_lights", "intersection_cam_ambulance")
NO_EV_CLIPS = ("traffic_no_ev", "highway_cam_no_ev")

#: Recording configuration the track ids of :data:`TRACK_LABELS` belong to.
RECORD_CONFIG: dict[str, Any] = {
    "detector": "yolox_nano",
    "score_threshold": 0.3,
    "class_agnostic": True,
    "detector_threads": 1,
    "stride": 1,
    "sort": {"max_age": 1, "min_hits": 3, "iou_threshold": 0.3},
    "crop_margin": 0.1,
    "min_width_px": 18.0,
}

#: Seed 000 Table 3: % change of per-actor precision, recall, F1 against T = 0.
SEED000_TABLE3: dict[float, tuple[float, float, float]] = {
    0.0: (0.0, 0.0, 0.0),
    0.3: (10.30, -0.68, 5.07),
    0.5: (9.87, -0.51, 4.87),
    0.7: (6.80, -20.0, -7.02),
}

_FORMAT = 1


# ------------------------------------------------------------------------------------ recording
@dataclass(frozen=True)
class ClipRecord:
    """Every (frame, track) of one clip with its box and per-frame probability (NaN: no judgement)."""

    clip: str
    fps: float
    frames: int
    frame: np.ndarray  # (n,) int64
    track_id: np.ndarray  # (n,) int64
    boxes: np.ndarray  # (n, 4) float64, x1 y1 x2 y2
    probability: np.ndarray  # (n,) float64, NaN where the classifier gave none
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def track_ids(self) -> list[int]:
        """Distinct track ids, ascending."""
        return sorted(set(self.track_id.tolist()))

    def probabilities_of(self, track_id: int, every: int = 1) -> np.ndarray:
        """Probabilities of one track in frame order; with ``every = k`` only frames where
        ``(frame + track_id) % k == 0`` keep theirs (others NaN), as the staggered classifier does."""
        sel = self.track_id == track_id
        probs = self.probability[sel].copy()
        if every > 1:
            probs[(self.frame[sel] + track_id) % every != 0] = np.nan
        return probs

    def save(self, path: str | Path) -> Path:
        """Write as ``.npz`` (no pickle), all-or-nothing."""
        path = Path(path)
        meta = {**self.meta, "clip": self.clip, "fps": self.fps, "frames": self.frames, "format": _FORMAT}
        with atomic_path(path) as tmp, tmp.open("wb") as fh:
            np.savez_compressed(
                fh,
                frame=self.frame,
                track_id=self.track_id,
                boxes=self.boxes,
                probability=self.probability,
                meta=np.asarray(json.dumps(meta, sort_keys=True)),
            )
        return path

    @classmethod
    def load(cls, path: str | Path) -> ClipRecord:
        """Read a file written by :meth:`save`.

        Raises:
            InputError: missing, unreadable or not such a record (names the file).
        """
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as npz:
                meta = json.loads(str(npz["meta"]))
                rec = cls(
                    clip=str(meta["clip"]),
                    fps=float(meta["fps"]),
                    frames=int(meta["frames"]),
                    frame=np.asarray(npz["frame"], dtype=np.int64),
                    track_id=np.asarray(npz["track_id"], dtype=np.int64),
                    boxes=np.asarray(npz["boxes"], dtype=np.float64).reshape(-1, 4),
                    probability=np.asarray(npz["probability"], dtype=np.float64),
                    meta=meta,
                )
        except FileNotFoundError:
            raise InputError(path, "track probability record not found") from None
        except Exception as exc:  # zipfile / numpy / json / KeyError on a bad file
            raise InputError(path, f"not a track probability record ({type(exc).__name__}: {exc})") from None
        if not (len(rec.frame) == len(rec.track_id) == len(rec.boxes) == len(rec.probability)):
            raise InputError(path, "track probability record with arrays of different lengths")
        return rec


# --------------------------------------------------------------------------------------- labels
@dataclass
class TrackLabels:
    """Per-track labels: explicit ``(clip, track id)`` rows, and a default per clip (``*`` rows)."""

    path: Path
    explicit: dict[tuple[str, int], int] = field(default_factory=dict)
    default: dict[str, int] = field(default_factory=dict)
    notes: dict[tuple[str, int | None], str] = field(default_factory=dict)

    def label(self, clip: str, track_id: int) -> int:
        """0/1 label of a track.

        Raises:
            InputError: the clip has neither a row for this track nor a ``*`` default.
        """
        got = self.explicit.get((clip, int(track_id)))
        if got is not None:
            return got
        if clip in self.default:
            return self.default[clip]
        raise InputError(self.path, f"no label for clip {clip!r} track {track_id} (and no '*' row)")

    @property
    def clips(self) -> list[str]:
        """Clips the file speaks about."""
        return sorted({c for c, _ in self.explicit} | set(self.default))


def read_track_labels(path: str | Path = TRACK_LABELS) -> TrackLabels:
    """Read ``clip,track_id,emergency,note`` rows (``#`` lines are comments).

    ``track_id`` is an integer or ``*`` (every track of the clip without its own row).

    Raises:
        InputError: missing file or columns, a malformed or repeated row (with the line number).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "track label file not found")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot be read as a track label CSV ({exc})") from None
    lines = [ln for ln in text.splitlines() if not ln.lstrip().startswith("#")]
    reader = csv.reader(io.StringIO("\n".join(lines)))
    header = [c.strip().lower() for c in next(reader, [])]
    need = ("clip", "track_id", "emergency")
    if any(c not in header for c in need):
        raise InputError(path, f"needs columns clip,track_id,emergency[,note]; found {','.join(header)}")
    ci, ti, ei = (header.index(c) for c in need)
    ni = header.index("note") if "note" in header else None
    out = TrackLabels(path)
    for n, row in enumerate(reader, start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) < len(header) - (ni is not None):
            raise InputError(path, f"row {n}: {len(row)} fields, the header has {len(header)}")
        clip, tid, value = row[ci].strip(), row[ti].strip(), row[ei].strip()
        if value not in ("0", "1"):
            raise InputError(path, f"row {n}: emergency must be 0 or 1, got {value!r}")
        note = row[ni].strip() if ni is not None and ni < len(row) else ""
        if tid == "*":
            if clip in out.default:
                raise InputError(path, f"row {n}: a second '*' row for clip {clip!r}")
            out.default[clip] = int(value)
            out.notes[(clip, None)] = note
            continue
        try:
            key = (clip, int(tid))
        except ValueError:
            raise InputError(path, f"row {n}: track_id must be an integer or '*', got {tid!r}") from None
        if key in out.explicit:
            raise InputError(path, f"row {n}: clip {clip!r} track {tid} listed twice")
        out.explicit[key] = int(value)
        out.notes[key] = note
    return out


# ---------------------------------------------------------------------------------------- sweep
def actor_predictions(
    record: ClipRecord,
    threshold: float | None,
    *,
    window: int = 25,
    min_frames: int = 6,
    prob_threshold: float = 0.5,
    every: int = 1,
) -> dict[int, bool]:
    """Per track: predicted positive? (module docstring).

    ``threshold`` is the smoother's T (the track is positive when the :class:`TrackSmoother` marks
    it active on at least one frame); ``None`` means no smoother (positive when any frame's
    probability is at least ``prob_threshold``). ``every = k`` keeps only every k-th judgement per
    track (staggered, see :meth:`ClipRecord.probabilities_of`).
    """
    out: dict[int, bool] = {}
    for tid in record.track_ids:
        probs = record.probabilities_of(tid, every)
        if threshold is None:
            valid = probs[~np.isnan(probs)]
            out[tid] = bool(valid.size and np.any(valid >= prob_threshold))
            continue
        sm = TrackSmoother(
            window=window, min_frames=min_frames, threshold=threshold, prob_threshold=prob_threshold
        )
        active = False
        for i, p in enumerate(probs.tolist()):
            obs = EVObservation(tid, i, 0.0, None if math.isnan(p) else p)
            (state,) = sm.update([obs], alive_track_ids=[tid])
            if state.state is EVState.ACTIVE:
                active = True
                break
        out[tid] = active
    return out


@dataclass(frozen=True)
class SweepRow:
    """Per-actor (or per-frame) counts and metrics of one setting."""

    setting: str
    threshold: float | None
    tp: int
    fp: int
    fn: int
    tn: int
    precision: float
    recall: float
    f1: float
    accuracy: float

    @property
    def n(self) -> int:
        return self.tp + self.fp + self.fn + self.tn


def _row(setting: str, threshold: float | None, pred: np.ndarray, truth: np.ndarray) -> SweepRow:
    tp = int(np.sum(pred & truth))
    fp = int(np.sum(pred & ~truth))
    fn = int(np.sum(~pred & truth))
    tn = int(np.sum(~pred & ~truth))
    prf = precision_recall_f1(tp, fp, fn)
    acc = (tp + tn) / max(len(truth), 1)
    return SweepRow(setting, threshold, tp, fp, fn, tn, prf["precision"], prf["recall"], prf["f1"], acc)


def sweep(
    records: Iterable[ClipRecord],
    labels: TrackLabels,
    thresholds: Sequence[float] = (0.0, 0.3, 0.5, 0.7),
    *,
    window: int = 25,
    min_frames: int = 6,
    prob_threshold: float = 0.5,
    every: int = 1,
    min_judged: int = 1,
) -> tuple[list[SweepRow], dict[str, float]]:
    """Per-actor rows (no smoother, then each T) and the per-frame row, over all clips together.

    Actors are the tracks with at least ``min_judged`` valid per-frame judgements when every frame
    is judged (so the actor set does not change with ``every``); ``min_judged = min_frames``
    keeps only the tracks the smoother can decide at all.

    Returns ``(rows, per_frame_threshold_metrics)``; the last row is ``"per frame"`` (every judged
    track-frame of those actors scored against its track's label), and the dict holds its max-F1
    and precision at recall 0.8 over thresholds.
    """
    records = list(records)
    truth: list[bool] = []
    preds: dict[float | None, list[bool]] = {t: [] for t in (None, *thresholds)}
    frame_scores: list[np.ndarray] = []
    frame_truth: list[np.ndarray] = []
    for rec in records:
        per_t = {
            t: actor_predictions(
                rec, t, window=window, min_frames=min_frames, prob_threshold=prob_threshold, every=every
            )
            for t in preds
        }
        for tid in rec.track_ids:
            if int(np.sum(~np.isnan(rec.probabilities_of(tid)))) < min_judged:
                continue
            y = bool(labels.label(rec.clip, tid))
            truth.append(y)
            for t in preds:
                preds[t].append(per_t[t][tid])
            probs = rec.probabilities_of(tid, every)
            probs = probs[~np.isnan(probs)]
            frame_scores.append(probs)
            frame_truth.append(np.full(len(probs), y))
    y_arr = np.asarray(truth, dtype=bool)
    rows = [_row("no smoother (any frame)", None, np.asarray(preds[None], dtype=bool), y_arr)]
    rows += [_row(f"smoother T={t:g}", t, np.asarray(preds[t], dtype=bool), y_arr) for t in thresholds]
    scores = np.concatenate(frame_scores) if frame_scores else np.empty(0)
    ft = np.concatenate(frame_truth) if frame_truth else np.empty(0, dtype=bool)
    rows.append(_row("per frame", None, scores >= prob_threshold, ft))
    return rows, threshold_metrics(scores, ft, recall_at=0.8)


def relative_change(row: SweepRow, base: SweepRow) -> tuple[float, float, float]:
    """% change of precision, recall and F1 of ``row`` against ``base`` (seed 000's Table 3 unit)."""

    def pct(a: float, b: float) -> float:
        return 100.0 * (a - b) / b if b and not math.isnan(a) and not math.isnan(b) else float("nan")

    return pct(row.precision, base.precision), pct(row.recall, base.recall), pct(row.f1, base.f1)
