"""Augmentation of (image, light boxes): the boxes follow a drawn lamp through every transform."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from makeway.train.light_augment import (
    AugmentConfig,
    affine,
    augment,
    default_fisheye_k,
    fisheye,
    perspective,
    photometric,
)


def _scene(centre: tuple[int, int], radius: int = 7) -> tuple[np.ndarray, np.ndarray]:
    img = np.full((240, 320, 3), 40, np.uint8)
    x, y = centre
    # a blue lamp (a lit rectangle, so its box is exactly its outline) on a dark background
    cv2.rectangle(img, (x - radius, y - radius), (x + radius, y + radius), (255, 120, 0), -1)
    return img, np.array([[x - radius, y - radius, x + radius + 1, y + radius + 1]], np.float64)


def _lamp_box(img: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(img[..., 0] > 150)
    return np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], np.float64)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    iw = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    ih = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = iw * ih
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


@pytest.mark.parametrize("transform", [fisheye, affine, perspective])
@pytest.mark.parametrize("centre", [(160, 120), (270, 40), (40, 200)])
def test_boxes_follow_a_drawn_lamp(transform, centre) -> None:  # type: ignore[no-untyped-def]
    for seed in range(4):
        img, boxes = _scene(centre)
        out, new, keep = transform(img, boxes, np.random.default_rng(seed))
        assert out.shape == img.shape and out.dtype == np.uint8
        if not keep[0]:  # pushed out of the image: then the lamp must be (mostly) gone too
            assert (out[..., 0] > 150).sum() < 0.5 * (img[..., 0] > 150).sum()
            continue
        assert _iou(new[0], _lamp_box(out)) > 0.7, (transform.__name__, seed, new[0], _lamp_box(out))


def test_fisheye_uses_the_rig_lens_jittered_under_ten_percent() -> None:
    assert default_fisheye_k() == pytest.approx((0.062, -0.011, 0.004, -0.0009))
    img, boxes = _scene((160, 120))
    with pytest.raises(ValueError, match="jitter"):
        fisheye(img, boxes, np.random.default_rng(0), jitter=0.1)
    # filling the width with a barrel-distorted view magnifies the middle: a central lamp stays
    # centred and grows
    _out, new, _ = fisheye(img, boxes, np.random.default_rng(0), jitter=0.0)
    assert abs((new[0, 0] + new[0, 2]) / 2 - 160.5) < 1.5
    assert new[0, 2] - new[0, 0] > boxes[0, 2] - boxes[0, 0]


def test_photometric_keeps_shape_and_range_and_augment_keeps_attributes_aligned() -> None:
    img, boxes = _scene((160, 120))
    out = photometric(img, np.random.default_rng(1))
    assert out.shape == img.shape and out.dtype == np.uint8
    two = np.vstack([boxes, [[0, 0, 10, 10]]])
    rng = np.random.default_rng(3)
    for _ in range(10):
        _o, b, keep = augment(img, two, rng, AugmentConfig(p_photometric=0.0))
        assert len(b) == keep.sum()


def test_bad_images_are_refused_with_a_clear_error() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="uint8 BGR"):
        affine(np.zeros((10, 10), np.uint8), np.zeros((0, 4)), rng)
    with pytest.raises(ValueError, match="uint8 BGR"):
        perspective(np.zeros((10, 10, 3), np.float32), np.zeros((0, 4)), rng)
    with pytest.raises(ValueError, match=r"\(n, 4\)"):
        affine(np.zeros((10, 10, 3), np.uint8), np.zeros((2, 3)), rng)


def test_night_darkens_mid_tones_keeps_lamps_and_swap_turns_red_lamps_blue() -> None:
    from makeway.train.light_augment import night, swap_red_blue

    img, _ = _scene((160, 120))
    cv2.rectangle(img, (10, 10), (20, 20), (255, 255, 255), -1)  # a clipped lamp core
    img[100:110, 10:20] = (30, 30, 200)  # a red lamp
    dark = night(img, np.random.default_rng(0))
    assert dark[50, 50, 0] < img[50, 50, 0] and (dark[15, 15] == 255).all()
    swapped = swap_red_blue(img)
    assert tuple(swapped[105, 15]) == (200, 30, 30)  # now blue in BGR
    assert tuple(swapped[120, 160]) == tuple(img[120, 160][::-1])


def test_night_lamps_darkens_the_scene_but_keeps_the_labelled_lamp() -> None:
    from makeway.train.light_augment import night_lamps

    img, boxes = _scene((160, 120))
    img[:, :] = np.clip(img.astype(np.int16) + 100, 0, 255).astype(np.uint8)  # a daytime grey scene
    cv2.rectangle(img, (153, 113), (167, 127), (255, 120, 0), -1)  # the lamp (box `boxes`)
    for seed in range(5):
        out = night_lamps(img, boxes, np.random.default_rng(seed))
        assert out.shape == img.shape and out.dtype == np.uint8
        assert out[20:60, 20:60].mean() < 0.65 * img[20:60, 20:60].mean()  # the scene went dark
        x1, y1, x2, y2 = boxes[0].astype(int)
        assert out[y1:y2, x1:x2, 0].mean() >= 0.95 * img[y1:y2, x1:x2, 0].mean()  # the lamp did not
        assert _lamp_box(out)[0] <= x1 + 1 and _lamp_box(out)[2] >= x2 - 1


def test_paste_lamps_copies_real_patches_with_their_boxes() -> None:
    from makeway.train.light_augment import lamp_patches, paste_lamps

    src, src_boxes = _scene((100, 100), radius=5)
    patches = lamp_patches([src], [src_boxes])
    assert len(patches) == 1
    patch, pbox = patches[0]
    assert patch.shape[0] > pbox[3] - pbox[1] and patch.shape[1] > pbox[2] - pbox[0]  # the halo
    dst = np.full((200, 200, 3), 30, np.uint8)
    rng = np.random.default_rng(1)
    for _ in range(10):
        out, boxes = paste_lamps(dst, np.zeros((0, 4)), patches, rng, count=(1, 1))
        assert boxes.shape == (1, 4)
        x1, y1, x2, y2 = boxes[0]
        assert 0 <= x1 < x2 <= 200 and 0 <= y1 < y2 <= 200
        # the pasted lamp (blue, or red when its channels were swapped) is where its box says
        cx, cy = int((x1 + x2) / 2), int((y1 + y2) / 2)
        assert out[cy, cx].max() > 200 and (out >= dst).all()  # "lighten" blend never darkens
        ys, xs = np.nonzero(out.max(axis=2) > 150)
        assert _iou(np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], float), boxes[0]) > 0.5
    existing = np.array([[20.0, 20.0, 30.0, 30.0]])
    _, kept = paste_lamps(dst, existing, patches, rng, count=(2, 2))
    assert len(kept) == 3 and np.array_equal(kept[0], existing[0])
