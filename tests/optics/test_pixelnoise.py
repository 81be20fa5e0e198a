from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav.experiments.scenes import thesis_world, with_true_edge
from spotnav.optics.pixelnoise import (
    CAMERA_NOISE_BLUR_PX,
    _ring_variances,
    advance_noise_pool,
    discard_noise_reading,
    frame_blur_from_noise,
    new_noise_pool,
    pooled_frame_blur,
)
from spotnav.optics.render import Renderer
from spotnav.pose.precise import localize_precise
from spotnav.setup.paths import helix_tips, poses_through_insertion

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


def test_an_uncertain_blur_is_read_in_every_channel_that_agrees() -> None:
    # A 2 px blur of the encoded frame on a dark fundus (1024 px, the light study's helix, 3rd of 16 tips, its seed):
    # the spot's channel alone told 2.5 +- 0.6 px, and the edge was refused `blurred` (0.38 px of shift uncertain);
    # with the other channels that agree, the frame is answered within 3 sigma.
    world = thesis_world(1024, 1)
    world = replace(world, faults=replace(world.faults, frame_blur_px=2.0))
    pose = poses_through_insertion(helix_tips(16)[2:3], world.instrument.insertion_in_eye)[0]
    estimate = localize_precise(Renderer(world).render(pose, seed=7002), with_true_edge(world))
    assert estimate.ok, estimate.detail
    assert np.linalg.norm(estimate.tip_in_eye - pose.tip_in_eye) < 3.0 * estimate.sigma_mm


def _pooled_blur(frames: list[np.ndarray], pool: np.ndarray, inner: float = 40.0) -> tuple[float, float]:
    for codes in frames:
        advance_noise_pool(pool)
        blur, sigma = pooled_frame_blur(codes, 0, _CENTRE, inner, inner + 20.0, 255, pool)
    return blur, sigma


def test_a_pool_of_one_frame_reads_the_ring_whole() -> None:
    codes = cv2.GaussianBlur(_noisy_background(6.0, 3), (0, 0), 1.0)
    assert _pooled_blur([codes], new_noise_pool(1)) == _blur_of(codes)
    assert _pooled_blur([codes], new_noise_pool()) == _blur_of(codes)  # a stream's first frame, alone


@pytest.mark.parametrize("inner", [25.0, 40.0])
def test_four_frames_read_a_quarter_each_of_what_one_frame_reads(inner: float) -> None:
    # The same frame four times: the quarters tile the whole reading, so the pool holds the same differences and
    # gives the same variances (to rounding) and the same blur.
    codes = cv2.GaussianBlur(_noisy_background(6.0, 5), (0, 0), 1.2)
    pool = new_noise_pool()
    blur, sigma = _pooled_blur([codes] * 5, pool, inner)
    whole, count = _ring_variances(codes, _CENTRE, inner, inner + 20.0, 255, 1024, 5)
    assert pool[0, :, 0].tolist() == [4.0, 3.0, 2.0, 1.0]  # the quarters, the newest first (the whole one left)
    assert pool[0, :, 1].sum() == count
    pooled = (pool[0, :, 1] @ pool[0, :, 2:]) / count
    np.testing.assert_allclose(pooled, whole, rtol=0.02)  # each quarter trims its own outliers
    assert (blur, sigma) == pytest.approx(frame_blur_from_noise(codes, _CENTRE, inner, inner + 20.0, 255), rel=0.05)


@pytest.mark.parametrize("true_px", [0.0, 1.0, 1.5])
def test_a_stream_tells_its_blur_from_a_quarter_of_each_frame_ring(true_px: float) -> None:
    # Ten frames of a stream, blurred alike after their encoding: the last four's quarters tell the blur within
    # 0.1 px and 3 sigmas, with a sigma within 1.2 times one frame's whole ring.
    frames = [_noisy_background(6.0, seed) for seed in range(10)]
    if true_px > 0.0:
        frames = [cv2.GaussianBlur(codes, (0, 0), true_px) for codes in frames]
    blur, sigma = _pooled_blur(frames, new_noise_pool())
    whole_sigma = _blur_of(frames[-1])[1]
    assert abs(blur - true_px) < max(3.0 * sigma, 0.1)
    assert sigma < 1.2 * whole_sigma


def test_reading_a_frame_again_replaces_its_share_of_the_pool() -> None:
    frames = [_noisy_background(6.0, seed) for seed in range(6)]
    pool = new_noise_pool()
    _pooled_blur(frames, pool)
    once = pool.copy()
    again = pooled_frame_blur(frames[-1], 0, _CENTRE, 40.0, 60.0, 255, pool)
    np.testing.assert_array_equal(pool, once)
    discard_noise_reading(pool)  # a reading left out: the next frame reads the quarter after the one before it
    assert pool[0, 0].tolist() == [0.0] * 6
    advance_noise_pool(pool)
    pooled_frame_blur(frames[0], 0, _CENTRE, 40.0, 60.0, 255, pool)
    assert pool[0, 0, 0] == once[0, 1, 0] % 4 + 1
    assert again == pooled_frame_blur(frames[-1], 0, _CENTRE, 40.0, 60.0, 255, once)


def test_a_noise_pool_has_one_or_four_frames() -> None:
    for frames in (0, 2, 8):
        with pytest.raises(ValueError, match="frames must be 1 or 4"):
            new_noise_pool(frames)
