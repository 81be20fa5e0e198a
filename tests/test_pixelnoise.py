from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav.pixelnoise import CAMERA_NOISE_BLUR_PX, frame_blur_from_noise

_CENTRE = np.array([100.0, 100.0])


def _noisy_background(noise_dn: float, seed: int, level: float = 40.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(np.round(level + noise_dn * rng.standard_normal((200, 200))), 0, 255).astype(np.uint8)


def _blur_of(codes: np.ndarray) -> tuple[float, float]:
    return frame_blur_from_noise(codes, _CENTRE, 40.0, 60.0, 255)


@given(seed=st.integers(0, 2**16), noise_dn=st.floats(1.5, 8.0))
@settings(max_examples=20, deadline=None)
def test_white_noise_shows_no_blur(seed: int, noise_dn: float) -> None:
    blur, sigma = _blur_of(_noisy_background(noise_dn, seed))
    assert 0.0 <= blur < 0.35 and blur < 3.0 * sigma + 0.1


@pytest.mark.parametrize("true_px", [0.8, 1.0, 1.2])
def test_the_blur_of_an_encoded_frame_is_read_from_its_noise(true_px: float) -> None:
    # OpenCV's Gaussian on the 8-bit codes, as a codec or a camera's smoothing would: found within 0.1 px and
    # within 3 of its sigmas.
    blurred = cv2.GaussianBlur(_noisy_background(6.0, 7), (0, 0), true_px)
    blur, sigma = _blur_of(blurred)
    assert blur == pytest.approx(true_px, abs=0.1)
    assert abs(blur - true_px) < 3.0 * sigma + 0.02


def test_noise_no_more_correlated_than_a_camera_s_own_shows_no_blur_of_the_frame() -> None:
    # A half-pixel correlation is what a render's pixel filter or a sensor's demosaicing gives, in light.
    blur, sigma = _blur_of(cv2.GaussianBlur(_noisy_background(4.0, 7), (0, 0), 0.5))
    assert blur == 0.0 and CAMERA_NOISE_BLUR_PX > sigma > 0.4


def test_a_frame_with_no_noise_beyond_the_rounding_does_not_tell() -> None:
    # A smooth ramp, rounded: only the rounding is left, and it cannot say whether the frame was blurred.
    ramp = np.round(np.linspace(20.0, 60.0, 200))[None, :].repeat(200, axis=0).astype(np.uint8)
    assert np.isnan(_blur_of(ramp)).all()
    assert np.isnan(_blur_of(cv2.GaussianBlur(_noisy_background(2.0, 3), (0, 0), 2.0))).all()


def test_other_light_and_clipped_pixels_are_not_noise() -> None:
    # Another spot's bright plateau (over the ceiling) and a clipped or black region in the ring are left out.
    codes = _noisy_background(3.0, 5)
    codes[:, 150:] = 250
    codes[:30] = 0
    blur, _ = frame_blur_from_noise(codes, _CENTRE, 40.0, 60.0, 200)
    assert 0.0 <= blur < 0.35


def test_a_ring_off_the_frame_does_not_tell() -> None:
    assert np.isnan(frame_blur_from_noise(_noisy_background(3.0, 1), np.array([900.0, 900.0]), 10.0, 20.0, 255)).all()
