from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav.experiments.chapter6 import thesis_world, with_true_edge
from spotnav.experiments.paths import helix_tips, poses_through_insertion
from spotnav.pixelnoise import CAMERA_NOISE_BLUR_PX, frame_blur_from_noise
from spotnav.precise import localize_precise
from spotnav.render import Renderer

_CENTRE = np.array([100.0, 100.0])


def _noisy_background(noise_dn: float, seed: int, level: float = 40.0, texture_dn: float = 0.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[:200, :200]
    texture = texture_dn * np.sin(u / 7.0) * np.cos(v / 9.0)  # smooth over a few pixels, as a fundus's
    return np.clip(np.round(level + texture + noise_dn * rng.standard_normal((200, 200))), 0, 255).astype(np.uint8)


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


@pytest.mark.parametrize(("noise_dn", "true_px"), [(2.0, 1.0), (3.0, 1.5), (6.0, 2.0)])
def test_a_blur_that_hides_the_noise_in_the_rounding_at_lag_1_is_read_at_longer_lags(
    noise_dn: float, true_px: float
) -> None:
    # Blurred this much, the noise's second differences at lag 1 are under the rounding's; lags 2 to 4 still see it.
    for seed in range(3):
        blur, sigma = _blur_of(cv2.GaussianBlur(_noisy_background(noise_dn, seed), (0, 0), true_px))
        assert abs(blur - true_px) < max(3.0 * sigma, 0.1), (seed, blur, sigma)


@pytest.mark.parametrize("texture_dn", [3.0, 10.0])
def test_smooth_texture_is_not_taken_for_a_blurred_noise(texture_dn: float) -> None:
    # Texture grows from lag to lag as the lag's fourth power: without noise it does not tell; with a little
    # noise, the noise is white.
    assert np.isnan(_blur_of(_noisy_background(0.0, 1, texture_dn=texture_dn))).all()
    blur, _ = _blur_of(_noisy_background(0.6, 1, texture_dn=texture_dn))
    assert blur == 0.0


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


def test_a_ring_whose_lag_two_noise_is_the_rounding_alone_is_read_by_the_longest_lags() -> None:
    # A 2 px blur of the encoded frame (1024 px, the helix's 9th of 25 tips, the fault study's seed) leaves the
    # noise at lag 2 exactly the rounding's: its ratio divided by zero, and the frame raised ZeroDivisionError.
    world = thesis_world(1024, 1)
    world = replace(world, faults=replace(world.faults, frame_blur_px=2.0))
    pose = poses_through_insertion(helix_tips(25)[8:9], world.instrument.insertion_in_eye)[0]
    estimate = localize_precise(Renderer(world).render(pose, seed=24008), with_true_edge(world))
    assert estimate.status in ("ok", "blurred")
    if estimate.ok:
        assert np.linalg.norm(estimate.tip_in_eye - pose.tip_in_eye) < 0.030
