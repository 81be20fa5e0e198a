"""Calibration from known poses: what the frames determine is fitted, the rest is named, a misfit is refused."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import small_setup

from spotnav.app.calibrate import (
    APERTURE_MARGIN,
    EDGE_BAND_MARGIN,
    HELD_OUT_FOLDS,
    RESPONSE_CANDIDATES,
    RESPONSE_MARGIN,
    calibrate,
)
from spotnav.errors import InputError, SpotnavError
from spotnav.experiments.chapter6 import thesis_world, with_true_edge
from spotnav.experiments.scenes import with_lens_blur
from spotnav.optics.light import edge_angle
from spotnav.optics.render import Renderer
from spotnav.pose import calibration
from spotnav.pose.conefit.parameters import (
    PARAMETER_GROUPS,
    SHARED_SIZE,
    geometry_covariance,
    geometry_to_file_units,
    geometry_values,
    prior_sigmas,
    setup_with_geometry,
)
from spotnav.pose.known_frame import KnownFrame
from spotnav.pose.localize import localize
from spotnav.pose.precise import localize_precise
from spotnav.setup.config import Instrument, Setup, Uncertainty, World
from spotnav.setup.geometry import InstrumentPose, edge_angle_of_blend
from spotnav.setup.paths import helix_tips, poses_through_insertion, working_volume_tips
from spotnav.setup.uncertainty import GEOMETRY_PARAMETERS


def known_frames(world: Setup, count: int = 8, seed: int = 5, *, axes: bool = False) -> list[KnownFrame]:
    """Frames rendered in ``world`` at tips over the working volume, with the robot's tips (and axes)."""
    renderer = Renderer(world)
    frames = []
    for i, tip in enumerate(working_volume_tips(count, seed=seed)):
        pose = InstrumentPose.through_insertion(tip, world.instrument.insertion_in_eye)
        frames.append(KnownFrame(f"frame {i}", renderer.render(pose, seed=i), tip, pose.axis if axes else None))
    return frames


def _value(result: object, name: str) -> tuple[float, float]:
    index = GEOMETRY_PARAMETERS.index(name)
    return float(result.values[index]), float(result.sigmas[index])  # type: ignore[attr-defined]


def _only(setup: Setup, **uncertain: float) -> Setup:
    """The setup known exactly but for these ``[uncertainty]`` values."""
    return replace(setup, uncertainty=replace(Uncertainty.exact(), **uncertain))


def test_the_edge_angle_is_fitted_when_the_beam_is_softer_than_the_model() -> None:
    # A beam softer than the default model (blend 0.3), the rest known: 8 known frames recover its
    # half-light angle and nothing else is fitted.
    world = small_setup(1024, blend=0.3)
    setup = _only(world, edge_half_angle_deg=0.3)
    result = calibrate(known_frames(world), setup)
    truth = np.degrees(edge_angle_of_blend(world.instrument.beam_half_angle, 0.3))
    value, sigma = _value(result, "edge_half_angle_deg")
    assert value == pytest.approx(truth, abs=max(4 * sigma, 0.02))
    assert result.fitted == ("edge_half_angle_deg",)
    assert result.rms_after_deg < 0.5 * result.rms_before_deg
    assert result.setup.instrument.edge_half_angle_deg == pytest.approx(value)
    assert result.setup.camera == world.camera and result.setup.light == world.light
    assert dict(result.fixed)["camera_x_mm"] == "known exactly ([uncertainty] 0)"


def test_a_point_light_calibrates_to_no_light_radius() -> None:
    # spotnav's renderer has a point light: fitting the light's radius must not invent one.
    world = small_setup(1024, blend=0.3)
    result = calibrate(known_frames(world), _only(world, edge_half_angle_deg=0.3, light_radius_mm=0.05))
    assert "light_radius_mm" in result.fitted
    value, sigma = _value(result, "light_radius_mm")
    assert value < max(4 * sigma, 0.003)
    truth = np.degrees(edge_angle_of_blend(world.instrument.beam_half_angle, 0.3))
    assert _value(result, "edge_half_angle_deg")[0] == pytest.approx(truth, abs=0.05)


def test_the_eye_radius_is_fitted_with_three_beams() -> None:
    # The true eye is 13.5 mm, the setup says 12.5: forced, the joint fit finds the radius within 0.1 mm.
    base = small_setup(1024, blend=0.15)
    world = replace(base, instrument=Instrument(beam_count=3), world=World(eye_radius_mm=13.5))
    result = calibrate(known_frames(world), _only(with_true_edge(world), eye_radius_mm=1.0), fit=["eye-radius"])
    value, sigma = _value(result, "eye_radius_mm")
    assert value == pytest.approx(13.5, abs=0.1)
    assert 0 < sigma < 0.1
    assert result.setup.eye.radius_mm == pytest.approx(value)


def test_a_wrong_geometry_is_measured_and_localized_within_its_sigma(monkeypatch: pytest.MonkeyPatch) -> None:
    # The world differs from the setup in every way at once (camera tilted and shifted, 0.5 % longer, a lens,
    # the principal point, the eye, the insertion point, the beam): a plain calibrate on 10 known poses
    # with axes, then new frames are localized as the Cycles frames must be at this size (mean 0.010 mm,
    # max 0.030), and within 3 sigma (the calibration's own uncertainty included) but for one at most.
    nominal = small_setup(1024, blend=0.15)
    change = np.zeros(SHARED_SIZE)
    change[3:17] = [*np.radians([0.3, -0.4, 0.2]), 0.3, -0.4, 0.5, 0.005, 6.0, -4.0, -3.0, 0, 0, 0, 0]
    world = setup_with_geometry(nominal, change)
    world = replace(world, eye=replace(world.eye, radius_mm=12.6), world=World(eye_radius_mm=12.6))
    instrument = replace(world.instrument, insertion_point_mm=(0.4, 5.7, 20.5), beam_half_angle_deg=9.2)
    world = replace(world, instrument=instrument)
    setup = replace(nominal, uncertainty=Uncertainty())
    known = known_frames(world, 10, seed=11, axes=True)
    result = calibrate(known, setup)
    # The calibration frames' own tips, found from their edges alone, miss by 0.003 mm on average, within what the
    # fit's covariance says. They missed by 0.01 mm, and the covariance was scaled up 1.8 times, while vessels along
    # the edges moved the rays that read them; the edge reader now leaves such rays out (the scale's own test is
    # test_the_most_likely_scale_of_the_geometry_s_sigmas). Whatever the scale, every sigma carries it.
    assert len(result.tip_misses_mm) == 10 and np.mean(result.tip_misses_mm) < 0.006
    scale = result.covariance_scale
    assert scale == 1.0
    with monkeypatch.context() as patch:
        patch.setattr(calibration, "_most_likely_scale", lambda *_: 1.0)
        unscaled = calibrate(known, setup)
    np.testing.assert_allclose(result.sigmas, scale * unscaled.sigmas, rtol=1e-12)
    np.testing.assert_allclose(
        geometry_covariance(result.setup, one_frame=False),
        scale**2 * geometry_covariance(unscaled.setup, one_frame=False),
        rtol=1e-9,
        atol=1e-30,
    )
    for group in ("edge_half_angle_deg", "camera_rotation_x_deg", "camera_rotation_z_deg", "distortion_k1"):
        assert group in result.fitted
    np.testing.assert_allclose(result.setup.instrument.insertion_point_mm, (0.4, 5.7, 20.5), atol=1e-3)
    assert "camera_z_mm" in dict(result.fixed)  # a camera's height looks like its focal length
    renderer = Renderer(world)
    errors, within = [], []
    for i, tip in enumerate(helix_tips(6)):
        pose = InstrumentPose.through_insertion(tip, world.instrument.insertion_in_eye)
        estimate = localize(renderer.render(pose, seed=100 + i), result.setup)
        assert estimate.ok, estimate.detail
        errors.append(np.linalg.norm(estimate.tip_in_eye - tip))
        within.append(errors[-1] <= 3 * estimate.sigma_mm)
    assert np.mean(errors) < 0.010 and np.max(errors) < 0.030
    assert sum(within) >= len(within) - 1
    nominal_estimate = localize(renderer.render(pose, seed=100), setup)
    assert nominal_estimate.status == "uncalibrated", nominal_estimate.detail  # refused, not 0.6 mm off


def test_a_plain_calibration_of_an_exact_geometry_does_not_make_it_worse() -> None:
    world = small_setup(1024, blend=0.15)
    exact = with_true_edge(world)
    result = calibrate(known_frames(world, 10, seed=3, axes=True), replace(world, uncertainty=Uncertainty()))
    assert result.covariance_scale == 1.0  # its own frames' tips miss by no more than its covariance says
    assert max(result.tip_misses_mm) < 0.01
    renderer = Renderer(world)
    errors: dict[str, list[float]] = {"exact": [], "calibrated": []}
    for i, tip in enumerate(helix_tips(6)):
        image = renderer.render(InstrumentPose.through_insertion(tip, world.instrument.insertion_in_eye), seed=i)
        for name, setup in (("exact", exact), ("calibrated", result.setup)):
            estimate = localize(image, setup)
            assert estimate.ok, estimate.detail
            errors[name].append(np.linalg.norm(estimate.tip_in_eye - tip))
    # Ten frames at 1024 px pin the edge angle to some 0.01 deg: at most 0.005 mm more error on average than
    # knowing the geometry, and none that its sigma does not cover.
    assert np.mean(errors["calibrated"]) < np.mean(errors["exact"]) + 0.005


def test_calibration_refuses_too_few_degenerate_or_misfit_frames() -> None:
    world = small_setup(512, blend=0.15)
    setup = _only(world, edge_half_angle_deg=0.3, eye_radius_mm=0.25, light_radius_mm=0.05)
    frames = known_frames(world, count=2)
    with pytest.raises(SpotnavError, match="at least 3 usable frames"):
        calibrate(frames, setup)
    renderer = Renderer(world)
    same = InstrumentPose.through_insertion([1.0, 1.0, 4.0], world.instrument.insertion_in_eye)
    repeated = [KnownFrame(f"f{i}", renderer.render(same, seed=i), same.tip_in_eye) for i in range(5)]
    with pytest.raises(SpotnavError, match=r"cannot determine eye-radius: .* 0\.00 mm apart in x, y.*would$"):
        calibrate(repeated, setup, fit=["eye-radius"])
    with pytest.raises(
        SpotnavError,
        match=r"cannot determine edge-angle and light-radius together: .*4\.00-4\.00 mm above the pole\): fit one of "
        r"them \(leave --fit light-radius out\), or known frames at more varied heights would tell them apart$",
    ):
        calibrate(repeated, setup, fit=["edge-angle", "light-radius"])
    dark = [KnownFrame("dark", renderer.render(same, power_w=0.0), same.tip_in_eye), *frames]
    with pytest.raises(SpotnavError, match="dark: 0 bright regions"):
        calibrate(dark, setup)
    with pytest.raises(SpotnavError, match="'lens' is not a parameter group"):
        calibrate(frames, setup, fit=["lens"])
    # Tips swapped between frames: no geometry puts their edges on their cones.
    many = known_frames(world, count=6)
    shuffled = [replace(f, tip_in_eye=g.tip_in_eye) for f, g in zip(many, many[1:] + many[:1], strict=True)]
    with pytest.raises(SpotnavError, match="does not fit the frames"):
        calibrate(shuffled, setup)


@pytest.mark.parametrize(("written", "found"), [("agx", "agx"), ("srgb", None)])
def test_calibration_tells_a_tone_curve_from_srgb_when_the_response_is_not_stated(
    written: str, found: str | None
) -> None:
    # Frames written through AgX (spots high on its shoulder) or sRGB; the setup does not say which.
    world = small_setup(1024)
    world = replace(world, camera=replace(world.camera, response=written))
    setup = _only(replace(world, camera=replace(world.camera, response=None)), edge_half_angle_deg=0.3)
    result = calibrate(known_frames(world, axes=True), setup)
    assert result.setup.camera.response == found
    spreads = dict(result.responses)
    assert tuple(spreads) == RESPONSE_CANDIDATES
    better = spreads["agx"] < (1.0 - RESPONSE_MARGIN) * spreads["srgb"]
    assert better == (found == "agx")
    # A stated response is the camera's: nothing is estimated.
    stated = calibrate(known_frames(world, count=4, axes=True), replace(setup, camera=world.camera))
    assert stated.responses == () and stated.setup.camera.response == written


def test_a_calibration_that_misses_its_own_frames_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    world = small_setup(512, blend=0.15)
    monkeypatch.setattr(calibration, "_most_likely_scale", lambda *_: 10.0)
    with pytest.raises(InputError, match="does not find its own frames' tips"):
        calibrate(known_frames(world, 5), _only(world, edge_half_angle_deg=0.3))


def test_a_clipped_beam_is_read_with_the_soft_band_its_calibration_fitted() -> None:
    # The thesis's exposure (+4.5 stops: every spot clipped) and a beam sharper than the setup's default model
    # (blend 0.1 against 0.15): the clipped spots are read from their flanks by the light's soft band. Calibration
    # tries bands about the setup's, keeps the one whose spots agree best, and writes it: the frames are then read
    # with the band they were calibrated with, not one that follows the fitted edge (2 (beta - edge)).
    world = thesis_world(768, 1, exposure_stops=4.5)
    world = replace(world, light=replace(world.light, blend=0.1))
    setup = _only(world, edge_half_angle_deg=0.3)
    result = calibrate(known_frames(world), setup)
    nominal = np.degrees(2.0 * (world.instrument.beam_half_angle - edge_angle(setup)))
    (first, first_spread), *others = result.edge_bands
    assert first == pytest.approx(nominal) and len(others) >= 4
    band = result.setup.instrument.edge_band_deg
    assert band is not None and band < nominal  # a sharper beam: a narrower band
    assert dict(result.edge_bands)[band] < (1.0 - EDGE_BAND_MARGIN) * first_spread
    renderer = Renderer(world)
    poses = poses_through_insertion(helix_tips(16), world.instrument.insertion_in_eye)
    frames = [renderer.render(pose, seed=100 + i) for i, pose in enumerate(poses)]
    following = replace(result.setup, instrument=replace(result.setup.instrument, edge_band_deg=None))
    errors = {}
    for name, calibrated in (("written", result.setup), ("following the edge", following)):
        estimates = [localize_precise(frame, calibrated) for frame in frames]
        assert sum(e.ok for e in estimates) >= 15, name
        pairs = zip(estimates, poses, strict=True)
        errors[name] = [np.linalg.norm(e.tip_in_eye - p.tip_in_eye) for e, p in pairs if e.ok]
    # Measured: 0.0028 / 0.0062 mm with the written band, 0.0043 / 0.0090 with one that follows the edge.
    assert np.mean(errors["written"]) < 0.004 and np.max(errors["written"]) < 0.010
    assert np.mean(errors["written"]) < np.mean(errors["following the edge"])


def test_a_calibration_keeps_the_band_its_frames_were_read_with() -> None:
    # No spot clips: the band is not fitted, but written, so that a moved edge does not move it.
    world = small_setup(1024, blend=0.3)
    setup = _only(world, edge_half_angle_deg=0.3)
    result = calibrate(known_frames(world, 6), setup)
    assert result.edge_bands == ()
    nominal = np.degrees(2.0 * (world.instrument.beam_half_angle - edge_angle(setup)))
    assert result.setup.instrument.edge_band_deg == pytest.approx(nominal)
    assert abs(result.setup.instrument.edge_half_angle_deg - np.degrees(edge_angle(setup))) > 0.05  # the edge moved


def test_the_three_beams_tilt_is_calibrated_and_its_poses_answered() -> None:
    # The fibres tilt 15.5 deg where the setup says 15, the rest known but for a real tip's tilt and edge: 8 known
    # frames recover the tilt, and helix tips are then found within a few microns.
    base = small_setup(1024, blend=0.15)
    world = replace(base, instrument=Instrument(beam_count=3, beam_tilt_deg=15.5))
    nominal = replace(world, instrument=replace(world.instrument, beam_tilt_deg=15.0))
    setup = _only(with_true_edge(nominal), beam_tilt_deg=0.5, edge_half_angle_deg=0.3)
    result = calibrate(known_frames(world), setup)
    value, sigma = _value(result, "beam_tilt_deg")
    assert "beam_tilt_deg" in result.fitted
    assert value == pytest.approx(15.5, abs=max(4 * sigma, 0.01))
    assert sigma < 0.05
    assert result.setup.instrument.beam_tilt_deg == pytest.approx(value)
    renderer = Renderer(world)
    errors = []
    for i, tip in enumerate(helix_tips(6)):
        pose = InstrumentPose.through_insertion(tip, world.instrument.insertion_in_eye)
        answer = localize_precise(renderer.render(pose, seed=100 + i), result.setup)
        assert answer.status == "ok", answer.detail
        errors.append(float(np.linalg.norm(answer.tip_in_eye - tip)))
    assert max(errors) < 0.01


def test_one_beam_has_no_tilt_to_calibrate() -> None:
    world = small_setup(1024, blend=0.15)
    with pytest.raises(InputError, match="one beam has no tilt"):
        calibrate(known_frames(world, 3), world, fit=["beam-tilt"])


# Groups that 6 known frames at 512 px cannot determine alone, and the frames the refusal names instead.
_UNDETERMINED_AT_512 = {"distortion": "known frames out to the image's edges would"}


def _world_off_in(nominal: Setup, group: str) -> tuple[Setup, np.ndarray]:
    """A world whose ``group`` is off the nominal setup by a real microscope's 1 sigma, and its values in the units
    of :data:`GEOMETRY_PARAMETERS` (changes for the camera's rotation and focal length).

    The renderer draws the beam from its half-angle and blend and the light as a point: the edge angle is moved
    through the half-angle, and the light's radius stays 0.
    """
    ids = list(PARAMETER_GROUPS[group])
    change = np.zeros(SHARED_SIZE)
    if group == "edge-angle":
        sigma = Uncertainty().edge_half_angle_deg
        instrument = replace(nominal.instrument, beam_half_angle_deg=nominal.instrument.beam_half_angle_deg + sigma)
        world = replace(nominal, instrument=instrument)
    elif group == "light-radius":
        world = nominal
    else:
        change[ids] = prior_sigmas(replace(nominal, uncertainty=Uncertainty()))[ids]
        world = setup_with_geometry(nominal, change)
    truth = geometry_values(world)
    changes_only = [*PARAMETER_GROUPS["camera-rotation"], *PARAMETER_GROUPS["focal-length"]]
    truth[changes_only] = geometry_to_file_units(change)[changes_only]
    return world, truth


@pytest.mark.parametrize("group", list(PARAMETER_GROUPS))
def test_fit_each_group_round_trips(group: str) -> None:
    # A world off the setup in one group by a real microscope's 1 sigma, the setup exact elsewhere: --fit GROUP
    # (which judges the frames against a real microscope's uncertainty where the setup states 0) measures it within
    # 4 of its sigmas, or refuses it in one sentence that says what frames would determine it. Without known axes
    # the insertion point is fitted from the images. The beams' tilt with three beams (one beam has none).
    nominal = small_setup(512, blend=0.15)
    nominal = replace(nominal, camera=replace(nominal.camera, response="srgb"))
    if group == "beam-tilt":
        nominal = replace(nominal, instrument=Instrument(beam_count=3))
    world, truth = _world_off_in(nominal, group)
    frames = known_frames(world, 6, axes=group != "insertion-point")
    if group in _UNDETERMINED_AT_512:
        with pytest.raises(InputError) as refused:
            calibrate(frames, nominal, fit=[group], held_out=False)
        assert f"cannot determine {group}: " in str(refused.value) and "\n" not in str(refused.value)
        assert str(refused.value).endswith(_UNDETERMINED_AT_512[group])
        return
    result = calibrate(frames, nominal, fit=[group], held_out=False)
    ids = list(PARAMETER_GROUPS[group])
    assert set(GEOMETRY_PARAMETERS[i] for i in ids) <= set(result.fitted)
    assert np.all(result.sigmas[ids] > 0)
    np.testing.assert_array_less(np.abs(result.values[ids] - truth[ids]), 4 * result.sigmas[ids])


def _a_new_user_s_frames(size_px: int, count: int) -> tuple[Setup, list[KnownFrame]]:
    """The nominal setup with a real microscope's uncertainty (the response stated), and ``count`` known frames with
    axes from a world 0.5 deg wider in the beam and 0.5 mm higher in the camera (issue 62's new user)."""
    nominal = replace(small_setup(size_px, blend=0.15), uncertainty=Uncertainty())
    nominal = replace(nominal, camera=replace(nominal.camera, response="srgb"))
    camera = replace(nominal.camera, distance_mm=nominal.camera.distance_mm + 0.5)
    instrument = replace(nominal.instrument, beam_half_angle_deg=nominal.instrument.beam_half_angle_deg + 0.5)
    return nominal, known_frames(replace(nominal, camera=camera, instrument=instrument), count, axes=True)


def test_fit_any_group_alone_or_all_at_once_is_answered_or_refused_in_one_sentence() -> None:
    # A real microscope's uncertainty, a world 0.5 deg wider in the beam and 0.5 mm higher in the camera, 6 known
    # frames with axes: every --fit GROUP, and all at once, fits the group or says in one sentence why not.
    nominal, frames = _a_new_user_s_frames(512, 6)
    # One beam has no tilt to fit (test_one_beam_has_no_tilt_to_calibrate).
    others = [group for group in PARAMETER_GROUPS if group not in ("insertion-point", "beam-tilt")]
    for fit in [[group] for group in others] + [others]:
        try:
            result = calibrate(frames, nominal, fit=fit, held_out=False)
        except InputError as error:
            assert "\n" not in str(error) and str(error).startswith("the known frames cannot determine "), fit
            assert str(error).endswith((" would", "would tell them apart", "force fewer groups at once")), str(error)
        else:
            fitted = {GEOMETRY_PARAMETERS[i] for group in fit for i in PARAMETER_GROUPS[group]}
            assert fitted <= set(result.fitted), fit
    # Known axes meet at the insertion point: forcing it is refused, alone or with the others.
    for fit in (["insertion-point"], [*others, "insertion-point"]):
        with pytest.raises(InputError, match=r"^with known axes the insertion point is where they meet; leave --fit"):
            calibrate(frames, nominal, fit=fit, held_out=False)


def test_the_held_out_check_localizes_each_known_frame_with_a_calibration_of_the_others() -> None:
    # The new user's trap (issue 62): a world 0.5 deg wider in the beam and 0.5 mm higher in the camera, a real
    # microscope's uncertainty. Each of 8 known frames is localized by a calibration of the other six, and is found
    # within its sigma; the calibration returned is the one of all 8.
    nominal, frames = _a_new_user_s_frames(768, 8)
    result = calibrate(frames, nominal)
    held = result.held_out
    assert held is not None and held.folds == HELD_OUT_FOLDS and result.frames == 8
    assert held.names == tuple(frame.name for frame in frames)
    assert held.answered == 8 and held.coverage() >= 7 / 8 and not held.misses()
    assert np.nanmax(held.errors_mm) < 0.03
    # A robot that reports one tip 0.1 mm off: the calibrations without it find it where it is, not where it says.
    moved = frames[3].tip_in_eye + np.array([0.0, 0.0, 0.1])
    wrong = [*frames[:3], replace(frames[3], tip_in_eye=moved), *frames[4:]]
    try:
        missed = calibrate(wrong, nominal).held_out
    except InputError as error:  # or the calibration with it does not find its own frames' tips
        assert "does not find its own frames' tips" in str(error)
    else:
        assert missed is not None and missed.misses()


@pytest.mark.slow
def test_calibration_measures_a_lens_s_depth_of_field_from_clipped_spots() -> None:
    # +4.5 stops through a lens (focused at the pole) that blurs the helix's spots by 1 px (their median); the setup
    # states no aperture. The spots that clip agree with their known poses only through the right aperture.
    world = with_lens_blur(thesis_world(768, 1, exposure_stops=4.5), 1.0)
    true_aperture = world.camera.aperture_mm
    assert true_aperture is not None
    setup = _only(replace(world, camera=replace(world.camera, aperture_mm=None)), edge_half_angle_deg=0.3)
    result = calibrate(known_frames(world, axes=True), setup)
    fitted, sigma = result.setup.camera.aperture_mm, result.setup.calibration.aperture_sigma_mm
    assert fitted is not None and 0.0 < sigma < 0.5 * true_aperture, (fitted, sigma, result.apertures)
    assert abs(fitted - true_aperture) < 3.0 * sigma, (fitted, sigma, true_aperture, result.apertures)
    pinhole_spread, best_spread = result.apertures[0][1], min(spread for _, spread in result.apertures)
    assert best_spread < (1.0 - APERTURE_MARGIN) * pinhole_spread
    # Stated, it is used as it is: no aperture is tried.
    stated = calibrate(known_frames(world, 6, axes=True), _only(world, edge_half_angle_deg=0.3))
    assert stated.apertures == () and stated.setup.camera.aperture_mm == true_aperture
