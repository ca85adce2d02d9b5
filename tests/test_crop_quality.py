"""Image quality as a class cue, and its removal (:mod:`makeway.train.crop_quality`), on real crops."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from makeway.perceive.vision.ev_classifier import shrink_copies
from makeway.sense.crops import CropSet
from makeway.train.crop_quality import (
    QUALITY_SIDES,
    effective_side,
    match_positive_quality,
    source_of_groups,
)

SIDE = 224


def soften(image: np.ndarray, side: int) -> np.ndarray:
    """The crop as a camera ``side`` px wide would have seen it, enlarged back to its size."""
    return shrink_copies(image[None], side)[0]


@pytest.fixture(scope="module")
def crops(ev_crops: CropSet) -> tuple[np.ndarray, np.ndarray]:
    """24 EV and 24 other-vehicle web photos at 224 px (sharp close-ups)."""
    pos = np.flatnonzero(ev_crops.labels == 1)[:24]
    neg = np.flatnonzero(ev_crops.labels == 0)[:24]
    idx = np.concatenate([pos, neg])
    return ev_crops.subset(idx).load_images(SIDE, cache=False), ev_crops.labels[idx]


def test_effective_side_tells_a_softened_crop_from_a_sharp_one(crops: tuple[np.ndarray, np.ndarray]) -> None:
    images, _ = crops
    sharp = np.array([effective_side(im) for im in images])
    soft48 = np.array([effective_side(soften(im, 48)) for im in images])
    soft96 = np.array([effective_side(soften(im, 96)) for im in images])
    assert np.median(sharp) >= 160  # web close-ups hold most of their 224 px
    assert np.all(soft48 <= 64)  # nothing finer than 48 px survives, whatever the crop
    assert np.all(soft96 <= 128)
    assert np.all(soft48 <= soft96) and np.all(soft96 <= np.maximum(sharp, 128))
    # a featureless crop keeps nothing: the smallest side; the sides are tried in order
    assert effective_side(np.full((SIDE, SIDE, 3), 128, np.uint8)) == min(QUALITY_SIDES)
    assert effective_side(cv2.cvtColor(soften(images[0], 48), cv2.COLOR_BGR2GRAY)) == soft48[0]
    with pytest.raises(ValueError, match="shape"):
        effective_side(np.zeros((8, 8, 4), np.uint8))
    with pytest.raises(ValueError, match="no sides"):
        effective_side(images[0], ())


def test_positives_are_made_as_soft_as_their_sources_negatives(crops: tuple[np.ndarray, np.ndarray]) -> None:
    images, labels = crops
    # source "road": sharp EVs, other vehicles seen at 48 px (as in road footage);
    # source "web": both sharp; source "evs": positives only
    n = len(images)
    road = np.arange(n) % 2 == 0  # half of each class
    web = ~road
    x = images.copy()
    for i in np.flatnonzero(road & (labels == 0)):
        x[i] = soften(images[i], 48)
    sources = np.where(road, "road", "web").astype(object)
    out, used = match_positive_quality(x, labels, sources, seed=3)
    neg_sides = {effective_side(x[i]) for i in np.flatnonzero(road & (labels == 0))}
    road_pos = np.flatnonzero(road & (labels == 1))
    assert set(used[road_pos].tolist()) <= neg_sides and np.all(used[road_pos] > 0)
    assert all(effective_side(out[i]) <= 96 for i in road_pos)  # were 160-224 px sharp
    assert np.array_equal(out[labels == 0], x[labels == 0])  # negatives are never touched
    # in the web source negatives are sharp: a positive is softened only where a drawn side is
    # below its own, and then to exactly that side
    for i in np.flatnonzero(web & (labels == 1)):
        if used[i]:
            assert np.array_equal(out[i], soften(x[i], int(used[i])))
        else:
            assert np.array_equal(out[i], x[i])
    # the same seed gives the same result; a source without negatives is left alone
    again, used_again = match_positive_quality(x, labels, sources, seed=3)
    assert np.array_equal(again, out) and np.array_equal(used_again, used)
    only = labels == 1
    kept, none_used = match_positive_quality(x[only], labels[only], np.full(int(only.sum()), "evs"))
    assert np.array_equal(kept, x[only]) and not none_used.any()


def test_sources_from_group_names_and_bad_input(crops: tuple[np.ndarray, np.ndarray]) -> None:
    images, labels = crops
    assert source_of_groups(["ev_crops/12", "road_clips/clip/7", "loose"], 3).tolist() == [
        "ev_crops",
        "road_clips",
        "",
    ]
    assert source_of_groups(None, 2).tolist() == ["", ""]
    with pytest.raises(ValueError, match="3 crops but 2 groups"):
        source_of_groups(["a/1", "b/2"], 3)
    with pytest.raises(ValueError, match=r"images, .* labels"):
        match_positive_quality(images, labels[:-1], np.full(len(images), "a"))
    with pytest.raises(ValueError, match="0 or 1"):
        match_positive_quality(images[:2], np.array([0, 2]), np.array(["a", "a"]))
