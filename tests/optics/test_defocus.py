"""The lens's depth of field: the thin lens's blur, and a blur that varies over the frame."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from spotnav.optics.defocus import light_blur_px, spot_light_blur_px, varying_blur
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose


def test_a_point_s_blur_is_the_thin_lens_s_disk() -> None:
    camera = replace(Setup().camera, width_px=1000, height_px=1000, aperture_mm=10.0)  # f = 300 * 1000 / 36 px
    focal = 300.0 * 1000 / 36.0
    pole, deeper = np.zeros(3), np.array([0.0, 0.0, -0.5])  # depth 110 and 110.5 mm
    assert light_blur_px(camera, pole) == pytest.approx(0.0, abs=1e-12)  # on the focal plane
    expected = 10.0 * focal * (1 / 110.0 - 1 / 110.5) / 4.0  # the disk's diameter, a quarter of it as sigma
    assert light_blur_px(camera, deeper) == pytest.approx(expected, rel=1e-9)
    assert light_blur_px(camera, deeper, 5.0) == pytest.approx(expected / 2.0, rel=1e-9)
    assert light_blur_px(replace(camera, aperture_mm=None), deeper) == 0.0  # unstated: a pinhole
    focused = replace(camera, focus_distance_mm=110.5)
    assert light_blur_px(focused, deeper) == pytest.approx(0.0, abs=1e-12)
    assert light_blur_px(focused, pole) == pytest.approx(expected, rel=1e-9)


def test_a_spot_s_blur_is_its_axis_s_point_on_the_retina() -> None:
    setup = replace(Setup(), camera=replace(Setup().camera, aperture_mm=20.0))
    pose = InstrumentPose.through_insertion(np.array([3.0, 0.0, 4.0]), setup.instrument.insertion_in_eye)
    blur = spot_light_blur_px(setup, pose.tip_in_eye, pose.axis)
    hit = pose.tip_in_eye + pose.axis * np.linspace(0.0, 30.0, 300001)[:, None]
    on_retina = hit[np.argmin(np.abs(np.linalg.norm(hit - setup.eye.center_in_eye, axis=1) - setup.eye.radius_mm))]
    assert blur == pytest.approx(float(light_blur_px(setup.camera, on_retina)), rel=1e-3)
    assert blur > 0.0 and spot_light_blur_px(Setup(), pose.tip_in_eye, pose.axis) == 0.0


def test_a_varying_blur_is_each_pixel_s_own_gaussian() -> None:
    rng = np.random.default_rng(3)
    image = np.zeros((80, 80, 3), np.float32)
    image[30:50, 30:50] = rng.uniform(0.5, 1.0, (20, 20, 3))
    for sigma in (0.5, 1.25):  # on the grid of blurs: exactly that blur
        even = varying_blur(image, np.full((80, 80), sigma))
        assert np.allclose(even, cv2.GaussianBlur(image, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT), atol=1e-6)
    # Between two blurs of the grid: a mixture with its own variance (an edge's second moment).
    step = np.zeros((1, 200, 3), np.float32)
    step[:, 100:] = 1.0
    slope = np.diff(varying_blur(np.repeat(step, 40, axis=0), np.full((40, 200), 0.6))[20, 80:121, 0])
    x = np.arange(len(slope)) - 19.0  # the step lies between pixels 99 and 100 (the image's border far off)
    spread = np.sqrt(np.sum(slope * x**2) / np.sum(slope))
    assert spread == pytest.approx(0.6, abs=0.05)
    assert np.array_equal(varying_blur(image, np.zeros((80, 80))), image)
