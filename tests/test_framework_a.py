"""Framework A (issue 24, items 3–5): the YOLOX-nano graph as torch, the SimOTA loss, the ONNX export,
the shipped two-class detector, and ``--framework a`` through the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import require_module, yolo_subset

require_module("torch")

import torch  # noqa: E402

from makeway.cli.main import app  # noqa: E402
from makeway.eval.actor_sweep import ClipRecord, TrackLabels  # noqa: E402
from makeway.eval.framework_ab import class_flips, id_switches, label_by_overlap  # noqa: E402
from makeway.perceive.vision.detectors import YoloxNano, _grid  # noqa: E402
from makeway.perceive.vision.ev_detector import EV_DET_FILE, EVDetector  # noqa: E402
from makeway.track.one_stage import track_one_stage  # noqa: E402
from makeway.track.sort import Sort  # noqa: E402
from makeway.train import framework_a as fa  # noqa: E402

runner = CliRunner()

# held-out images of ambulance_yolo (src/makeway/data/ambulance_yolo_held_out.txt), each with one
# large, clearly visible labelled ambulance
HELD_OUT = [
    "0014_jpg.rf.14c7014a07cb1991cee783910e2c58f2",
    "0036_jpg.rf.a996babd248d73aa8735d05c0148e6c4",
]
# images of the training side with a large ambulance (test_detection_eval.py's)
TRAIN_SIDE = [
    "0009_jpg.rf.57b34231535de22443800ce18496f706",
    "0022_jpg.rf.cb893467345630b42489d08eb5623329",
    "0024_jpg.rf.2ff4c9029ae75191110dabd1c0158339",
]


@pytest.fixture(scope="module")
def yolox_path(data_root: Path) -> Path:
    path = data_root / "models" / "yolox_nano.onnx"
    if not path.is_file():
        pytest.fail(f"{path} missing from the shared data")
    return path


@pytest.fixture(scope="module")
def net(yolox_path: Path) -> fa.EVDetNet:
    torch.set_num_threads(2)
    return fa.EVDetNet.from_yolox(yolox_path).eval()


def _image(ambulance_dir: Path, stem: str) -> np.ndarray:
    image = cv2.imread(str(ambulance_dir / "images" / f"{stem}.jpg"))
    assert image is not None
    return image


def _gt(ambulance_dir: Path, stem: str, width: int, height: int) -> np.ndarray:
    rows = np.loadtxt(ambulance_dir / "labels" / f"{stem}.txt", ndmin=2)
    rows = rows[rows[:, 0] == 0]
    cx, cy, w, h = rows[:, 1] * width, rows[:, 2] * height, rows[:, 3] * width, rows[:, 4] * height
    return np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)


# ------------------------------------------------------------------------------------ graph surgery


def test_torch_graph_equals_onnx_runtime_on_a_real_image(
    net: fa.EVDetNet, yolox_path: Path, ambulance_dir: Path
) -> None:
    """The untouched YOLOX-nano graph run as torch (cut at the raw head tensors, our sigmoid and
    concatenation) gives ONNX Runtime's outputs: boxes and objectness, and — the new head starts
    from the COCO rows truck and car — those two class scores."""
    canvas, _ = fa.letterbox(_image(ambulance_dir, TRAIN_SIDE[0]))
    x = torch.from_numpy(canvas.transpose(2, 0, 1)[None].astype(np.float32))
    with torch.no_grad():
        ours = fa._Export(net)(x)[0].numpy()
    ref = YoloxNano(yolox_path, num_threads=2, fit_aspect=False)
    (theirs,) = ref._session.run(None, {ref._input_name: x.numpy()})
    theirs = theirs[0][:, [0, 1, 2, 3, 4, 5 + 7, 5 + 2]]
    assert ours.shape == theirs.shape == (3549, 7)
    np.testing.assert_allclose(ours, theirs, atol=1e-4, rtol=1e-4)
    # the training shortcut: the head alone on the neck's maps (from ONNX Runtime) is the same network
    neck = fa.neck_features(fa.neck_session(yolox_path, threads=2), [canvas])
    with torch.no_grad():
        raw = fa._flatten(net.head([torch.from_numpy(n.astype(np.float32)) for n in neck]))[0]
    head_only = torch.cat([raw[:, :4], torch.sigmoid(raw[:, 4:])], dim=1).numpy()
    np.testing.assert_allclose(head_only, ours, atol=2e-2)  # the cache holds float16 maps


# ------------------------------------------------------------------------------ loss and assignment


def test_giou_of_equal_and_disjoint_boxes() -> None:
    a = torch.tensor([[0.0, 0.0, 2.0, 2.0], [0.0, 0.0, 1.0, 1.0]])
    b = torch.tensor([[0.0, 0.0, 2.0, 2.0], [2.0, 0.0, 3.0, 1.0]])
    iou, g = fa.giou(a, b)
    assert iou[0] == pytest.approx(1.0) and g[0] == pytest.approx(1.0)
    # disjoint unit squares one apart: IoU 0, hull 3, union 2 → GIoU = -1/3
    assert iou[1] == pytest.approx(0.0) and g[1] == pytest.approx(-1.0 / 3.0, abs=1e-6)


def _hand_made(size: int = 64) -> tuple[torch.Tensor, ...]:
    """A 64×64 input (8×8 + 4×4 + 2×2 = 84 cells) with one ground-truth box [16, 16, 48, 48]: three
    stride-8 cells near its centre predict it exactly, every other cell a 4-pixel box."""
    xy, st = fa.grid_of(size, size)
    n = xy.shape[0]
    raw = torch.zeros(n, 7)
    raw[:, 2:4] = torch.log(4.0 / st)[:, None]  # w = h = 4 px everywhere
    gt = torch.tensor([[16.0, 16.0, 48.0, 48.0]])
    exact = []
    for col, row in ((3, 3), (4, 3), (3, 4)):  # stride-8 cells: index = row * 8 + col
        k = row * 8 + col
        exact.append(k)
        raw[k, 0] = 32.0 / 8 - col  # cx = (x + col) * 8 = 32
        raw[k, 1] = 32.0 / 8 - row
        raw[k, 2:4] = float(np.log(32.0 / 8))  # w = h = 32
    return raw, gt, xy, st, torch.tensor(exact)


def test_simota_takes_the_dynamic_k_best_cells() -> None:
    raw, gt, xy, st, exact = _hand_made()
    boxes = fa.decode_boxes(raw[:, :4], xy, st)
    fg, matched, iou = fa.simota_assign(boxes, raw[:, 4], raw[:, 5:], gt, torch.tensor([0]), xy, st)
    # top-10 IoUs: three of 1, seven of 16/1024 → k = int(3.11) = 3: exactly the three exact cells
    assert sorted(torch.nonzero(fg).flatten().tolist()) == sorted(exact.tolist())
    assert matched.tolist() == [0, 0, 0]
    np.testing.assert_allclose(iou.numpy(), 1.0, atol=1e-6)
    # no ground truth: no positive cell
    fg0, _, _ = fa.simota_assign(boxes, raw[:, 4], raw[:, 5:], torch.zeros(0, 4), torch.zeros(0), xy, st)
    assert not fg0.any()


def test_yolox_loss_rewards_the_right_box_and_class() -> None:
    raw, gt, xy, st, exact = _hand_made()
    target = [(gt, torch.tensor([0]))]
    _, parts = fa.yolox_loss(raw[None], target, xy, st)
    assert parts["n_fg"] == 3 and parts["box"] == pytest.approx(0.0, abs=1e-5)
    shifted = raw.clone()
    shifted[exact, 0] += 0.5  # 4 px to the right
    _, worse = fa.yolox_loss(shifted[None], target, xy, st)
    assert worse["box"] > 0.05
    confident = raw.clone()
    confident[exact, 4] = 6.0  # objectness of the positives up, class 0 up, class 1 down
    confident[exact, 5] = 6.0
    confident[exact, 6] = -6.0
    _, better = fa.yolox_loss(confident[None], target, xy, st)
    assert better["obj"] < parts["obj"] and better["cls"] < parts["cls"]
    wrong = confident.clone()
    wrong[exact, 5], wrong[exact, 6] = -6.0, 6.0  # the other class
    _, flipped = fa.yolox_loss(wrong[None], target, xy, st)
    assert flipped["cls"] > 10 * better["cls"]
    # gradients reach the raw outputs
    leaf = raw.clone().requires_grad_(True)
    loss, _ = fa.yolox_loss(leaf[None], target, xy, st)
    loss.backward()
    assert leaf.grad is not None and float(leaf.grad.abs().sum()) > 0


# ------------------------------------------------------------------------------ full fine-tune


def _samples(ambulance_dir: Path) -> list[fa.Sample]:
    out = []
    for stem in TRAIN_SIDE:
        image = _image(ambulance_dir, stem)
        gt = _gt(ambulance_dir, stem, image.shape[1], image.shape[0]).astype(np.float32)
        out.append(fa.Sample(image, gt, np.zeros(len(gt), np.int64), stem, f"{stem}.jpg"))
    return out


def test_mosaic_keeps_each_box_on_its_vehicle(ambulance_dir: Path) -> None:
    """Four real photos tiled, scaled and cut: every box left lies inside the canvas, is at least
    2 px a side, and covers image content (not the grey pad); the same generator seed gives the
    same view."""
    samples = _samples(ambulance_dir)
    group = [samples[0], samples[1], samples[2], samples[0]]
    seen = 0
    for seed in range(12):
        canvas, boxes, classes = fa.mosaic_sample(group, np.random.default_rng(seed), 320)
        again, boxes2, _ = fa.mosaic_sample(group, np.random.default_rng(seed), 320)
        np.testing.assert_array_equal(canvas, again)
        np.testing.assert_array_equal(boxes, boxes2)
        assert canvas.shape == (320, 320, 3) and canvas.dtype == np.uint8
        assert len(boxes) == len(classes) and set(classes.tolist()) <= {0}
        assert (boxes >= 0).all() and (boxes <= 320).all()
        assert ((boxes[:, 2:] - boxes[:, :2]) >= 2).all()
        for x1, y1, x2, y2 in boxes.round().astype(int):
            patch = canvas[y1:y2, x1:x2].astype(int)
            assert (np.abs(patch - 114).max(axis=2) > 3).mean() > 0.5  # mostly photo, not pad
        seen += len(boxes)
    assert seen >= 12  # the ambulances survive most cuts
    with pytest.raises(ValueError, match="4 samples"):
        fa.mosaic_sample(samples[:3], np.random.default_rng(0), 320)


def test_full_fine_tune_trains_every_layer(yolox_path: Path, ambulance_dir: Path) -> None:
    """``part="full"``'s loop on three real photos, two epochs on the CPU with loader workers: the
    gradient reaches the backbone's first convolution (the head-only path freezes it), the losses
    are finite, the history holds each validated epoch, and the best validated weights are the ones
    left."""
    samples = _samples(ambulance_dir)
    torch.manual_seed(0)
    net = fa.EVDetNet.from_yolox(yolox_path)
    first = next(iter(net.graph.weights.values())).detach().clone()
    best, best_epoch, history = fa._fit_full(
        net, samples, samples[:1], epochs=2, batch=2, size=128, lr=1e-3, head_lr=1e-2, seed=0,
        workers=1, mosaic=0.5, val_every=1, max_minutes=None, progress=False, say=lambda _: None,
        start=0.0,
    )  # fmt: skip
    assert [row["epoch"] for row in history] == [1.0, 2.0]
    assert all(np.isfinite(row["loss"]) and row["loss"] > 0 for row in history)
    conv = next(iter(net.graph.weights.values()))  # the backbone's first convolution
    assert conv.grad is not None and float(conv.grad.abs().sum()) > 0  # the last step reached it
    assert 0 <= best_epoch <= 2 and 0.0 <= best["map50"] <= 1.0
    if best_epoch:
        assert best["map50"] == pytest.approx(history[best_epoch - 1]["val_map50"])
        assert not torch.equal(first, conv)
    else:  # no epoch beat the start: the starting weights are back
        assert torch.equal(first, conv)
    assert best["map50"] == pytest.approx(fa.validate(net, samples[:1])["map50"])
    with pytest.raises(ValueError, match="only 3 training images"):
        fa._fit_full(
            net, samples, samples[:1], epochs=1, batch=4, size=128, lr=1e-3, head_lr=1e-2, seed=0,
            workers=0, mosaic=0.0, val_every=1, max_minutes=None, progress=False, say=lambda _: None,
            start=0.0,
        )  # fmt: skip


def test_train_detector_refuses_a_missing_gpu_and_an_unknown_part(
    ambulance_dir: Path, tmp_path: Path
) -> None:
    """Checked before any image is read: one line, exit 2, nothing written."""
    base = ["classify", "train-detector", str(tmp_path / "a.onnx"), "--data", str(ambulance_dir), "-q"]
    r = runner.invoke(app, [*base, "--part", "everything"])
    assert r.exit_code == 2 and "unknown part 'everything'" in r.output
    if not torch.cuda.is_available():
        r = runner.invoke(app, [*base, "--part", "full", "--device", "cuda"])
        assert r.exit_code == 2 and "no CUDA device" in r.output
    assert not (tmp_path / "a.onnx").exists()


# ------------------------------------------------------------------------------------ ONNX round trip


def test_export_round_trip(net: fa.EVDetNet, ambulance_dir: Path, tmp_path: Path) -> None:
    path = fa.export_ev_detector(net, tmp_path / "a.onnx", threshold=0.42, training="test")
    det = EVDetector(path, num_threads=2, fit_aspect=False)
    assert det.threshold == pytest.approx(0.42) and det.metadata["training"] == "test"
    image = _image(ambulance_dir, TRAIN_SIDE[1])
    pred, sx, sy, shape = det.raw(image)
    canvas, r = fa.letterbox(image)
    assert shape == (416, 416) and sx == pytest.approx(r) and sy == pytest.approx(r)
    with torch.no_grad():
        ours = fa._Export(net)(torch.from_numpy(canvas.transpose(2, 0, 1)[None].astype(np.float32)))
    np.testing.assert_allclose(pred, ours[0].numpy(), atol=1e-4, rtol=1e-4)
    # a 16:9 frame runs at 416×256 through the same file (the graph is not bound to 416×416)
    wide = EVDetector(path, num_threads=2)
    frame = cv2.resize(image, (640, 360))
    pred, _, _, shape = wide.raw(frame)
    assert shape == (256, 416) and pred.shape == (sum(len(_grid(256, 416, 0.0)[1]) for _ in [0]), 7)


# ------------------------------------------------------------------------------------ shipped model


def test_shipped_detector_finds_held_out_ambulances(ambulance_dir: Path) -> None:
    assert EV_DET_FILE.is_file() and EV_DET_FILE.stat().st_size < 5_000_000
    det = EVDetector(num_threads=2)
    assert 0.0 < det.threshold < 1.0 and "YOLOX" in det.metadata["license"]
    from makeway.eval.detection import box_iou_matrix

    for stem in HELD_OUT:
        image = _image(ambulance_dir, stem)
        gt = _gt(ambulance_dir, stem, image.shape[1], image.shape[0])
        found = det.detect(image)
        ev = found.ev_scores >= det.threshold
        assert ev.any(), stem
        assert box_iou_matrix(gt, found.boxes[ev]).max() >= 0.5, stem
        hit = int(np.argmax(box_iou_matrix(gt, found.boxes).max(axis=0)))
        assert found.p_ev[hit] > 0.5, stem


def test_track_one_stage_keeps_the_id_through_class_flips() -> None:
    """One SORT over all vehicles: a box whose class flips EV → other → EV keeps one id (seed
    001's Framework A tracked per class would restart it twice), and each track carries the P(EV) of
    its own detection this frame."""
    tracker = Sort(max_age=1, min_hits=1, iou_threshold=0.3)
    ids, probs = [], []
    for frame, p in enumerate([0.9, 0.8, 0.3, 0.2, 0.7]):
        boxes = np.array([[100.0 + frame, 50.0, 200.0 + frame, 120.0], [400.0, 60.0, 470.0, 110.0]])
        p_ev = np.array([p, 0.05])
        arrays = (boxes, np.array([0.9, 0.8]), np.where(p_ev >= 0.5, 0, 1), p_ev)
        tracks, by_id = track_one_stage(tracker, arrays)
        first = min(tracks, key=lambda t: t.box.x1)
        ids.append(first.track_id)
        probs.append(by_id[first.track_id])
        assert first.class_id == (0 if p >= 0.5 else 1)
        assert first.label == ("emergency vehicle" if p >= 0.5 else "other vehicle")
    assert len(set(ids)) == 1
    np.testing.assert_allclose(probs, [0.9, 0.8, 0.3, 0.2, 0.7])


# ---------------------------------------------------------------------------------------------- CLI


def test_evaluate_detector_framework_a(ambulance_dir: Path, tmp_path: Path) -> None:
    folder = yolo_subset(ambulance_dir, tmp_path / "set", TRAIN_SIDE)
    r = runner.invoke(app, ["evaluate-detector", "--data", str(folder), "--framework", "a"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["framework"] == "a" and out["score"] == "ev_score" and out["n_images"] == 3
    assert out["map50"] >= 0.9 and out["recall"] >= 2 / 3 and out["ms_per_image"] > 0


def test_detect_framework_a_on_a_clip_segment(video_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    clip = video_dir / "intersection_cam_ambulance.mp4"
    r = runner.invoke(
        app,
        ["detect", str(clip), "--framework", "a", "--rule", "crop", "--max-frames", "8", "--no-video",
         "-o", str(out), "--json", "-q"],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    assert summary["detector"] == "ev_det_yolox" and summary["frames"] == 8
    lines = [json.loads(line) for line in (out / "tracks.jsonl").read_text().splitlines()]
    assert len(lines) == 8
    labels = {t["label"] for line in lines for t in line["tracks"]}
    assert labels and labels <= {"emergency vehicle", "other vehicle"}


@pytest.mark.parametrize("command", ["evaluate-detector", "detect"])
def test_bad_model_files_are_one_line(
    command: str, ambulance_dir: Path, video_dir: Path, yolox_path: Path, tmp_path: Path
) -> None:
    target = ["--data", str(ambulance_dir)] if command == "evaluate-detector" else [
        str(video_dir / "traffic_no_ev.mp4"), "--no-video", "-o", str(tmp_path / "o")]  # fmt: skip
    missing = tmp_path / "nowhere.onnx"
    r = runner.invoke(app, [command, *target, "--framework", "a", "--model", str(missing)])
    assert r.exit_code == 2 and str(missing) in r.stderr and len(r.stderr.strip().splitlines()) == 1
    # an ONNX model, but the COCO detector, not a makeway EV detector (no metadata)
    r = runner.invoke(app, [command, *target, "--framework", "a", "--model", str(yolox_path)])
    assert r.exit_code == 2 and "ev detector" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------- A against B on video


def _record(clip: str, rows: list[tuple[int, int, float, float]]) -> ClipRecord:
    """A record of ``(frame, track, x1, p)`` rows: 40×40 boxes at ``x1``, probability ``p``."""
    arr = np.asarray(rows, dtype=np.float64)
    boxes = np.stack([arr[:, 2], np.full(len(arr), 10.0), arr[:, 2] + 40, np.full(len(arr), 50.0)], axis=1)
    return ClipRecord(clip, 25.0, int(arr[:, 0].max()) + 1, arr[:, 0].astype(np.int64),
                      arr[:, 1].astype(np.int64), boxes, arr[:, 3])  # fmt: skip


def test_overlap_labels_flips_and_id_switches() -> None:
    # B (labelled): track 7 is the EV at x = 0, track 8 a car at x = 200, for frames 0-5
    b = _record("clip", [(f, 7, 0.0, 0.9) for f in range(6)] + [(f, 8, 200.0, 0.1) for f in range(6)])
    # A: the EV is track 1 on frames 0-2 and track 2 on frames 3-5 (one id switch), its class
    # flipping once within track 1; the car is track 3; track 4 is far from anything B tracked
    a = _record(
        "clip",
        [(0, 1, 1.0, 0.9), (1, 1, 1.0, 0.4), (2, 1, 2.0, 0.4)]
        + [(f, 2, 2.0, 0.8) for f in range(3, 6)]
        + [(f, 3, 201.0, 0.2) for f in range(6)]
        + [(0, 4, 500.0, 0.6)],
    )
    labels = TrackLabels(Path("x"), explicit={("clip", 7): 1}, default={"clip": 0})
    la, unmatched = label_by_overlap(a, b, labels)
    assert la == {1: 1, 2: 1, 3: 0, 4: 0} and unmatched == 1
    flips = class_flips(a, la)
    assert (flips.tracks, flips.tracks_flipping, flips.flips) == (4, 1, 1)
    assert (flips.ev_tracks, flips.ev_tracks_flipping, flips.ev_flips) == (2, 1, 1)
    assert id_switches(a, b, {7: 1, 8: 0}) == (1, 1)  # A's id changes once while following B's EV
    assert id_switches(b, a, la) == (0, 2)  # B follows A's two EV tracks with one id
