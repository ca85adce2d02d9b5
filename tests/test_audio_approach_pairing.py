"""Issue 25: each ranger set has its own approaching/receding classifier, trained on that set's
distances, and the listener picks the one paired with the rangers it runs."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from makeway.perceive.audio.motion import (
    APPROACH_MODELS,
    DB_PER_NEPER_RANGE,
    DEFAULT_APPROACH_MODEL,
    TrendApproach,
    approach_model_for,
)
from makeway.perceive.audio.siren_model import (
    DEFAULT_SIREN_RANGERS,
    PRIOR_SIREN_RANGERS,
    SIREN_RANGER_SETS,
    WIDE_SIREN_RANGERS,
    SirenModel,
    ranger_set_name,
)
from makeway.perceive.audio.stream import SirenListener, default_approach
from makeway.registry import UnknownNameError
from makeway.sense.recording import reference_mics


def _trained_on(path: object) -> list[str]:
    """The ranger files the classifier at ``path`` was trained on, from its ONNX metadata (the
    ``rangers`` key, or for files written before it the siren model's repr)."""
    meta = TrendApproach(path).session_.get_modelmeta().custom_metadata_map  # type: ignore[arg-type]
    training = json.loads(meta["training"])
    if "rangers" in training:
        return sorted(training["rangers"])
    found = re.search(r"ranger=([\w.+]+)\)", training["siren_model"])
    assert found is not None, training["siren_model"]
    return sorted(found.group(1).split("+"))


def test_every_ranger_set_has_a_classifier_trained_on_its_distances() -> None:
    assert list(APPROACH_MODELS) == list(SIREN_RANGER_SETS) == ["prior", "wide"]
    for name, rangers in SIREN_RANGER_SETS.items():
        path = APPROACH_MODELS[name]
        assert path.is_file() and path.stat().st_size <= 5_000_000
        assert _trained_on(path) == sorted(p.name for p in rangers)
    assert APPROACH_MODELS["prior"] != APPROACH_MODELS["wide"]
    with pytest.raises(UnknownNameError, match="prior, wide"):
        APPROACH_MODELS["loud"]


def test_approach_model_for_matches_by_file_name() -> None:
    assert ranger_set_name(WIDE_SIREN_RANGERS) == "wide"
    assert ranger_set_name(list(reversed(PRIOR_SIREN_RANGERS))) == "prior"  # any order
    assert ranger_set_name([p.name for p in WIDE_SIREN_RANGERS]) == "wide"  # by file name
    assert approach_model_for(WIDE_SIREN_RANGERS) == APPROACH_MODELS["wide"]
    assert approach_model_for(PRIOR_SIREN_RANGERS) == APPROACH_MODELS["prior"]
    # any other combination (one ranger, a mix, none) gets the default rangers' classifier
    for other in ([WIDE_SIREN_RANGERS[0]], [PRIOR_SIREN_RANGERS[0], WIDE_SIREN_RANGERS[0]], []):
        assert ranger_set_name(other) is None
        assert approach_model_for(other) == DEFAULT_APPROACH_MODEL
    assert approach_model_for(DEFAULT_SIREN_RANGERS) == DEFAULT_APPROACH_MODEL


def test_the_listener_reads_its_rangers_with_their_classifier() -> None:
    """``audio listen``, the closed loop and ``audio eval --approach`` build the estimator with
    :func:`default_approach`: the classifier follows the rangers the network runs with."""
    mics = reference_mics()
    for name, rangers in SIREN_RANGER_SETS.items():
        net = SirenModel(threads=1, ranger=rangers, localizer_distance=True)
        est = default_approach(net)
        assert isinstance(est, TrendApproach) and est.model == APPROACH_MODELS[name]
        heard = SirenListener(mics, 48000, model=net).approach
        assert isinstance(heard, TrendApproach) and heard.model == APPROACH_MODELS[name]
    shipped = default_approach(SirenModel(threads=1))
    assert isinstance(shipped, TrendApproach) and shipped.model == DEFAULT_APPROACH_MODEL


def test_the_two_classifiers_differ_on_the_same_rows() -> None:
    """The paired files are two trained classifiers, not one copied: on feature rows of a point
    source (slopes of ln distance from fast approach to fast recession, the level slope that goes
    with them: −8.69 dB per unit of d ln r / dt) both call a closing siren approaching and a
    receding one receding, with different probabilities."""
    prior, wide = TrendApproach(APPROACH_MODELS["prior"]), TrendApproach(APPROACH_MODELS["wide"])
    names = prior.feature_names
    assert wide.feature_names == names
    slopes = np.linspace(-0.4, 0.4, 9)  # d ln r / dt (1/s): −0.4 is 10 m/s closing at 25 m
    rows = np.zeros((len(slopes), len(names)), dtype=np.float32)
    for k in range(len(prior.horizons)):
        rows[:, 2 * k], rows[:, 2 * k + 1] = slopes, 1.0
    rows[:, names.index("level_slope_db_s")] = -DB_PER_NEPER_RANGE * slopes
    rows[:, names.index("has_level_slope")] = 1.0
    rows[:, names.index("log_distance")] = np.log(25.0)
    p, w = prior.predict_proba(rows), wide.predict_proba(rows)
    for probs in (p, w):
        assert (probs[slopes < -0.05] > 0.5).all() and (probs[slopes > 0.05] < 0.5).all()
    assert not np.allclose(p, w, atol=1e-3)
