"""The cone-fit engine: the model's residual and Jacobian, the robust fit, its covariance, the geometry's parameters."""

from __future__ import annotations

import pickle
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from spotnav.optics.camera import camera_model, perturbed_model, project_points
from spotnav.optics.light import edge_angle
from spotnav.pose.conefit.covariance import correlation_inflation, scatter_covariance
from spotnav.pose.conefit.parameters import (
    AXIS_MODES,
    EDGE_MODEL_SIGMA,
    PARAMETER_GROUPS,
    SHARED_SIZE,
    geometry_covariance,
    geometry_values,
    prior_sigmas,
    setup_with_geometry,
)
from spotnav.pose.conefit.problem import EdgePoints, _frame_starts, _start_frames, cone_problem
from spotnav.pose.conefit.solution import _free_trace
from spotnav.pose.conefit.solvers import SOLVERS, _fit_recipe, _tip_box, fit_cones, robust_sigma
from spotnav.setup.config import CalibrationRecord, Camera, Instrument, Setup, Uncertainty
from spotnav.setup.geometry import (
    InstrumentPose,
    _axis_rotations,
    angles_between,
    beam_axes,
    cone_sphere_curve,
    edge_angle_of_blend,
    normalize,
)
from spotnav.setup.uncertainty import GEOMETRY_PARAMETERS

CENTER = np.array([0.0, 0.0, 12.5])
EXACT = Setup(camera=Camera(width_px=1024, height_px=1024), uncertainty=Uncertainty.exact())


def _tilted(setup: Setup, rotation_deg: tuple[float, float, float], distortion: tuple[float, ...]) -> Setup:
    """The setup's camera turned about its own centre and given a lens (a calibrated camera)."""
    change = np.zeros(14)
    change[:3] = np.radians(rotation_deg)
    model = perturbed_model(camera_model(setup.camera), change)
    rotation = model[18:27].reshape(3, 3)
    camera = Camera.calibrated(
        setup.camera.width_px,
        setup.camera.height_px,
        setup.camera.matrix_px,
        distortion,
        rotation,
        -rotation @ setup.camera.center_in_eye,
    )
    return replace(setup, camera=camera)


def _edges_px(setup: Setup, pose: InstrumentPose, roll: float = 0.0, count: int = 200) -> list[np.ndarray]:
    """Each beam's exact edge curve (the edge cone widened by the light's radius), projected to pixels."""
    instrument = setup.instrument
    angle = edge_angle(setup)
    axes = beam_axes(pose.axis, instrument.beam_count, instrument.beam_tilt, roll)
    behind = instrument.light_radius_mm / np.tan(angle)
    radius = setup.eye.radius_mm
    centre = np.array([0.0, 0.0, radius])
    return [
        project_points(setup.camera, cone_sphere_curve(pose.tip_in_eye - behind * a, a, angle, centre, radius, count))
        for a in axes
    ]


def _one_frame(setup: Setup, edges: list[np.ndarray], tip: np.ndarray, direction: np.ndarray, roll: float, **options):
    points = EdgePoints.of_frames([edges], [list(range(len(edges)))])
    return cone_problem(setup, points, tip[None], direction[None], np.array([roll]), **options)


def test_edge_points_number_their_spots_over_the_frames_and_refuse_frames_out_of_order() -> None:
    spots = [[np.ones((3, 2)), np.full((2, 2), 2.0)], [], [np.full((4, 2), 3.0)]]
    points = EdgePoints.of_frames(spots, [[0, 2], [], [1]], [[0.1, 0.2], [], [0.3]])
    np.testing.assert_array_equal(points.frame, [0, 0, 0, 0, 0, 2, 2, 2, 2])
    np.testing.assert_array_equal(points.beam, [0, 0, 0, 2, 2, 1, 1, 1, 1])
    np.testing.assert_array_equal(points.spot, [0, 0, 0, 1, 1, 2, 2, 2, 2])
    np.testing.assert_array_equal(points.pixels[:, 0], [1, 1, 1, 2, 2, 3, 3, 3, 3])
    np.testing.assert_array_equal(points.spot_sigma, [0.1, 0.2, 0.3])
    assert len(EdgePoints.of_frames([[]], [[]]).pixels) == 0
    with pytest.raises(ValueError, match="frame order"):
        EdgePoints(np.ones((3, 2)), [0, 1, 0], [0, 0, 0], [0, 1, 2])
    with pytest.raises(ValueError, match="numbered from 0"):
        EdgePoints(np.ones((3, 2)), [0, 0, 0], [0, 0, 0], [0, -1, 1])
    with pytest.raises(ValueError, match="at least 3"):
        EdgePoints(np.ones((3, 2)), [0, 0, 1], [0, 0, 0], [0, 1, 2], spot_sigma=[0.1, 0.2])


@given(
    seed=st.integers(0, 2**31),
    slots=st.lists(st.integers(0, 7), min_size=3, max_size=3, unique=True),
    fixed=st.lists(st.booleans(), min_size=3, max_size=3),
    reach=st.floats(0.1, 5.0),
)
def test_the_tip_box_and_trace_are_numpy_s(seed: int, slots: list[int], fixed: list[bool], reach: float) -> None:
    # The box bounds each free tip coordinate by its start +- reach and nothing else; the trace sums the free tip
    # variances in NumPy's order (the same bits as the fancy-indexed sum). A fixed coordinate's index is -1.
    rng = np.random.default_rng(seed)
    index = [-1 if known else slot for slot, known in zip(slots, fixed, strict=True)]
    frame_index = np.array([[*index, -1, -1, -1], [8, 9, 10, 11, -1, -1]], dtype=np.int64)
    start = rng.normal(size=12)
    low, high, tips = _tip_box(start, frame_index, reach)
    expected = frame_index[:, :3][frame_index[:, :3] >= 0]
    np.testing.assert_array_equal(tips, expected)
    bounded = np.isin(np.arange(12), expected)
    np.testing.assert_array_equal(low[expected], start[expected] - reach)
    np.testing.assert_array_equal(high[expected], start[expected] + reach)
    assert np.all(low[~bounded] == -np.inf) and np.all(high[~bounded] == np.inf)
    covariance = rng.normal(size=(12, 12)) * 10.0 ** rng.integers(-6, 6, size=(12, 12))
    tip = np.array(index)
    assert _free_trace(covariance, tip) == covariance[tip[tip >= 0], tip[tip >= 0]].sum()


@given(seed=st.integers(0, 2**31), count=st.integers(1, 5))
def test_the_start_frames_are_the_tips_the_axis_rotations_and_the_rolls(seed: int, count: int) -> None:
    rng = np.random.default_rng(seed)
    tips, axes, rolls = rng.normal(size=(count, 3)), normalize(rng.normal(size=(count, 3))), rng.normal(size=count)
    expected = np.empty((count, 6))
    expected[:, :3], expected[:, 3:5], expected[:, 5] = tips, _axis_rotations(axes), rolls  # the axes are unit
    np.testing.assert_array_equal(_start_frames(tips, axes, rolls), expected)


@given(frames=st.lists(st.integers(0, 6), max_size=40), count=st.integers(1, 6))
def test_the_frames_start_where_numpy_s_search_puts_them(frames: list[int], count: int) -> None:
    frame = np.sort(np.array(frames, dtype=np.int64))
    np.testing.assert_array_equal(_frame_starts(frame, count), np.searchsorted(frame, np.arange(count + 1)))


@settings(max_examples=20)
@given(
    x=st.floats(-2.5, 2.5),
    y=st.floats(-2.5, 2.5),
    z=st.floats(3, 6),
    roll=st.floats(-np.pi, np.pi),
    beams=st.sampled_from([1, 3]),
    light=st.sampled_from([0.0, 0.02, 0.1]),
    lens=st.booleans(),
)
def test_the_fit_recovers_the_pose_from_exact_curves(
    x: float, y: float, z: float, roll: float, beams: int, light: float, lens: bool
) -> None:
    # Points on the exact cone-sphere curves, seen through the ideal camera or a tilted one with a lens, a
    # start 0.1 mm off: the fit lands on the truth.
    setup = replace(EXACT, instrument=Instrument(beam_count=beams, light_radius_mm=light))
    if lens:
        setup = _tilted(setup, (0.3, -0.2, 0.4), (-3.0, 0.5, 0.001, -0.002, 0.0))
    pose = InstrumentPose.through_insertion([x, y, z], setup.instrument.insertion_in_eye)
    roll = roll if beams == 3 else 0.0
    edges = _edges_px(setup, pose, roll)
    start = pose.tip_in_eye + np.array([0.05, -0.05, 0.08])
    problem = _one_frame(setup, edges, start, pose.axis, roll + 0.05 * (beams > 1))
    fit = fit_cones(problem, contour_sigma=0.0)
    np.testing.assert_allclose(fit.tip(), pose.tip_in_eye, atol=1e-6)
    np.testing.assert_allclose(fit.axis(), pose.axis, atol=1e-6)
    assert fit.inliers.all()
    # The solution's arrays are its own and read-only: the kept insertion point, the recipe's answer.
    np.testing.assert_array_equal(fit.insertion_in_eye, setup.instrument.insertion_in_eye)
    assert not any(a.flags.writeable for a in (fit.insertion_in_eye, fit.x, fit.residuals, fit.inliers))
    assert fit.tip_sigma_mm(geometry=False) < 1e-6


def test_a_free_axis_is_fitted_within_its_uncertainty() -> None:
    setup = EXACT
    pose = InstrumentPose([1.0, -0.5, 4.5], [0.2, -0.1, -1.0])  # not through the insertion point
    (edge,) = _edges_px(setup, pose, count=300)
    noisy = edge + np.random.default_rng(0).normal(0.0, 0.1, edge.shape)
    problem = _one_frame(setup, [noisy], pose.tip_in_eye + 0.05, pose.axis, 0.0, axis="free")
    fit = fit_cones(problem)
    assert np.linalg.norm(fit.tip() - pose.tip_in_eye) < 3 * fit.tip_sigma_mm()
    assert angles_between(fit.axis(), pose.axis) < np.radians(1.0)


@settings(max_examples=15, deadline=None)
@given(
    x=st.floats(-2.5, 2.5),
    y=st.floats(-2.5, 2.5),
    z=st.floats(3, 6),
    kind=st.sampled_from([(1, "insertion"), (3, "insertion"), (3, "free")]),
    seed=st.integers(0, 1000),
)
def test_the_compiled_solver_gives_scipy_s_answer(x: float, y: float, z: float, kind: tuple, seed: int) -> None:
    # Noisy edge points, a start 0.1 mm off: Levenberg-Marquardt lands where SciPy's trust region does. (One
    # beam's free axis has a mirror-image minimum; either solver may find either: precise-free tries both.)
    beams, axis = kind
    setup = replace(EXACT, instrument=Instrument(beam_count=beams), uncertainty=Uncertainty())
    pose = InstrumentPose.through_insertion([x, y, z], setup.instrument.insertion_in_eye)
    rng = np.random.default_rng(seed)
    edges = [edge + rng.normal(0.0, 0.2, edge.shape) for edge in _edges_px(setup, pose, 0.1 * (beams > 1))]
    start = pose.tip_in_eye + 0.1 * rng.normal(size=3) / np.sqrt(3)
    problem = _one_frame(setup, edges, start, pose.axis, 0.0, axis=axis)
    scipy, compiled = fit_cones(problem), fit_cones(problem, solver="levenberg-marquardt")
    np.testing.assert_allclose(compiled.tip(), scipy.tip(), atol=1e-6)
    np.testing.assert_allclose(compiled.tip_sigma_mm(), scipy.tip_sigma_mm(), rtol=1e-6)
    assert np.array_equal(compiled.inliers, scipy.inliers) and compiled.settled == scipy.settled


@pytest.mark.parametrize("seed", [327, 532])
def test_the_compiled_solver_gives_scipy_s_answer_through_outliers(seed: int) -> None:
    # One beam, a free axis, a tenth of the points 8 px off, a start 0.3 mm off: the robust pass's damped steps
    # first raise the cost a little, then lower it a lot. A solver that took that first rise for convergence ended
    # 0.026 and 0.027 mm from SciPy's answer, inside its box and reported settled.
    rng = np.random.default_rng(seed)
    setup = replace(EXACT, uncertainty=Uncertainty())
    tip = [rng.uniform(-2.5, 2.5), rng.uniform(-2.5, 2.5), rng.uniform(3, 6)]
    pose = InstrumentPose.through_insertion(tip, setup.instrument.insertion_in_eye)
    (edge,) = _edges_px(setup, pose)
    edge = edge + rng.normal(0.0, 0.2, edge.shape)
    outliers = rng.integers(0, len(edge), len(edge) // 10)
    edge[outliers] += rng.normal(0.0, 8.0, (len(outliers), 2))
    start = pose.tip_in_eye + 0.3 * rng.normal(size=3) / np.sqrt(3)
    problem = _one_frame(setup, [edge], start, pose.axis, 0.0, axis="free")
    scipy, compiled = fit_cones(problem), fit_cones(problem, solver="levenberg-marquardt")
    np.testing.assert_allclose(compiled.tip(), scipy.tip(), atol=1e-6)
    assert compiled.settled and np.linalg.norm(compiled.tip() - pose.tip_in_eye) < 0.05


@pytest.mark.parametrize("solver", ["gauss-newton", "levenberg-marquardt"])
def test_the_fit_recipe_is_one_code_compiled_or_run_by_python(solver: str) -> None:
    # Gauss-Newton and Levenberg-Marquardt run the recipe compiled; the same recipe run by Python gives the same
    # bits. Compiled, it runs no trust region (SciPy's).
    setup = replace(EXACT, instrument=Instrument(beam_count=3), uncertainty=Uncertainty())
    pose = InstrumentPose.through_insertion([1.0, -0.5, 4.5], setup.instrument.insertion_in_eye)
    rng = np.random.default_rng(4)
    edges = [edge + rng.normal(0.0, 0.2, edge.shape) for edge in _edges_px(setup, pose, 0.1)]
    problem = _one_frame(setup, edges, pose.tip_in_eye + 0.02, pose.axis, 0.0)
    fit = fit_cones(problem, solver=solver)
    low, high = np.full(problem.size, -np.inf), np.full(problem.size, np.inf)
    x, box = problem.start, (low, high, np.arange(0))
    arguments = (x, problem.arrays, len(problem.free_frame), box, SOLVERS.index(solver))
    compiled, interpreted = _fit_recipe(*arguments, None), _fit_recipe.py_func(*arguments, (problem, None))
    assert compiled[3] and interpreted[3]  # done
    for a, b, c in zip(compiled[:3], interpreted[:3], (fit.x, fit.residuals, fit.inliers), strict=True):
        assert np.array_equal(a, b) and np.array_equal(a, c)
    with pytest.raises(ValueError, match="Gauss-Newton's or Levenberg-Marquardt's"):
        _fit_recipe(*arguments[:-1], SOLVERS.index("trust-region"), None)


def test_the_compiled_solver_does_not_leap_to_the_box_wall() -> None:
    # One beam, a free axis, a start 1 mm off: its first, barely damped step lowered the cost by leaping 4 mm, to
    # the tip's box; such a solve is done again by SciPy's trust region, which lands 0.03 mm from the truth.
    setup = replace(EXACT, uncertainty=Uncertainty())
    pose = InstrumentPose([1.0, -0.5, 4.5], [0.2, -0.1, -1.0])
    (edge,) = _edges_px(setup, pose, count=300)
    noisy = edge + np.random.default_rng(0).normal(0.0, 0.1, edge.shape)
    start = pose.tip_in_eye + np.array([-0.999, 0.016, -0.029])
    fit = fit_cones(_one_frame(setup, [noisy], start, pose.axis, 0.0, axis="free"), solver="levenberg-marquardt")
    assert fit.settled and np.linalg.norm(fit.tip() - pose.tip_in_eye) < 0.05


def test_a_solution_pickles_and_its_frames_carry_its_covariance() -> None:
    # The covariance computed on first use is a picklable recipe; one frame of a joint fit carries its block.
    setup = replace(EXACT, uncertainty=Uncertainty())
    poses = [InstrumentPose.through_insertion(t, setup.instrument.insertion_in_eye) for t in ([0.5, -1, 4], [1, 1, 5])]
    edges = [_edges_px(setup, pose) for pose in poses]
    points = EdgePoints.of_frames(edges, [[0], [0]])
    tips = np.array([pose.tip_in_eye + 0.02 for pose in poses])
    problem = cone_problem(setup, points, tips, np.array([pose.axis for pose in poses]), [0.0, 0.0])
    fit = fit_cones(problem, solver="levenberg-marquardt")
    copy = pickle.loads(pickle.dumps(fit))
    np.testing.assert_allclose(copy.covariance, fit.covariance)
    second = pickle.loads(pickle.dumps(fit.frame_solution(1)))
    np.testing.assert_allclose(second.tip_covariance(), fit.tip_covariance(1))


def test_an_edge_shift_widens_the_tip_s_sigma_by_its_own_spots_and_by_the_edge_angle_they_share() -> None:
    # A whole-edge shift, each spot's and all spots' together (an edge angle that much off), moves a 3-beam tip as
    # a light that much wider does: 0.25 deg wider, some 0.04 mm on the helix at 1024 px (0.16 mm per deg).
    setup = replace(EXACT, instrument=replace(EXACT.instrument, beam_count=3))
    pose = InstrumentPose.through_insertion([0.5, 0.5, 5.0], setup.instrument.insertion_in_eye)
    edges = [edge + np.random.default_rng(2).normal(0.0, 0.1, edge.shape) for edge in _edges_px(setup, pose)]
    fit = fit_cones(_one_frame(setup, edges, pose.tip_in_eye, pose.axis, 0.0))
    same = fit.with_edge_shift(0.0)
    assert same.tip_sigma_mm() == pytest.approx(fit.tip_sigma_mm(), rel=1e-9)
    wider = [fit.with_edge_shift(np.radians(d)).tip_sigma_mm() for d in (0.01, 0.05, 0.2)]
    assert fit.tip_sigma_mm() < wider[0] < wider[1] < wider[2]
    assert 0.004 < wider[1] < 0.016
    np.testing.assert_array_equal(fit.with_edge_shift(0.01).tip(), fit.tip())  # the fit itself stays
    # A joint fit's frame takes its block of the widened joint fit.
    poses = [InstrumentPose.through_insertion(t, setup.instrument.insertion_in_eye) for t in ([0.5, -1, 4], [1, 1, 5])]
    points = EdgePoints.of_frames([_edges_px(setup, p) for p in poses], [[0, 1, 2], [0, 1, 2]])
    tips, axes = np.array([p.tip_in_eye for p in poses]), np.array([p.axis for p in poses])
    joint = fit_cones(cone_problem(setup, points, tips, axes, [0.0, 0.0]), solver="levenberg-marquardt")
    frame = joint.frame_solution(1)
    assert frame.with_edge_shift(np.radians(0.05)).tip_sigma_mm() > 2 * frame.tip_sigma_mm()


def test_a_problem_needs_one_axis_per_frame() -> None:
    points = EdgePoints.of_frames([[np.zeros((5, 2))], [np.zeros((5, 2))]], [[0], [0]])
    with pytest.raises(ValueError, match="one row per frame"):
        cone_problem(EXACT, points, np.zeros((2, 3)), np.array([[0.0, 0.0, -1.0]]), axis="known")


def test_the_geometry_adds_its_uncertainty_to_the_tip() -> None:
    # The same points fitted in a setup known exactly and in one known as well as a real microscope: the
    # points' part of sigma is the same, the geometry's part comes on top, mostly from the camera's tilt.
    pose = InstrumentPose.through_insertion([1.0, -0.5, 4.0], EXACT.instrument.insertion_in_eye)
    (edge,) = _edges_px(EXACT, pose)
    noisy = edge + np.random.default_rng(1).normal(0.0, 0.1, edge.shape)
    exact = fit_cones(_one_frame(EXACT, [noisy], pose.tip_in_eye, pose.axis, 0.0))
    real = fit_cones(_one_frame(replace(EXACT, uncertainty=Uncertainty()), [noisy], pose.tip_in_eye, pose.axis, 0.0))
    np.testing.assert_allclose(real.tip(), exact.tip())
    assert real.tip_sigma_mm(geometry=False) == pytest.approx(exact.tip_sigma_mm(geometry=False))
    assert real.tip_sigma_mm() > 10 * exact.tip_sigma_mm()
    shares = dict(zip(real.geometry_ids, real.geometry_share(), strict=True))
    tilt = sum(shares[i] for i in PARAMETER_GROUPS["camera-rotation"])
    assert tilt == max(sum(shares.get(i, 0.0) for i in ids) for ids in PARAMETER_GROUPS.values())
    # A camera tilted by 0.5 deg sees the world 0.96 mm aside: that is the tip's uncertainty.
    assert real.tip_sigma_mm() == pytest.approx(np.radians(0.5) * 110.0 * np.sqrt(2 / 3), rel=0.3)
    # The tip's covariance is its points' part and the geometry's through the tip's gain.
    data, gain = real.tip_terms()
    ids = list(real.geometry_ids)
    covariance = data + gain @ real.problem.prior[np.ix_(ids, ids)] @ gain.T
    assert np.sqrt(np.trace(covariance) / 3) == pytest.approx(real.tip_sigma_mm(), rel=1e-9)
    assert np.sqrt(np.trace(data) / 3) == pytest.approx(real.tip_sigma_mm(geometry=False), rel=1e-9)


@settings(max_examples=10)
@given(seed=st.integers(0, 2**16), beams=st.sampled_from([1, 3]), axis=st.sampled_from(list(AXIS_MODES)))
@example(seed=15490, beams=3, axis="insertion")
def test_the_jacobian_is_the_residuals_derivative(seed: int, beams: int, axis: str) -> None:
    # Every shared parameter free and each frame's own (the tip, the roll, the free axis's angles), at a random
    # point: the engine's derivatives agree with central differences of its residual, to their truncation and
    # rounding. The engine differentiates the residual and the camera's points, exact but for the beam axes' central
    # differences (to 1e-6). The reference is extrapolated from central differences at a step and at half of it
    # (Richardson's): a plain one's truncation reached 5e-6 of a tip's column at a point where the residual curves
    # fast (seed 15490). The residual's evaluation loses up to 4 of its 16 digits (the across-axis distance is the
    # root of a difference of squares), and a difference's step divides that loss: for a column whose derivative is
    # 1e-9, more than its size.
    rng = np.random.default_rng(seed)
    setup = _tilted(replace(EXACT, instrument=Instrument(beam_count=beams)), (0.2, 0.1, -0.3), (-2.0, 0, 0, 0, 0))
    tips = np.array([[0.5, -0.5, 4.0], [-1.0, 1.0, 5.0]])
    axes = tips - setup.instrument.insertion_in_eye
    edges = [_edges_px(setup, InstrumentPose(t, a), 0.3) for t, a in zip(tips, axes, strict=True)]
    points = EdgePoints.of_frames(edges, [list(range(beams))] * 2)
    sigmas = prior_sigmas(replace(setup, uncertainty=Uncertainty()))
    shared = rng.normal(0.0, 0.2, SHARED_SIZE) * sigmas
    problem = cone_problem(
        setup, points, tips, axes, [0.3, 0.3], axis=axis, free_shared=range(SHARED_SIZE), shared=shared
    )
    x = problem.start + rng.normal(0.0, 1e-3, problem.size) * (np.arange(problem.size) >= SHARED_SIZE)
    jacobian = problem.jacobian_matrix(x)
    # One beam has no tilt (its sigma 0): its column is 0, differenced at a tilt's step.
    steps = np.concatenate([1e-4 * np.where(sigmas > 0, sigmas, 1e-2), np.full(problem.size - SHARED_SIZE, 1e-5)])
    lost = 1e4 * np.finfo(float).eps * np.abs(problem.residuals(x)).max()
    for column in range(problem.size):
        step = np.zeros(problem.size)
        step[column] = steps[column]
        wide = (problem.residuals(x + step) - problem.residuals(x - step)) / (2 * step[column])
        narrow = (problem.residuals(x + step / 2) - problem.residuals(x - step / 2)) / step[column]
        numeric = (4 * narrow - wide) / 3
        # The reference's rounding: (4 * 2 + 1) / 3 times a central difference's at the step.
        atol = 1e-6 * np.abs(numeric).max() + lost / (step[column] / 3) + 1e-12
        np.testing.assert_allclose(jacobian[:, column], numeric, rtol=1e-6, atol=atol)


def test_known_poses_recover_a_tilted_camera_with_a_lens() -> None:
    # Exact edges of eight known poses (tips and axes) seen through the true camera: tilted, 0.5 % longer,
    # with k1 = -3. The nominal setup with those parameters free finds them.
    truth = np.zeros(SHARED_SIZE)
    truth[3:6] = np.radians([0.3, -0.2, 0.4])
    truth[9] = 0.005
    truth[12] = -3.0
    truth[0] = np.radians(-0.1)
    world = setup_with_geometry(EXACT, truth)
    rng = np.random.default_rng(4)
    tips = np.column_stack([rng.uniform(-2.5, 2.5, 8), rng.uniform(-2.5, 2.5, 8), rng.uniform(3, 6, 8)])
    axes = tips - EXACT.instrument.insertion_in_eye
    edges = [_edges_px(world, InstrumentPose(t, a)) for t, a in zip(tips, axes, strict=True)]
    points = EdgePoints.of_frames(edges, [[0]] * 8)
    free = [0, 3, 4, 5, 9, 12]
    problem = cone_problem(EXACT, points, tips, axes, axis="known", free_tips=False, free_shared=free)
    fit = fit_cones(problem)
    np.testing.assert_allclose(fit.shared[free], truth[free], rtol=1e-4, atol=1e-9)
    with pytest.raises(ValueError, match="tip is not free"):
        fit.tip_terms()


def test_scatter_covariance_is_the_textbook_formula() -> None:
    rng = np.random.default_rng(3)
    jacobian, residuals = rng.normal(size=(50, 4)), rng.normal(size=50)
    spots = np.repeat(np.arange(5), 10)
    covariance, response = scatter_covariance(jacobian, residuals, spots, 0.0, 4)
    variance = np.sum(residuals**2) / 46 * correlation_inflation(residuals, spots)
    np.testing.assert_allclose(covariance, variance * np.linalg.inv(jacobian.T @ jacobian), rtol=1e-9)
    np.testing.assert_allclose(response, np.linalg.inv(jacobian.T @ jacobian), rtol=1e-9)
    # A prior adds its information; a spot's shift moves the parameters by R J_s^T 1.
    prior = np.array([1.0, 0.0, 4.0, 0.0])
    with_prior, _ = scatter_covariance(jacobian, residuals, spots, 0.0, 4, prior)
    np.testing.assert_allclose(with_prior, np.linalg.inv(jacobian.T @ jacobian / variance + np.diag(prior)))
    shifted, _ = scatter_covariance(jacobian, residuals, spots, 0.1, 4)
    sums = np.array([jacobian[spots == s].sum(axis=0) for s in range(5)]) @ response
    np.testing.assert_allclose(shifted - covariance, 0.01 * sums.T @ sums, rtol=1e-9, atol=1e-15)
    # Spot numbers of any integer type, or a list, are the same spots.
    for other in (spots.astype(np.int32), spots.astype(np.uint8), spots.tolist()):
        np.testing.assert_array_equal(scatter_covariance(jacobian, residuals, other, 0.1, 4)[0], shifted)


def test_correlation_inflation_of_known_sequences() -> None:
    groups = np.zeros(40, dtype=np.int64)
    assert correlation_inflation(np.tile([1.0, -1.0], 20), groups) == 1.0  # anti-correlated: no inflation
    assert correlation_inflation(np.linspace(-1, 1, 40), groups) == pytest.approx(19.0)  # rho capped at 0.9
    # Neighbours are taken within a group only: two groups, each alternating about its own mean.
    two = np.concatenate([np.tile([5.0, 3.0], 10), np.tile([-2.0, -4.0], 10)])
    assert correlation_inflation(two, np.repeat([0, 1], 20)) == 1.0
    assert correlation_inflation(np.empty(0), np.empty(0, dtype=np.int64)) == 1.0


def test_robust_sigma_ignores_outliers() -> None:
    values = np.random.default_rng(3).normal(2.0, 0.5, 20001)
    values[:2000] = 1e6  # 10 % gross outliers
    # 10 % of the values off the scale widen the robust sigma by 14 % (0.5 sigma: 1.14 x 0.5); a plain
    # standard deviation would be 3e5.
    assert robust_sigma(values, True) == pytest.approx(0.5 * 1.14, rel=0.02)
    assert robust_sigma(values - np.median(values), False) == pytest.approx(robust_sigma(values, True))


def test_geometry_covariance_takes_the_calibration_over_the_uncertainty() -> None:
    setup = Setup(camera=Camera(width_px=1024, height_px=1024))
    default = geometry_covariance(setup)
    sigmas = prior_sigmas(setup)
    np.testing.assert_allclose(np.sqrt(np.diag(default))[1:], sigmas[1:])
    assert default[0, 0] == pytest.approx(sigmas[0] ** 2 + EDGE_MODEL_SIGMA**2)
    assert sigmas[3] == pytest.approx(np.radians(0.5)) and sigmas[9] == pytest.approx(0.01)
    # k1's default moves the middle of the image's edge by 5 px.
    half = 512.0 / setup.camera.focal_px
    assert sigmas[12] * half**3 * setup.camera.focal_px == pytest.approx(5.0)
    names = ("edge_half_angle_deg", "camera_x_mm")
    record = CalibrationRecord(names, ((0.01**2, 1e-5), (1e-5, 0.02**2)), names, 0.02, 8, 0.015)
    calibrated = geometry_covariance(replace(setup, calibration=record))
    assert calibrated[0, 0] == pytest.approx(np.radians(0.01) ** 2 + np.radians(0.015) ** 2)
    x = GEOMETRY_PARAMETERS.index("camera_x_mm")
    assert calibrated[x, x] == pytest.approx(0.02**2) and calibrated[0, x] == pytest.approx(np.radians(1e-5))
    assert calibrated[1, 1] == default[1, 1]  # not in the calibration: its [uncertainty]


def test_edge_angle_default_and_override() -> None:
    setup = Setup()
    assert edge_angle(setup) == pytest.approx(edge_angle_of_blend(np.radians(9.0), 0.15))
    assert np.degrees(edge_angle(setup)) == pytest.approx(8.6555, abs=1e-3)
    given_angle = replace(setup, instrument=replace(setup.instrument, edge_half_angle_deg=8.5))
    assert np.degrees(edge_angle(given_angle)) == pytest.approx(8.5)


def test_setup_with_geometry_is_the_perturbed_camera() -> None:
    change = np.zeros(SHARED_SIZE)
    change[[0, 1, 2]] = np.radians(0.1), 0.02, 0.1
    change[3:17] = [1e-3, -2e-3, 3e-3, 0.1, -0.2, 0.3, 0.004, 2.0, -1.0, -2.5, 10.0, 1e-3, -1e-3, 0.0]
    change[17:] = [0.1, -0.1, 0.2, np.radians(0.3)]
    setup = setup_with_geometry(EXACT, change)
    np.testing.assert_allclose(camera_model(setup.camera), perturbed_model(camera_model(EXACT.camera), change[3:17]))
    assert setup.eye.radius_mm == pytest.approx(12.6) and setup.instrument.light_radius_mm == pytest.approx(0.02)
    assert setup.instrument.edge_half_angle_deg == pytest.approx(np.degrees(edge_angle(EXACT)) + 0.1)
    np.testing.assert_allclose(setup.instrument.insertion_point_mm, [0.1, 5.9, 20.2])
    assert setup.instrument.beam_tilt_deg == pytest.approx(EXACT.instrument.beam_tilt_deg + 0.3)
    assert setup_with_geometry(EXACT, np.zeros(SHARED_SIZE)).camera == EXACT.camera  # unchanged stays ideal


def test_geometry_values_are_a_fresh_array_each_call() -> None:
    # Calibration writes into the values it is given: another call for an equal setup must not see that.
    values = geometry_values(EXACT)
    values[3] = 99.0
    again = geometry_values(replace(EXACT))
    assert again is not values and again[3] == 0.0
    np.testing.assert_array_equal(again[:3], values[:3])
