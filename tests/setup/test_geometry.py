from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav.setup.geometry import (
    InstrumentPose,
    angles_between,
    approximation_deviation,
    assign_beams,
    axis_rotations,
    beam_axes,
    cone_generators,
    cone_sphere_curve,
    edge_angle_of_blend,
    intersect_rays_sphere,
    normalize,
    orthonormal_basis,
    rotation_about_y,
    rotation_about_z,
    spot_attenuation,
)

THESIS_TABLE_4_1 = {5: 0.08, 7: 0.23, 9: 0.49, 11: 0.91, 13: 1.51, 15: 2.34}

unit_vectors = (
    st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1))
    .filter(lambda v: np.linalg.norm(v) > 0.1)
    .map(lambda v: normalize(np.array(v)))
)


@pytest.mark.parametrize(("beta", "thesis_um"), THESIS_TABLE_4_1.items())
def test_table_4_1_matches_the_printed_digits(beta: int, thesis_um: float) -> None:
    deviation = approximation_deviation(np.radians(beta))
    assert round(deviation.gap_y_um, 2) == thesis_um


def test_full_3d_deviation_is_about_3_um_at_9_deg() -> None:
    deviation = approximation_deviation(np.radians(9.0))
    assert 2.5 < deviation.to_plane_um < 3.5
    assert deviation.along_ray_um >= deviation.to_plane_um


@pytest.mark.parametrize("angle", [0.3, -1.2, 2.0])
def test_rotations_are_proper(angle: float) -> None:
    for matrix in (rotation_about_y(angle), rotation_about_z(angle)):
        np.testing.assert_allclose(matrix @ matrix.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(matrix) == pytest.approx(1.0)
    # Right-handed: +x turns toward +y about z, and +z toward +x about y.
    np.testing.assert_allclose(rotation_about_z(np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(rotation_about_y(np.pi / 2) @ [0, 0, 1], [1, 0, 0], atol=1e-12)


@given(axis=unit_vectors)
def test_orthonormal_basis_is_right_handed(axis: np.ndarray) -> None:
    e1, e2 = orthonormal_basis(axis)
    frame = np.column_stack([e1, e2, axis])
    np.testing.assert_allclose(frame.T @ frame, np.eye(3), atol=1e-9)
    assert np.linalg.det(frame) == pytest.approx(1.0)


@settings(max_examples=60)
@given(
    # Every apex in this box is inside the sphere: the corner (3, 3, 1) is 12.26 mm from the centre.
    apex=st.tuples(st.floats(-3, 3), st.floats(-3, 3), st.floats(1, 10)),
    axis=unit_vectors,
    half_angle=st.floats(0.05, 0.7),
)
def test_cone_sphere_curve_lies_on_both_surfaces(apex: tuple, axis: np.ndarray, half_angle: float) -> None:
    center, radius = np.array([0.0, 0.0, 12.5]), 12.5
    apex = np.array(apex)
    points = cone_sphere_curve(apex, axis, half_angle, center, radius, count=64)
    np.testing.assert_allclose(np.linalg.norm(points - center, axis=1), radius, rtol=1e-9)
    angles = np.arccos(np.clip(normalize(points - apex) @ axis, -1, 1))
    np.testing.assert_allclose(angles, half_angle, atol=1e-7)


@given(
    axis=unit_vectors,
    half_angle=st.floats(0.05, 0.7),
    light_radius=st.floats(0.0, 0.5),
    along=st.floats(0.5, 20.0),
    azimuth=st.floats(-np.pi, np.pi),
)
def test_a_widened_cone_is_a_cone_whose_apex_lies_behind_the_tip(
    axis: np.ndarray, half_angle: float, light_radius: float, along: float, azimuth: float
) -> None:
    # A point light_radius + along * tan(angle) from the axis is on the widened cone (the edge model of
    # spotnav.pose.conefit): at the cone's angle from an apex light_radius / tan(angle) behind the tip.
    axis = normalize(axis)
    e1, e2 = orthonormal_basis(axis)
    point = along * axis + (light_radius + along * np.tan(half_angle)) * (np.cos(azimuth) * e1 + np.sin(azimuth) * e2)
    apex = -light_radius / np.tan(half_angle) * axis
    assert angles_between(point - apex, axis) == pytest.approx(half_angle, abs=1e-9)


def test_cone_sphere_curve_rejects_apex_outside() -> None:
    with pytest.raises(ValueError, match="inside"):
        cone_sphere_curve(np.array([0.0, 5.0, 1.0]), np.array([0.0, 1.0, 0.0]), 0.25, np.array([0, 0, 12.5]), 12.5)


def test_spot_attenuation_is_cycles_smoothstep() -> None:
    beta = np.radians(9.0)
    cosines = np.cos(np.radians([0.0, 7.0, 8.9, 9.1, 20.0]))
    sharp = spot_attenuation(cosines, beta, 0.0)
    np.testing.assert_array_equal(sharp, [1, 1, 1, 0, 0])
    soft = spot_attenuation(cosines, beta, 0.15)
    assert soft[0] == 1.0 and soft[3] == 0.0 and soft[4] == 0.0
    assert 0.0 < soft[2] < soft[1] <= 1.0
    inner = np.cos(beta) + 0.15 * (1 - np.cos(beta))  # the blend starts here
    assert spot_attenuation(np.array([inner + 1e-9]), beta, 0.15)[0] == pytest.approx(1.0)


def test_edge_angle_of_blend_is_the_half_light_angle() -> None:
    beta = np.radians(9.0)
    assert edge_angle_of_blend(beta, 0.0) == pytest.approx(beta)
    for blend in (0.05, 0.15, 0.5):
        edge = edge_angle_of_blend(beta, blend)
        assert spot_attenuation(np.array([np.cos(edge)]), beta, blend)[0] == pytest.approx(0.5)
        assert edge < beta


def test_intersect_rays_sphere_misses_give_nan() -> None:
    t = intersect_rays_sphere(
        np.array([0.0, 0.0, 100.0]), np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]), np.zeros(3), 1.0
    )
    assert t[0] == pytest.approx(101.0)
    assert np.isnan(t[1])


def test_cone_generators_make_the_half_angle() -> None:
    axis = normalize(np.array([0.2, -0.3, -1.0]))
    rays = cone_generators(axis, 0.25, np.linspace(0, 6, 7))
    np.testing.assert_allclose(rays @ axis, np.cos(0.25))
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0)


@given(axis=unit_vectors, tilt=st.floats(0.01, 0.7))
def test_three_beams_follow_the_contract(axis: np.ndarray, tilt: float) -> None:
    beams = beam_axes(axis, 3, tilt)
    np.testing.assert_allclose(beams @ axis, np.cos(tilt), atol=1e-9)
    e1, _ = orthonormal_basis(axis)
    radial = beams - np.outer(beams @ axis, axis)
    radial = radial / np.linalg.norm(radial, axis=1, keepdims=True)
    np.testing.assert_allclose(radial[0], e1, atol=1e-9)  # beam 0 toward the +x projection
    for k in (1, 2):
        # Counter-clockwise seen from the tip looking along the axis: (r0 x rk) points against the axis.
        assert np.dot(np.cross(radial[0], radial[k]), axis) * (1 if k == 1 else -1) < 0
        assert np.dot(radial[0], radial[k]) == pytest.approx(-0.5, abs=1e-9)


def test_beam_0_tilts_toward_x_when_looking_down() -> None:
    beams = beam_axes(np.array([0.0, 0.0, -1.0]), 3, np.radians(15))
    assert beams[0, 0] > 0 and abs(beams[0, 1]) < 1e-12
    # Seen from above (looking down), beam 1 is 120 deg counter-clockwise from +x: +y side.
    assert beams[1, 1] > 0 and beams[2, 1] < 0


@given(axis=unit_vectors, tilt=st.floats(0.01, 0.7), rolls=st.lists(st.floats(-np.pi, np.pi), min_size=1, max_size=4))
def test_beam_axes_broadcast_axes_against_rolls(axis: np.ndarray, tilt: float, rolls: list[float]) -> None:
    one_by_one = np.stack([beam_axes(axis, 3, tilt, roll) for roll in rolls])
    np.testing.assert_array_equal(beam_axes(axis, 3, tilt, np.array(rolls)), one_by_one)
    np.testing.assert_array_equal(beam_axes(np.tile(axis, (len(rolls), 1)), 3, tilt, np.array(rolls)), one_by_one)
    np.testing.assert_array_equal(beam_axes(np.tile(axis, (2, 1)), 3, tilt, rolls[0]), np.stack([one_by_one[0]] * 2))


def test_one_beam_is_the_axis() -> None:
    axis = normalize(np.array([0.1, 0.2, -1.0]))
    np.testing.assert_allclose(beam_axes(axis, 1, 0.3), axis[None, :])


def test_pose_validation() -> None:
    pose = InstrumentPose.through_insertion([3.0, 3.0, 5.0], [0.0, 6.0, 20.0])
    np.testing.assert_allclose(pose.axis, normalize(np.array([3.0, -3.0, -15.0])))
    with pytest.raises(ValueError, match="axis"):
        InstrumentPose([0, 0, 1], [0, 0, 0])
    with pytest.raises(ValueError, match="tip"):
        InstrumentPose([0, np.nan, 1], [0, 0, -1])


@given(about_y=st.floats(0.01, 3.13), about_z=st.floats(-3.14, 3.14))
def test_axis_rotations_round_trip(about_y: float, about_z: float) -> None:
    axis = rotation_about_z(about_z) @ rotation_about_y(about_y) @ np.array([0.0, 0.0, -1.0])
    np.testing.assert_allclose(axis_rotations(axis), [about_y, about_z], atol=1e-9)


def test_angles_between() -> None:
    assert angles_between(np.array([1.0, 0, 0]), np.array([0.0, 2.0, 0])) == pytest.approx(np.pi / 2)
    assert angles_between(np.array([0.0, 0, -1]), np.array([0.0, 0, -1])) == pytest.approx(0.0, abs=1e-12)
    small = np.array([np.sin(1e-7), 0.0, -np.cos(1e-7)])
    assert angles_between(small, np.array([0.0, 0, -1])) == pytest.approx(1e-7, rel=1e-6)


@given(axis=unit_vectors, tilt=st.floats(0.05, 0.7), roll=st.floats(-np.pi, np.pi))
def test_roll_turns_the_beams_to_the_next(axis: np.ndarray, tilt: float, roll: float) -> None:
    # A roll of 120 deg puts beam 0 where beam 1 was; any roll keeps the tilt.
    turned = beam_axes(axis, 3, tilt, 2 * np.pi / 3)
    np.testing.assert_allclose(turned[0], beam_axes(axis, 3, tilt)[1], atol=1e-9)
    np.testing.assert_allclose(beam_axes(axis, 3, tilt, roll) @ axis, np.cos(tilt), atol=1e-9)


@given(axis=unit_vectors, roll=st.floats(-np.pi, np.pi), first=st.integers(0, 2), count=st.sampled_from([2, 3]))
def test_assign_beams_finds_each_beam(axis: np.ndarray, roll: float, first: int, count: int) -> None:
    # Spots listed from any beam on: the first is called beam 0 and the roll absorbs the rest.
    tilt = np.radians(15.0)
    true_axes = beam_axes(axis, 3, tilt, roll)
    order = [(first + k) % 3 for k in range(count)]
    result = assign_beams(true_axes[order], axis)
    assert result.ok
    np.testing.assert_allclose(beam_axes(axis, 3, tilt, result.roll)[list(result.beams)], true_axes[order], atol=1e-9)


def test_two_spots_of_one_beam_are_ambiguous() -> None:
    axis = np.array([0.0, 0.0, -1.0])
    same = beam_axes(axis, 3, np.radians(15.0))[[0, 0]]
    result = assign_beams(same, axis)
    assert (result.status, result.beams, np.isnan(result.roll)) == ("ambiguous", (), True)


@given(
    seed=st.integers(0, 2**31),
    shape=st.sampled_from([(3,), (1, 3), (2, 3), (40, 3), (2, 5, 3)]),
    scale=st.sampled_from([1e-150, 1e-3, 1.0, 1e3, 1e150]),
)
def test_normalize_gives_numpy_s_unit_vectors_bit_for_bit(seed: int, shape: tuple[int, ...], scale: float) -> None:
    # The compiled rows sum the squares in NumPy's order: the same bits as the array expression, in every shape.
    vectors = np.random.default_rng(seed).normal(size=shape) * scale
    expected = vectors / np.sqrt(np.sum(vectors * vectors, axis=-1, keepdims=True))
    np.testing.assert_array_equal(normalize(vectors), expected)
    assert normalize(vectors.tolist()).shape == shape


@pytest.mark.parametrize(
    "vectors", [np.zeros(3), [np.nan, 0.0, 1.0], [np.inf, 0.0, 0.0], [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]], [1e-200] * 3]
)
def test_normalize_refuses_a_zero_or_non_finite_vector(vectors: object) -> None:
    with pytest.raises(ValueError, match="zero or non-finite"):
        normalize(vectors)


@pytest.mark.parametrize("shape", [(2,), (2, 2), (4, 4), (0,)])
def test_normalize_refuses_vectors_that_are_not_3d(shape: tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        normalize(np.ones(shape))
