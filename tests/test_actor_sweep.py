"""Per-actor smoother sweep on real video (issue 3, SPEC §1): recording, labels, sweep.

Records Framework B on the first 60 frames of the real night clip (a few seconds) and checks that the
committed track labels still match the tracker's ids there, then replays the smoother.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from makeway.errors import InputError
from makeway.eval.actor_sweep import (
    EV_CLIPS,
    NO_EV_CLIPS,
    TRACK_LABELS,
    ClipRecord,
    actor_predictions,
    read_track_labels,
    relative_change,
    sweep,
)
from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL
from makeway.pipeline.clip_record import cached_clip

CLIP = "night_ambulance_lights"


@pytest.fixture(scope="module")
def night60(video_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> ClipRecord:
    cache = tmp_path_factory.mktemp("track_probs")
    rec, hit = cached_clip(video_dir / f"{CLIP}.mp4", cache, DEFAULT_MODEL, max_frames=60)
    assert not hit
    again, hit2 = cached_clip(video_dir / f"{CLIP}.mp4", cache, DEFAULT_MODEL, max_frames=60)
    assert hit2 and np.array_equal(again.track_id, rec.track_id)
    np.testing.assert_array_equal(again.probability, rec.probability)
    return rec


def test_committed_labels_cover_every_clip() -> None:
    labels = read_track_labels()
    assert set(labels.clips) == set(EV_CLIPS) | set(NO_EV_CLIPS)
    for clip in NO_EV_CLIPS:
        assert labels.default[clip] == 0 and not any(c == clip for c, _ in labels.explicit)
    assert sum(v for (c, _), v in labels.explicit.items() if c in EV_CLIPS) >= 20
    assert labels.label(CLIP, 13) == 1 and labels.label(CLIP, 1) == 0 and labels.label(CLIP, 99999) == 0


def test_recording_matches_the_label_file_ids(night60: ClipRecord) -> None:
    """Track ids are deterministic: the ambulance is #13 from frame 15 on, the coach is #1 (label file)."""
    assert night60.frames == 60 and night60.clip == CLIP
    assert night60.frame.min() == 0 and night60.frame.max() == 59
    first = {t: int(night60.frame[night60.track_id == t].min()) for t in night60.track_ids}
    assert first[13] == 15 and first[1] == 0
    amb = night60.probabilities_of(13)
    assert np.nanmean(amb[-10:]) > 0.5  # once close, the classifier sees the lit ambulance
    w = night60.boxes[:, 2] - night60.boxes[:, 0]
    assert np.all(np.isnan(night60.probability[w < 18]))  # SPEC §1: no judgement under 18 px


def test_sweep_on_real_tracks(night60: ClipRecord) -> None:
    labels = read_track_labels()
    rows, thr = sweep([night60], labels)
    names = [r.setting for r in rows]
    assert names == [
        "no smoother (any frame)",
        "smoother T=0",
        "smoother T=0.3",
        "smoother T=0.5",
        "smoother T=0.7",
        "per frame",
    ]
    n_actors = len(night60.track_ids)
    for r in rows[:-1]:
        assert r.n == n_actors
    # raising T can only remove actors from the positive set (ever-active rule)
    positives = [r.tp + r.fp for r in rows[1:5]]
    assert positives == sorted(positives, reverse=True)
    assert rows[0].tp + rows[0].fp >= rows[1].tp + rows[1].fp
    assert actor_predictions(night60, 0.5)[13]  # the ambulance becomes active
    judged = int(np.sum(~np.isnan(night60.probability)))
    assert rows[-1].n == judged
    # the best F1 over thresholds is at least the F1 at the decision threshold 0.5, one of them
    assert thr["max_f1"] >= rows[-1].f1 - 1e-9 and rows[-1].f1 > 0.0
    p, r_, f = relative_change(rows[1], rows[1])
    assert (p, r_, f) == (0.0, 0.0, 0.0)
    # judging every 2nd frame leaves about half the judgements
    rows2, _ = sweep([night60], labels, every=2)
    assert abs(rows2[-1].n - judged / 2) < 0.1 * judged


def test_record_roundtrip_and_bad_file(night60: ClipRecord, tmp_path: Path) -> None:
    path = night60.save(tmp_path / "r.npz")
    back = ClipRecord.load(path)
    np.testing.assert_array_equal(back.boxes, night60.boxes)
    assert back.fps == night60.fps
    (tmp_path / "bad.npz").write_text("nope")
    with pytest.raises(InputError, match=r"bad\.npz"):
        ClipRecord.load(tmp_path / "bad.npz")


def test_label_file_errors(tmp_path: Path) -> None:
    p = tmp_path / "l.csv"
    p.write_text("# c\nclip,track_id,emergency,note\na,1,1,x\na,1,0,y\n")
    with pytest.raises(InputError, match="row 3: clip 'a' track 1 listed twice"):
        read_track_labels(p)
    p.write_text("clip,track_id,emergency\na,x,1\n")
    with pytest.raises(InputError, match="track_id must be an integer"):
        read_track_labels(p)
    p.write_text("clip,track_id,emergency\na,2,1\n")
    with pytest.raises(InputError, match="no label for clip 'a' track 3"):
        read_track_labels(p).label("a", 3)
    assert TRACK_LABELS.is_file()


def test_track_classifier_every_k_is_staggered(video_dir: Path) -> None:
    from makeway.messages import Box, Track
    from makeway.perceive.vision.ev_classifier import EVTrackClassifier, load_crop_classifier
    from makeway.sense.video import VideoReader

    with VideoReader(video_dir / f"{CLIP}.mp4", max_frames=1) as reader:
        _, _, image = next(iter(reader))
    tracks = [Track(i, Box(100 + 40 * i, 200, 220 + 40 * i, 320)) for i in range(1, 7)]
    clf = load_crop_classifier(DEFAULT_MODEL)
    full = EVTrackClassifier(clf).classify(image, tracks, 10, 0.4)
    for k in (2, 3):
        obs = EVTrackClassifier(clf, every=k).classify(image, tracks, 10, 0.4)
        for o, f in zip(obs, full, strict=True):
            if (10 + o.track_id) % k == 0:
                assert o.probability == pytest.approx(f.probability, abs=1e-6)
            else:
                assert o.probability is None
    with pytest.raises(ValueError, match="every"):
        EVTrackClassifier(clf, every=0)
