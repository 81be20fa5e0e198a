from __future__ import annotations

import cv2
import numpy as np
import pytest

from spotnav.detect import detect_spots_otsu, to_gray8


def disc_image(centers: list[tuple[int, int]], radius: int = 40, size: int = 400, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    image = rng.normal(15, 2, (size, size)).clip(0, 255).astype(np.uint8)
    for center in centers:
        cv2.circle(image, center, radius, 200, -1)
    return np.dstack([image] * 3)


def test_one_disc_gives_one_round_contour() -> None:
    detection = detect_spots_otsu(disc_image([(200, 180)]))
    assert len(detection.spots) == 1
    spot = detection.spots[0]
    assert not spot.touches_border
    distances = np.hypot(spot.contour_px[:, 0] - 200, spot.contour_px[:, 1] - 180)
    assert distances.mean() == pytest.approx(40, abs=1.0)
    assert detection.contrast > 100


def test_noise_alone_is_no_spot() -> None:
    assert detect_spots_otsu(disc_image([])).spots == ()


def test_two_discs_are_two_spots_largest_first() -> None:
    image = disc_image([(100, 100)], radius=30)
    cv2.circle(image, (300, 300), 45, (200, 200, 200), -1)
    spots = detect_spots_otsu(image).spots
    assert len(spots) == 2
    assert spots[0].area_px > spots[1].area_px


def test_cut_spot_touches_the_border() -> None:
    assert detect_spots_otsu(disc_image([(390, 200)])).spots[0].touches_border


def test_bit_depths_and_channels_agree() -> None:
    rgb = disc_image([(200, 200)])
    reference = detect_spots_otsu(rgb).spots[0].contour_px
    grey = rgb[..., 0]
    sixteen = grey.astype(np.uint16) * 257
    rgba = np.dstack([rgb, np.full(grey.shape, 255, np.uint8)])
    for variant in (grey, sixteen, rgba):
        np.testing.assert_array_equal(detect_spots_otsu(variant).spots[0].contour_px, reference)


def test_to_gray8_rejects_other_types() -> None:
    with pytest.raises(ValueError, match="8-bit or 16-bit"):
        to_gray8(np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match="grey, RGB or RGBA"):
        to_gray8(np.zeros((4, 4, 2), np.uint8))
