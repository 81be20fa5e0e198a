"""Frames the image stage's tests share: grey discs on a noisy background, and their fragments grouped."""

from __future__ import annotations

import cv2
import numpy as np

from spotnav.image.fragments import group_fragments
from spotnav.image.spots import SpotDetection, detect_spots_otsu


def disc_image(centers: list[tuple[int, int]], radius: int = 40, size: int = 400, seed: int = 0) -> np.ndarray:
    """An 8-bit RGB frame ``size`` px square: noise about grey 15, with a disc of grey 200 at each of ``centers``."""
    rng = np.random.default_rng(seed)
    image = rng.normal(15, 2, (size, size)).clip(0, 255).astype(np.uint8)
    for center in centers:
        cv2.circle(image, center, radius, 200, -1)
    return np.dstack([image] * 3)


def fragments_of(image: np.ndarray, gap_px: float = 12.0, whole_area_px: float = 1500.0) -> SpotDetection:
    """The regions of ``image`` (down to 0.5 % of the largest) grouped into spots (:func:`group_fragments`)."""
    return group_fragments(detect_spots_otsu(image, min_area_fraction=0.005), image.shape[:2], gap_px, whole_area_px)
