"""The lit-light verifier's appearance columns (``ProposalAppearance``): patch geometry with known
answers, the fitted projection and its metadata round trip, a verifier that reads the columns on a
real night frame, and malformed appearance metadata."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest

from conftest import require_module
from makeway.errors import InputError
from makeway.perceive.vision.light_verify import (
    CONTEXT_FEATURE_NAMES,
    FEATURE_NAMES,
    LightVerifier,
    ProposalAppearance,
    VerifiedLightDetector,
    appearance_patches,
)
from makeway.train.light_labels import iter_label_frames, read_labels
from makeway.train.light_split import LABEL_DIR

WIDTH = len(FEATURE_NAMES) + len(CONTEXT_FEATURE_NAMES)


def test_patches_are_centred_scaled_and_padded() -> None:
    img = np.zeros((120, 200, 3), np.uint8)
    img[50:60, 95:105] = (0, 0, 255)  # a 10 px red lamp centred at (100, 55)
    (p,) = appearance_patches(img, np.array([[95, 50, 105, 60]]), size=64, context=4.0, min_side_px=32)
    # 40 px across → 64 px: the lamp fills the middle 16 px, red, and nothing else is lit
    assert p.shape == (64, 64, 3)
    assert (p[26:38, 26:38] == (0, 0, 255)).all()
    assert p[:20].max() == 0 and p[44:].max() == 0
    # a 2 px box gets the minimum side (32 px); off the frame's corner the rest is grey 114
    (q,) = appearance_patches(img, np.array([[0, 0, 2, 2]]), size=64, context=4.0, min_side_px=32)
    assert (q[:20, :20] == 114).all() and (q[40:, 40:] == 0).all()
    assert appearance_patches(img, np.zeros((0, 4))).shape == (0, 64, 64, 3)


def test_projection_fits_round_trips_and_refuses_bad_state() -> None:
    rng = np.random.default_rng(0)
    basis = rng.normal(size=(2, 40))
    v = rng.normal(size=(500, 2)) @ basis * 5.0 + rng.normal(size=(500, 40)) * 0.1 + 3.0
    app = ProposalAppearance(n_components=2).fit(v)
    t = app.project(v)
    assert t.shape == (500, 2) and t.dtype == np.float32
    assert abs(float(np.corrcoef(t[:, 0], t[:, 1])[0, 1])) < 0.05  # principal axes: uncorrelated
    back = ProposalAppearance.from_json(app.to_json())
    assert back.n_components == 2 and back.layers == ("dark3", "dark4") and back.input_size == 64
    assert np.allclose(back.project(v[:5]), t[:5], atol=1e-5)
    assert app.feature_names == ("app_0", "app_1")
    with pytest.raises(ValueError, match=r"\(n, 40\)"):
        app.project(v[:, :10])
    with pytest.raises(ValueError, match="not fitted"):
        ProposalAppearance().project(v)
    with pytest.raises(ValueError, match="at least"):
        ProposalAppearance(n_components=8).fit(v[:3])
    d = json.loads(app.to_json())
    bads = (
        {**d, "scale": [0.0] * 40},
        {**d, "components": [[1.0]] * 3},
        {"mean": [1]},
        {**d, "backbone": "resnet"},
        {**d, "layers": ["dark9"]},
        {**d, "input_size": 50},
    )
    for bad in bads:
        with pytest.raises(ValueError, match="malformed"):
            ProposalAppearance.from_json(json.dumps(bad))
    with pytest.raises(ValueError, match="malformed"):
        ProposalAppearance.from_json("{not json")


@pytest.fixture(scope="module")
def night_frame(data_root: Path) -> np.ndarray:
    """The first checked night-clip frame with at least 3 labelled lamps."""
    lf = read_labels(LABEL_DIR / "night_ambulance_lights.csv")
    frames = lf.frames()
    key = next(
        k for k, rows in frames.items() if rows[0].checked and sum(r.kind == "light" for r in rows) >= 3
    )
    return next(iter(iter_label_frames(lf, data_root, keys=[key])))[1]


def test_verifier_with_appearance_columns_reads_them(night_frame: np.ndarray, tmp_path: Path) -> None:
    """A verifier exported with appearance columns and their settings loads with
    ``uses_appearance``; on a real night frame the detector feeds it the backbone's projected patch
    features (a model that splits on them alone scores proposals differently), and a model whose
    appearance settings are broken is refused with the file named."""
    require_module("xgboost")
    from makeway.train.light_verifier import _export, fit_verifier

    img = night_frame
    boxes = np.array(
        [[600, 300, 610, 306], [100, 500, 140, 520], [900, 100, 904, 104], [0, 0, 30, 30]], float
    )
    app = ProposalAppearance(n_components=3)
    vec = app.vectors(img, boxes)
    assert vec.shape == (4, 384) and np.isfinite(vec).all()
    app.fit(np.concatenate([vec, vec + 0.5 * np.random.default_rng(1).normal(size=vec.shape)]))
    rng = np.random.default_rng(0)
    x = rng.normal(size=(400, WIDTH + 3)).astype(np.float32)
    y = x[:, WIDTH] > 0.0  # "lit" = the first appearance coordinate
    path = tmp_path / "app.onnx"
    _export(fit_verifier(x, y, threads=1), path, {"threshold": "0.5", "appearance": app.to_json()})
    v = LightVerifier(path)
    assert v.uses_vehicles and v.uses_appearance and v.feature_names[WIDTH:] == ("app_0", "app_1", "app_2")
    assert v.appearance is not None
    assert np.allclose(v.appearance.transform(img, boxes), app.transform(img, boxes))
    det = VerifiedLightDetector("all", model=path, threshold=0.0)
    found = det.detect(img, 2)
    assert found and len({round(d.score, 4) for d in found}) > 1
    # the metadata names 203 columns but holds no (or broken) appearance settings: refused
    m = onnx.load(str(path))
    for value in (None, '{"mean": [1, 2]}'):
        keep = [p for p in m.metadata_props if p.key != "appearance"]
        del m.metadata_props[:]
        m.metadata_props.extend(keep)
        if value is not None:
            e = m.metadata_props.add()
            e.key, e.value = "appearance", value
        bad = tmp_path / "bad.onnx"
        onnx.save(m, str(bad))
        with pytest.raises(InputError, match=r"bad\.onnx"):
            LightVerifier(bad)
