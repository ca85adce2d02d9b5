"""The cross-source protocol (issue 24, item 1) on small real subsets of every source.

Sources here: 36 ev_crops crops, the crops of 6 ambulance_yolo photos, and the labelled tracks of the
first frames of two road clips (one with an ambulance, one without any EV). The trainer is a
colour rule whose every prediction the test computes itself, so each held-out score has a reason
independent of the protocol's code.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from makeway.apps.classify import build_ambulance_crops, evaluate_crop_classifier
from makeway.cli.classify import classify_app
from makeway.errors import InputError
from makeway.eval.actor_sweep import read_track_labels
from makeway.eval.cross_source import leave_one_source_out, score_sources, worst_source
from makeway.perceive.vision.ev_classifier import EVCropClassifier, load_crop_classifier
from makeway.pipeline.track_crops import build_track_crops
from makeway.sense.crops import CropSet, read_crop_folder, split_holdout
from makeway.train.ev_head import FeatureCache, cached_head

runner = CliRunner()
SIZE = 32


def redness(images: np.ndarray) -> np.ndarray:
    """Share of pixels whose red channel exceeds green by more than 50 (BGR ``uint8`` crops)."""
    img = images.astype(np.int16)
    return np.mean(img[..., 2] - img[..., 1] > 50, axis=(1, 2))


class RedRule:
    """EV when the red share reaches ``cut``; ``predict_proba`` is 1 or 0."""

    threshold = 0.5
    input_size = SIZE

    def __init__(self, cut: float) -> None:
        self.cut = cut

    def predict_proba(self, images: np.ndarray) -> np.ndarray:
        return (redness(images) >= self.cut).astype(np.float64)


def fit_cut(crops: CropSet) -> float:
    """The midpoint between the mean red share of positives and of negatives."""
    r = redness(crops.load_images(SIZE, cache=False))
    return float(0.5 * (r[crops.labels == 1].mean() + r[crops.labels == 0].mean()))


@pytest.fixture(scope="module")
def sources(data_root: Path, video_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, CropSet]:
    tmp = tmp_path_factory.mktemp("xsrc")
    ev = read_crop_folder(data_root / "vision" / "ev_crops").subset(np.arange(36))
    yolo = data_root / "vision" / "ambulance_yolo" / "valid"
    few = tmp / "yolo"
    for sub in ("images", "labels"):
        (few / sub).mkdir(parents=True)
    for path in sorted((yolo / "images").iterdir())[:6]:
        (few / "images" / path.name).write_bytes(path.read_bytes())
        label = yolo / "labels" / f"{path.stem}.txt"
        (few / "labels" / label.name).write_bytes(label.read_bytes())
    build_ambulance_crops(tmp / "amb", few, progress=False)
    build_track_crops(
        tmp / "fire",
        [video_dir / "fire_trucks_red_lights.mp4"],
        cache_dir=tmp / "boxes",
        every=5,
        max_frames=60,
        progress=False,
    )
    build_track_crops(
        tmp / "highway",
        [video_dir / "highway_cam_no_ev.mp4"],
        cache_dir=tmp / "boxes",
        every=10,
        max_frames=40,
        progress=False,
    )
    return {
        "ev_crops": ev,
        "ambulance_yolo": read_crop_folder(tmp / "amb"),
        "fire": read_crop_folder(tmp / "fire"),
        "highway": read_crop_folder(tmp / "highway"),
    }


def by_hand(crops: CropSet, cut: float) -> dict[str, float | None]:
    """Accuracy, precision, recall, F1, specificity of the red rule, counted crop by crop."""
    tp = fp = fn = tn = 0
    for i, path in enumerate(crops.paths):
        one = CropSet((path,), crops.labels[i : i + 1]).load_images(SIZE, cache=False)
        pred = bool(redness(one)[0] >= cut)
        truth = bool(crops.labels[i])
        tp += pred and truth
        fp += pred and not truth
        fn += truth and not pred
        tn += not pred and not truth
    n = tp + fp + fn + tn
    both = 0 < tp + fn < n
    precision = tp / (tp + fp) if both and tp + fp else None
    recall = tp / (tp + fn) if tp + fn else None
    f1 = 2 * tp / (2 * tp + fp + fn) if both and tp + fp else None
    return {
        "accuracy": (tp + tn) / n,
        "precision": precision,
        "recall": recall,
        "f1": f1,
        "specificity": tn / (tn + fp) if tn + fp else None,
    }


def test_track_crops_carry_their_track_label_and_group(sources: dict[str, CropSet]) -> None:
    labels = read_track_labels()
    fire = sources["fire"]
    assert fire.groups is not None
    for name, label, group in zip(fire.names, fire.labels.tolist(), fire.groups.tolist(), strict=True):
        clip, _, rest = name.rpartition("_t")
        tid = int(rest.split("_f")[0])
        assert group == f"{clip}#{tid}" and label == labels.label(clip, tid)
    # the label file's notes: in frames 0-59 the EVs are the ambulance (#5), the fire engine (#23) and a
    # sliver on the ambulance (#25); everything else is a car
    positive_groups = set(fire.groups[fire.labels == 1].tolist())
    assert "fire_trucks_red_lights#5" in positive_groups
    assert positive_groups <= {f"fire_trucks_red_lights#{t}" for t in (5, 23, 25)}
    assert fire.n_positive >= 5 and len(fire) - fire.n_positive >= 5
    assert sources["highway"].n_positive == 0  # a clip without any EV


def test_no_track_straddles_a_split(sources: dict[str, CropSet]) -> None:
    fire = sources["fire"]
    assert fire.groups is not None
    _, counts = np.unique(fire.groups, return_counts=True)
    assert counts.max() >= 3  # several frames per track: the rule has something to keep together
    train_idx, test_idx = split_holdout(fire, fraction=0.3, seed=0)
    assert len(test_idx) and len(train_idx)
    assert not set(fire.groups[train_idx].tolist()) & set(fire.groups[test_idx].tolist())


def test_leave_one_source_out_with_a_colour_rule(sources: dict[str, CropSet]) -> None:
    seen: list[CropSet] = []

    def trainer(train: CropSet) -> RedRule:
        seen.append(train)
        return RedRule(fit_cut(train))

    scores = leave_one_source_out(sources, trainer, model="red")
    assert [s.source for s in scores] == list(sources)
    for score, train in zip(scores, seen, strict=True):
        held = sources[score.source]
        others = [c for name, c in sources.items() if name != score.source]
        # trained on exactly the other sources, never on a crop or a group of the held-out one
        assert set(train.paths) == {p for c in others for p in c.paths}
        assert not set(train.paths) & set(held.paths)
        assert train.groups is not None
        assert all(g.split("/", 1)[0] in score.trained_on for g in train.groups.tolist())
        assert score.source not in score.trained_on
        red = [(redness(c.load_images(SIZE, cache=False)), c.labels) for c in others]
        pos = np.concatenate([r[y == 1] for r, y in red])
        neg = np.concatenate([r[y == 0] for r, y in red])
        cut = 0.5 * (pos.mean() + neg.mean())
        expected = by_hand(held, cut)
        got = score.as_dict()
        for key, value in expected.items():
            if value is None:
                assert got[key] is None, (score.source, key)
            else:
                assert got[key] == pytest.approx(value, abs=1e-4), (score.source, key)
        assert got["n"] == len(held) and got["positive_share"] == pytest.approx(
            held.n_positive / len(held), abs=1e-4
        )
    highway = next(s for s in scores if s.source == "highway")
    assert highway.classes == "negative only" and highway.accuracy == highway.specificity
    assert next(s for s in scores if s.source == "fire").classes == "both"
    assert worst_source(scores).accuracy == min(s.accuracy for s in scores)


def test_fixed_model_on_a_positive_only_source(sources: dict[str, CropSet]) -> None:
    amb = sources["ambulance_yolo"]
    only_pos = amb.subset(np.flatnonzero(amb.labels == 1))
    assert len(only_pos) >= 3
    (score,) = score_sources(RedRule(0.02), {"ambulances": only_pos}, model="red")
    expected = by_hand(only_pos, 0.02)
    assert score.classes == "positive only"
    assert score.precision is None and score.f1 is None and score.specificity is None
    assert score.recall == pytest.approx(expected["recall"]) and score.accuracy == score.recall


def test_cached_head_scores_as_the_head_does(sources: dict[str, CropSet], tmp_path: Path) -> None:
    clf = load_crop_classifier("default", num_threads=1)
    assert isinstance(clf, EVCropClassifier)
    crops = sources["fire"].subset(np.arange(6))
    direct = clf.predict_proba(crops.load_images(clf.input_size, cache=False))
    first = cached_head(clf, tmp_path, progress=False).predict_crop_set(crops)
    cache = FeatureCache(clf.blocks, folder=tmp_path, progress=False)
    assert cache.path is not None and cache.path.is_file() and len(cache._rows) == 6  # read back from disk
    again = cached_head(clf, tmp_path, progress=False).predict_crop_set(crops)
    np.testing.assert_allclose(first, direct, atol=1e-6)
    np.testing.assert_allclose(again, direct, atol=1e-6)


def test_cli_scores_a_fixed_model_per_source(sources: dict[str, CropSet], tmp_path: Path) -> None:
    fire, highway = sources["fire"].root, sources["highway"].root
    assert fire is not None and highway is not None
    args = ["cross-source", "--model", "fastest", "--cache", str(tmp_path), "-q"]
    args += ["--source-dir", f"fire={fire}", "--source-dir", f"highway={highway}", "--source", "fire,highway"]
    r = runner.invoke(classify_app, args)
    assert r.exit_code == 0, r.output
    lines = [json.loads(line) for line in r.stdout.splitlines()]
    assert [(d.get("model"), d.get("held_out")) for d in lines[:2]] == [
        ("fastest", "fire"),
        ("fastest", "highway"),
    ]
    for d, folder in zip(lines[:2], (fire, highway), strict=True):
        # the same figure through `classify eval`'s own scoring
        assert d["accuracy"] == pytest.approx(
            evaluate_crop_classifier(folder, "fastest").metrics["accuracy"], abs=1e-4
        )
    worst = min(lines[:2], key=lambda d: d["accuracy"])
    assert lines[2]["worst"]["fastest"] == {"held_out": worst["held_out"], "accuracy": worst["accuracy"]}


def _one_line_error(r: Any) -> str:
    assert r.exit_code == 2, r.output
    err = r.stderr.strip()
    assert err.count("\n") == 0 and err.startswith("error:"), err
    return err


def test_cli_bad_input(sources: dict[str, CropSet], tmp_path: Path) -> None:
    fire = sources["fire"].root
    base = ["cross-source", "--cache", str(tmp_path / "cache"), "-q"]
    err = _one_line_error(runner.invoke(classify_app, [*base, "--source", "nope"]))
    assert "unknown source 'nope'" in err and "road_clips" in err
    empty = tmp_path / "empty"
    (empty / "images").mkdir(parents=True)
    (empty / "labels.csv").write_text("image,emergency,group\n")
    err = _one_line_error(
        runner.invoke(
            classify_app, [*base, "--model", "fastest", "--source-dir", f"e={empty}", "--source", "e"]
        )
    )
    assert str(empty / "labels.csv") in err and "no labelled images" in err
    missing = tmp_path / "nothere.onnx"
    err = _one_line_error(
        runner.invoke(
            classify_app, [*base, "--model", str(missing), "--source-dir", f"f={fire}", "--source", "f"]
        )
    )
    assert str(missing) in err and "not found" in err
    assert not (tmp_path / "cache").exists()  # nothing built or written
    with pytest.raises(InputError, match="has no crops"):
        score_sources(RedRule(0.1), {"none": CropSet((), np.empty(0, dtype=np.int64))}, model="red")


def test_labels_csv_has_a_group_column(sources: dict[str, CropSet]) -> None:
    root = sources["fire"].root
    assert root is not None
    with (root / "labels.csv").open() as fh:
        assert next(csv.reader(fh)) == ["image", "emergency", "group"]


def test_head_trainer_with_quality_matching_fits_on_the_softened_positives(
    sources: dict[str, CropSet], tmp_path: Path
) -> None:
    """The trainer's head equals one fitted by hand on features of
    :func:`~makeway.train.crop_quality.match_positive_quality`'s images, and differs from the
    plain trainer's (some positives were softened)."""
    from makeway.eval.cross_source import merge_sources
    from makeway.train.crop_quality import match_positive_quality, source_of_groups
    from makeway.train.ev_head import head_trainer

    fire = sources["fire"]
    train = merge_sources(
        {"ambulance_yolo": sources["ambulance_yolo"], "fire": fire.subset(np.arange(0, len(fire), 2))}
    )
    test = sources["ev_crops"].subset(np.arange(12))
    blocks = ["yolox_nano@160:dark5"]  # one small block keeps the three fits quick
    cache = FeatureCache(blocks, folder=tmp_path, progress=False)
    matched = head_trainer(blocks, cache=cache, match_quality=True)(train)
    plain = head_trainer(blocks, cache=cache)(train)
    images, shrunk = match_positive_quality(
        train.load_images(cache.input_size, cache=False),
        train.labels,
        source_of_groups(train.groups, len(train)),
        seed=0,
    )
    assert (shrunk > 0).any() and not shrunk[train.labels == 0].any()
    x, xm = cache.extractor.transform_pair(images)
    by_hand = EVCropClassifier(blocks=blocks, seed=0).fit_features(
        x, train.labels, x_mirrored=xm, groups=train.groups
    )
    x_test, xm_test = cache.features(test)
    expected = by_hand.predict_proba_features(x_test, xm_test)
    np.testing.assert_allclose(matched.predict_crop_set(test), expected, atol=1e-6)
    assert not np.allclose(plain.predict_crop_set(test), expected, atol=1e-3)


def test_cli_train_with_quality_matching_says_what_it_softened(
    sources: dict[str, CropSet], tmp_path: Path
) -> None:
    fire = sources["fire"]
    assert fire.root is not None and 0 < fire.n_positive < len(fire)
    out = tmp_path / "head.npz"
    r = runner.invoke(
        classify_app,
        [
            "train",
            "--data",
            str(fire.root),
            "--match-quality",
            "--block",
            "yolox_nano@160:dark5",
            "--out",
            str(out),
        ],
    )
    assert r.exit_code == 0, r.output
    head = EVCropClassifier.load(out)
    assert "positive crops made as soft as its negatives" in head.training
    n = int(head.training.split(", ")[-1].split()[0])
    assert 0 < n <= fire.n_positive  # the clip's EVs are sharper than the traffic around them
