from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from spotnav.optics.camera import (
    CHANGE_SIZE,
    camera_model,
    perturbed_model,
    pixel_rays,
    project_points,
    sphere_point_rates,
    sphere_points,
    unproject_pixels_to_plane,
    unproject_pixels_to_sphere,
)
from spotnav.optics.occlusion import pixels_behind_segment
from spotnav.optics.response import decode_values, decoding_table, encode_light
from spotnav.setup.microscope import Camera

CAMERA = Camera()  # the thesis's: 5000 px, 36 mm sensor, 300 mm lens, 110 mm


def test_contract_example_pixel() -> None:
    # The spot of a beam at (3, 3, 5) straight down on the plane z = 0 (thesis Table 6.1).
    u, v = project_points(CAMERA, np.array([3.0, 3.0, 0.0]))
    assert u == pytest.approx(3636.8, abs=1.0)
    assert v == pytest.approx(1363.2, abs=0.1)


def test_pixel_scale_of_thesis_setup() -> None:
    # thesis-notes 3: 378.8 px per mm at the pole.
    u0, _ = project_points(CAMERA, np.array([0.0, 0.0, 0.0]))
    u1, _ = project_points(CAMERA, np.array([1.0, 0.0, 0.0]))
    assert u1 - u0 == pytest.approx(378.79, abs=0.01)
    assert u0 == pytest.approx(2499.5)


def test_image_axes_follow_the_contract() -> None:
    (u, v) = project_points(CAMERA, np.array([1.0, 1.0, 0.0]))
    assert u > 2499.5  # u grows with +x
    assert v < 2499.5  # v grows with -y


def test_principal_ray_hits_the_pole() -> None:
    center = np.array(CAMERA.principal_point_px)
    point = unproject_pixels_to_sphere(CAMERA, center, 12.5)
    np.testing.assert_allclose(point, [0.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(pixel_rays(CAMERA, center), [0.0, 0.0, -1.0])


@given(x=st.floats(-6.0, 6.0), y=st.floats(-6.0, 6.0), radius=st.floats(10.0, 15.0))
def test_unproject_inverts_project_on_the_bowl(x: float, y: float, radius: float) -> None:
    point = np.array([x, y, radius - np.sqrt(radius**2 - x**2 - y**2)])
    pixel = project_points(CAMERA, point)
    back = unproject_pixels_to_sphere(CAMERA, pixel, radius)
    np.testing.assert_allclose(back, point, atol=1e-9)


def test_vectorised_shapes() -> None:
    pixels = np.zeros((4, 5, 2)) + 2000.0
    assert pixel_rays(CAMERA, pixels).shape == (4, 5, 3)
    assert unproject_pixels_to_sphere(CAMERA, pixels, 12.5).shape == (4, 5, 3)
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        pixel_rays(CAMERA, np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        project_points(CAMERA, np.zeros(2))


def test_rays_off_the_bowl_are_nan() -> None:
    wide = Camera(width_px=100, height_px=100, sensor_width_mm=36.0, focal_length_mm=10.0, distance_mm=30.0)
    corner = unproject_pixels_to_sphere(wide, np.array([0.0, 0.0]), 12.5)
    assert np.all(np.isnan(corner))


@given(x=st.floats(-6, 6), y=st.floats(-6, 6), height=st.floats(-3, 3))
def test_unproject_to_plane_inverts_project(x: float, y: float, height: float) -> None:
    camera = Camera()
    point = np.array([x, y, height])
    back = unproject_pixels_to_plane(camera, project_points(camera, point), height)
    np.testing.assert_allclose(back, point, atol=1e-9)


def test_plane_above_the_camera_is_rejected() -> None:
    with pytest.raises(ValueError, match="below the camera"):
        unproject_pixels_to_plane(Camera(), np.zeros(2), 200.0)


@given(
    start=st.tuples(st.floats(-4, 4), st.floats(-4, 4), st.floats(1, 8)),
    end=st.tuples(st.floats(-8, 8), st.floats(-8, 8), st.floats(1, 24)),
    pixel=st.tuples(st.floats(1500, 3500), st.floats(1500, 3500)),
    radius=st.floats(0.05, 1.0),
)
def test_pixels_behind_segment_agree_with_a_sampled_distance(
    start: tuple[float, float, float], end: tuple[float, float, float], pixel: tuple[float, float], radius: float
) -> None:
    # Distance from the pixel's ray to 4001 points along the segment: the closest one decides.
    ray = pixel_rays(CAMERA, np.array(pixel))
    samples = np.linspace(start, end, 4001)
    offsets = samples - CAMERA.center_in_eye
    distances = np.sqrt(np.maximum(np.sum(offsets**2, axis=1) - (offsets @ ray) ** 2, 0.0))
    spacing = np.linalg.norm(np.subtract(end, start)) / 4000
    if abs(distances.min() - radius) > spacing + 1e-6:  # not within sampling of the cylinder's surface
        assert pixels_behind_segment(CAMERA, np.array(pixel), start, end, radius) == (distances.min() < radius)


def test_a_segment_hides_the_pixels_of_its_own_points() -> None:
    start, end = np.array([1.0, -0.5, 4.0]), np.array([0.0, 6.0, 20.0])
    on_it = project_points(CAMERA, np.linspace(start, end, 7))
    assert pixels_behind_segment(CAMERA, on_it, start, end, 0.3).all()
    beside = project_points(CAMERA, np.linspace(start, end, 7) + np.array([1.0, 0.0, 0.0]))
    assert not pixels_behind_segment(CAMERA, beside, start, end, 0.3).any()


def _calibrated(distortion: list[float], rotation_deg: tuple[float, float, float], shift: tuple) -> Camera:
    import cv2

    matrix = np.array([[8000.0, 0.0, 500.0], [0.0, 8100.0, 520.0], [0.0, 0.0, 1.0]])
    turn, _ = cv2.Rodrigues(np.radians(np.array(rotation_deg)))
    rotation = np.diag([1.0, -1.0, -1.0]) @ turn
    centre = np.array([0.0, 0.0, 110.0]) + np.array(shift)
    return Camera.calibrated(1024, 1024, matrix, distortion, rotation, -rotation @ centre)


@given(
    count=st.sampled_from([4, 5, 8, 12, 14]),
    seed=st.integers(0, 2**16),
    rotation=st.tuples(*[st.floats(-1.0, 1.0)] * 3),
    shift=st.tuples(*[st.floats(-1.0, 1.0)] * 3),
)
def test_projection_is_opencvs(count: int, seed: int, rotation: tuple, shift: tuple) -> None:
    # Any of OpenCV's distortion models (the tilted sensor too), any pose: cv2.projectPoints' pixels, and
    # the rays back through them point at the points.
    import cv2

    rng = np.random.default_rng(seed)
    distortion = rng.normal(0.0, 0.05, count)
    distortion[0] = rng.uniform(-4.0, 4.0)
    if count == 14:
        distortion[12:] = rng.uniform(-0.02, 0.02, 2)
    camera = _calibrated(list(distortion), rotation, shift)
    points = rng.uniform([-4, -4, 0], [4, 4, 6], (50, 3))
    # In the camera's frame (cv2.Rodrigues loses digits near the half turn of R = diag(1, -1, -1)).
    in_camera = points @ camera.rotation_to_camera.T + camera.translation_to_camera_mm
    expected, _ = cv2.projectPoints(
        in_camera, np.zeros(3), np.zeros(3), camera.matrix_px, camera.distortion_coefficients[:count]
    )
    pixels = project_points(camera, points)
    np.testing.assert_allclose(pixels, expected.reshape(-1, 2), atol=1e-6)
    towards = points - camera.center_in_eye
    rays = towards / np.linalg.norm(towards, axis=1)[:, None]
    np.testing.assert_allclose(pixel_rays(camera, pixels), rays, atol=1e-9)


@given(
    seed=st.integers(0, 2**16),
    rotation=st.tuples(*[st.floats(-1.0, 1.0)] * 3),
    tilted=st.booleans(),
)
def test_sphere_point_rates_are_the_points_derivatives(seed: int, rotation: tuple, tilted: bool) -> None:
    # A distorted camera (a tilted sensor or not), turned and moved from its start by a random change: the points'
    # derivatives with respect to the eye's radius and each of the change's values agree with central differences
    # of the points (extrapolated, Richardson's), to 1e-6 of each column's largest and the reference's rounding:
    # the undistortion stops within 1e-14 of the normalized plane (1.1e-12 mm at 110 mm), which the step divides.
    rng = np.random.default_rng(seed)
    distortion = list(rng.normal(0.0, 0.05, 14 if tilted else 5))
    distortion[0] = rng.uniform(-4.0, 4.0)
    if tilted:
        distortion[12:] = rng.uniform(-0.02, 0.02, 2)
    model = camera_model(_calibrated(distortion, rotation, (0.3, -0.2, 0.5)))
    # The change's scales: radians, mm, a relative focal length, pixels, then k1, k2, p1, p2, k3.
    scales = np.array([1e-2] * 3 + [0.3] * 3 + [3e-3, 1.0, 1.0, 0.3, 0.1, 1e-3, 1e-3, 0.1])
    change = rng.normal(0.0, 1.0, CHANGE_SIZE) * scales
    pixels = rng.uniform(300.0, 700.0, (40, 2))
    radius = 12.0
    rates = sphere_point_rates(model, change, pixels, radius)
    on_bowl = np.all(np.isfinite(sphere_points(perturbed_model(model, change), pixels, radius)), axis=1)
    assert on_bowl.sum() > 20
    steps = np.concatenate([[1e-3], 1e-3 * scales])

    def moved(k: int, by: float) -> np.ndarray:
        changed = change.copy()
        if k > 0:
            changed[k - 1] += by
        return sphere_points(perturbed_model(model, changed), pixels, radius + (by if k == 0 else 0.0))

    for k, step in enumerate(steps):
        wide = (moved(k, step) - moved(k, -step)) / (2 * step)
        narrow = (moved(k, step / 2) - moved(k, -step / 2)) / step
        numeric = ((4 * narrow - wide) / 3)[on_bowl]
        rounding = 3 * 1.1e-12 / step
        np.testing.assert_allclose(rates[on_bowl, :, k], numeric, atol=1e-6 * np.abs(numeric).max() + rounding)
    assert np.all(rates[~on_bowl] == 0.0)


def test_the_ideal_camera_is_the_calibrated_special_case() -> None:
    # The contract: matrix [[f, 0, c], [0, f, c], [0, 0, 1]], no distortion, R = diag(1, -1, -1), t = (0, 0, d).
    ideal = Camera(width_px=1024, height_px=1024)
    calibrated = ideal.as_calibrated()
    np.testing.assert_allclose(calibrated.matrix_px, [[8533.333333, 0, 511.5], [0, 8533.333333, 511.5], [0, 0, 1]])
    assert calibrated.rotation == ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0))
    assert calibrated.translation_mm == (0.0, 0.0, 110.0)
    points = np.random.default_rng(0).uniform([-3, -3, 0], [3, 3, 6], (20, 3))
    np.testing.assert_allclose(project_points(calibrated, points), project_points(ideal, points), atol=1e-9)
    pixels = project_points(ideal, points)
    np.testing.assert_allclose(
        unproject_pixels_to_sphere(calibrated, pixels, 12.5), unproject_pixels_to_sphere(ideal, pixels, 12.5)
    )


def test_a_resized_camera_sees_the_same_field() -> None:
    camera = _calibrated([-3.0, 0.0, 0.0, 0.0, 0.0], (0.2, -0.1, 0.3), (0.1, 0.2, 0.3))
    half = camera.resized(512, 512)
    points = np.random.default_rng(1).uniform([-3, -3, 0], [3, 3, 6], (20, 3))
    np.testing.assert_allclose((project_points(half, points) + 0.5) * 2, project_points(camera, points) + 0.5)


@given(
    light=st.floats(1e-3, 0.99),
    response=st.sampled_from(["srgb", "linear", "agx", 0.45, 1.8, 2.6]),
)
def test_decoding_inverts_encoding(light: float, response: str | float) -> None:
    # Every response of the contract ("The frames' encoding") round-trips light, and increases with it.
    value = encode_light(np.array([light, light * 1.01]), response)
    assert value[1] > value[0]
    assert decode_values(value[:1], response)[0] == pytest.approx(light, rel=1e-3)


@pytest.mark.parametrize("response", ["srgb", "linear", "agx", 2.2])
def test_decoding_tables_are_monotonic_from_black_to_full_scale(response: str | float) -> None:
    for bits in (8, 16):
        table = decoding_table(response, bits)
        assert table.shape == (2**bits,) and table[0] == pytest.approx(0.0, abs=1e-4) and table[-1] == 1.0
        assert np.all(np.diff(table) >= 0)
