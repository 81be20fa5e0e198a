from __future__ import annotations

import math
import pickle
import re
from dataclasses import fields, replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from spotnav.setup.config import Setup, setup_from_dict, setup_from_toml
from spotnav.setup.examples import EXAMPLE_SETUP, MICROSCOPE_SETUP
from spotnav.setup.sections import Bump
from spotnav.setup.uncertainty import CalibrationRecord, Uncertainty
from spotnav.setup.values import SetupError


def test_example_is_the_thesis_setup() -> None:
    setup = setup_from_toml(EXAMPLE_SETUP)
    assert setup == Setup(uncertainty=Uncertainty.exact())  # a simulation knows its geometry
    assert setup.camera.focal_px == pytest.approx(300 * 5000 / 36)
    assert setup.camera.principal_point_px == (2499.5, 2499.5)
    assert setup.instrument.insertion_point_mm == (0.0, 6.0, 20.0)
    assert math.degrees(setup.instrument.beam_half_angle) == pytest.approx(9.0)


def test_the_microscope_example_is_the_thesis_setup_with_a_real_microscope_s_uncertainty() -> None:
    # Issue 62: what `scene --example` writes states every [uncertainty] key at spotnav's defaults (a key added to
    # Uncertainty and not to the example fails here), and differs from the simulation's exact file in that alone.
    setup = setup_from_toml(MICROSCOPE_SETUP)
    assert setup == Setup() and setup.uncertainty == Uncertainty() != Uncertainty.exact()
    assert replace(setup, uncertainty=Uncertainty.exact()) == setup_from_toml(EXAMPLE_SETUP)
    assert not setup.claims_exact_geometry and setup_from_toml(EXAMPLE_SETUP).claims_exact_geometry


def test_a_setup_claims_exact_geometry_only_with_every_uncertainty_0_and_no_calibration() -> None:
    exact = Setup(uncertainty=Uncertainty.exact())
    assert exact.claims_exact_geometry
    for name in (item.name for item in fields(Uncertainty)):
        assert not replace(exact, uncertainty=replace(Uncertainty.exact(), **{name: 0.1})).claims_exact_geometry, name
    calibrated = replace(exact, calibration=CalibrationRecord(("camera_z_mm",), ((0.01,),), ("camera_z_mm",)))
    assert not calibrated.claims_exact_geometry


def test_empty_file_takes_the_thesis_defaults() -> None:
    assert setup_from_toml("") == Setup()


def test_bumps_are_parsed() -> None:
    setup = setup_from_toml("[world]\neye_radius_mm = 13.5\nbumps = [{x_mm = 1.0, y_mm = 2.0}]\n")
    assert setup.world.bumps == (Bump(1.0, 2.0),)
    assert setup.true_radius_mm == 13.5
    assert setup.eye.radius_mm == 12.5


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("[eye]\nradius_mm = -1.0", "eye.radius_mm"),
        ("[eye]\nradius_mm = 0", "eye.radius_mm"),
        ("[eye]\nradius_mm = nan", "eye.radius_mm"),
        ("[eye]\nradius_mm = inf", "eye.radius_mm"),
        ("[eye]\nradius_mm = 'big'", "eye.radius_mm"),
        ("[eye]\nradius_mm = true", "eye.radius_mm"),
        ("[eye]\nradius = 12.5", "eye.radius"),
        ("[camera]\nwidth_px = 5000.5", "camera.width_px"),
        ("[camera]\nwidth_px = 0", "camera.width_px"),
        ("[camera]\ndistance_mm = 20.0", "camera.distance_mm"),
        ("[camera]\nfocal_length_mm = -300.0", "camera.focal_length_mm"),
        ("[camera]\nfocal_length_mm = 1e308", "camera.focal_length_mm"),  # issue 20: a degenerate camera
        ("[camera]\nsensor_width_mm = 1e-308", "camera.focal_length_mm / camera.sensor_width_mm"),
        ("[camera]\ndistance_mm = 1e300", "camera.distance_mm"),
        ("[instrument]\nbeam_half_angle_deg = 0.0", "instrument.beam_half_angle_deg"),
        ("[instrument]\nbeam_half_angle_deg = 45.0", "instrument.beam_half_angle_deg"),
        ("[instrument]\nbeam_half_angle_deg = 60.0", "instrument.beam_half_angle_deg"),
        ("[instrument]\nbeam_count = 2", "instrument.beam_count"),
        ("[instrument]\ninsertion_point_mm = [0.0, 6.0]", "instrument.insertion_point_mm"),
        ("[instrument]\ninsertion_point_mm = [0.0, 60.0, 20.0]", "instrument.insertion_point_mm"),
        ("[light]\nblend = 1.5", "light.blend"),
        ("[light]\npower_w = -1.0", "light.power_w"),
        ("[render]\ntexture = 'marble'", "render.texture"),
        ("[world]\neye_radius_mm = -2.0", "world.eye_radius_mm"),
        ("[world]\nbumps = [{x_mm = 0.0, y_mm = 0.0, radius_mm = -1.0}]", "world.bumps.radius_mm"),
        ("[world]\nbumps = [{x_mm = 0.0}]", "world.bumps"),
        ("[world]\nsurface = 'cube'", "world.surface"),
        ("[world]\nsurface = 'plane'\nbumps = [{x_mm = 0.0, y_mm = 0.0}]", "world.bumps"),
        ("[instrument]\nheight_correction = 3.0", "instrument.height_correction"),
        ("[instrument]\nedge_half_angle_deg = 0.0", "instrument.edge_half_angle_deg"),
        ("[instrument]\nedge_half_angle_deg = 'wide'", "instrument.edge_half_angle_deg"),
        ("[instrument]\nlight_radius_mm = -0.01", "instrument.light_radius_mm"),
        ("[instrument]\nlight_radius_mm = 1.0", "instrument.light_radius_mm"),
        ("[instrument]\nlight_radius_mm = nan", "instrument.light_radius_mm"),
        ("[faults]\nshaft = 1", "faults.shaft"),
        ("[instrument]\nshaft_diameter_mm = -0.1", "instrument.shaft_diameter_mm"),
        ("[faults]\nglints = -1", "faults.glints"),
        ("[faults]\nglints = 2.5", "faults.glints"),
        ("[faults]\nvessels = 101", "faults.vessels"),
        ("[faults]\nvessel_contrast = 1.5", "faults.vessel_contrast"),
        ("[faults]\nstray_light = nan", "faults.stray_light"),
        ("[faults]\nmotion_blur_px = -3.0", "faults.motion_blur_px"),
        ("[faults]\nsmoke = 1", "faults.smoke"),
        ("[camera]\naperture_mm = -1.0", "camera.aperture_mm"),
        ("[camera]\naperture_mm = 2000.0", "camera.aperture_mm"),
        ("[camera]\naperture_mm = 'wide'", "camera.aperture_mm"),
        ("[camera]\nfocus_distance_mm = 0.0", "camera.focus_distance_mm"),
        ("[camera]\nfocus_distance_mm = nan", "camera.focus_distance_mm"),
        ("[calibration]\naperture_sigma_mm = -0.5", "calibration.aperture_sigma_mm"),
        ("[tip]\nx = 1", "[tip]"),
        ("eye = 3", "[eye]"),
        ("[eye\nradius_mm = 1", "not valid TOML"),
    ],
)
def test_bad_values_name_the_key(text: str, key: str) -> None:
    with pytest.raises(SetupError) as error:
        setup_from_toml(text)
    message = str(error.value)
    assert key in message
    assert "\n" not in message


def test_range_is_stated() -> None:
    with pytest.raises(SetupError, match=r"allowed \(0, 45\)"):
        setup_from_toml("[instrument]\nbeam_half_angle_deg = 50.0")


def test_camera_inside_the_true_eye_is_rejected() -> None:
    with pytest.raises(SetupError, match=r"world\.eye_radius_mm"):
        setup_from_toml("[camera]\ndistance_mm = 26.0\n[world]\neye_radius_mm = 13.5")


def test_setup_is_immutable() -> None:
    setup = Setup()
    with pytest.raises(AttributeError):
        setup.eye.radius_mm = 3.0  # type: ignore[misc]


def test_a_setup_hashes_as_its_values_and_pickles_without_its_kept_hash() -> None:
    # The hash is kept after its first use (the per-setup caches ask on every frame); equal setups built apart
    # hash alike, and a pickle (a worker process, whose strings hash otherwise) carries no hash to go stale.
    setup = setup_from_toml('[camera]\nresponse = "linear"\n[eye]\nradius_mm = 12.0\n')
    again = setup_from_toml('[camera]\nresponse = "linear"\n[eye]\nradius_mm = 12.0\n')
    assert hash(setup) == hash(again) and hash(setup.camera) == hash(again.camera)
    assert hash(setup) != hash(replace(setup, eye=replace(setup.eye, radius_mm=12.5)))
    assert {setup: 1}[again] == 1
    copy = pickle.loads(pickle.dumps(setup))
    assert "_hash" in setup.__dict__ and "_hash" in setup.camera.__dict__
    assert "_hash" not in copy.__dict__ and "_hash" not in copy.camera.__dict__
    assert copy == setup and hash(copy) == hash(setup)


def test_contains_point() -> None:
    setup = Setup()
    assert setup.contains_point([0.0, 0.0, 5.0])
    assert not setup.contains_point([0.0, 0.0, -0.1])
    assert not setup.contains_point([0.0, 0.0, 0.5], margin_mm=1.0)


values = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=5),
    st.lists(st.floats(-100, 100), max_size=4),
)


@given(
    section=st.sampled_from(["eye", "camera", "instrument", "light", "world", "render", "faults"]),
    key=st.sampled_from(
        [
            "radius_mm",
            "width_px",
            "distance_mm",
            "beam_half_angle_deg",
            "beam_count",
            "insertion_point_mm",
            "power_w",
            "blend",
            "eye_radius_mm",
            "supersampling",
            "texture",
            "surface",
            "height_correction",
            "edge_half_angle_deg",
            "shaft",
            "glints",
            "stray_light",
            "bogus",
        ]
    ),
    value=values,
)
def test_any_value_builds_or_raises_setup_error(section: str, key: str, value: object) -> None:
    data = {section: {key: value}} if value is not None else {section: {}}
    try:
        setup = setup_from_dict(data)
    except SetupError as error:
        assert str(error)
    else:
        assert isinstance(setup, Setup)


CALIBRATED = """
[camera]
width_px = 1024
height_px = 1024
matrix = [[8567.5, 0.0, 511.5], [0.0, 8567.5, 511.5], [0.0, 0.0, 1.0]]
distortion = [-3.0, 0.0, 0.0, 0.0, 0.0]
rotation = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
translation_mm = [-0.25, -0.35, 110.6]
"""


def test_a_calibrated_camera_is_read() -> None:
    camera = setup_from_toml(CALIBRATED).camera
    assert camera.is_calibrated and camera.focal_length_mm is None and camera.distance_mm is None
    assert camera.focal_px == 8567.5
    assert camera.distortion == (-3.0, 0.0, 0.0, 0.0, 0.0)
    np.testing.assert_allclose(camera.center_in_eye, (0.25, -0.35, 110.6))


@pytest.mark.parametrize(
    ("change", "key"),
    [
        (("distortion = [-3.0, 0.0, 0.0, 0.0, 0.0]", "distortion = [-3.0, 0.0, 0.0]"), "camera.distortion"),
        (("[0.0, 8567.5, 511.5]", "[0.5, 8567.5, 511.5]"), "camera.matrix"),
        (("[[8567.5, 0.0, 511.5]", "[[-1.0, 0.0, 511.5]"), "camera.matrix[0][0]"),
        (("[0.0, 8567.5, 511.5]", "[0.0, 8567.5, 2000.0]"), "camera.matrix[1][2]"),
        (("[0.0, -1.0, 0.0]", "[0.0, -1.1, 0.0]"), "camera.rotation"),
        (("[0.0, 0.0, -1.0]]", "[0.0, 0.0, 1.0]]"), "camera.rotation"),
        (("translation_mm = [-0.25, -0.35, 110.6]", ""), "camera.translation_mm is missing"),
        (("translation_mm = [-0.25, -0.35, 110.6]", "translation_mm = [-0.25, -0.35, -110.6]"), "camera"),
        (("translation_mm = [-0.25, -0.35, 110.6]", "translation_mm = [-0.25, -0.35, 20.0]"), "inside the eye"),
        (("height_px = 1024", "height_px = 1024\ndistance_mm = 110.0"), "camera.distance_mm cannot be given"),
    ],
)
def test_a_bad_calibrated_camera_names_the_key(change: tuple[str, str], key: str) -> None:
    with pytest.raises(SetupError, match=re.escape(key)):
        setup_from_toml(CALIBRATED.replace(*change))


def test_uncertainty_and_calibration_sections() -> None:
    setup = setup_from_toml("[uncertainty]\ncamera_rotation_deg = 0.1\n")
    assert setup.uncertainty.camera_rotation_deg == 0.1 and setup.uncertainty.insertion_point_mm == 0.5
    text = (
        '[calibration]\nparameters = ["camera_x_mm", "eye_radius_mm"]\ncovariance = [[0.01, 0.001], [0.001, 0.04]]\n'
        'fitted = ["camera_x_mm"]\nrms_deg = 0.02\nframes = 10\nframe_edge_sigma_deg = 0.01\n'
    )
    record = setup_from_toml(text).calibration
    assert record.parameters == ("camera_x_mm", "eye_radius_mm") and record.covariance[1] == (0.001, 0.04)
    for bad, key in (
        ("0.001], [0.002", "symmetric"),
        ("[[0.01, 0.001], [0.001, 0.04]]", "positive semi-definite"),
        ('"camera_x_mm", "eye_radius_mm"]\ncov', "calibration.covariance must be 1 rows"),
        ("camera_x_mm", "is not a known parameter"),
    ):
        changed = {
            "symmetric": text.replace("0.001], [0.001", "0.001], [0.002"),
            "positive semi-definite": text.replace("[[0.01, 0.001], [0.001, 0.04]]", "[[0.01, 0.5], [0.5, 0.04]]"),
            "calibration.covariance must be 1 rows": text.replace(
                '["camera_x_mm", "eye_radius_mm"]\ncov', '["camera_x_mm"]\ncov'
            ),
            "is not a known parameter": text.replace('fitted = ["camera_x_mm"]', 'fitted = ["lens"]'),
        }[key]
        assert bad
        with pytest.raises(SetupError, match=re.escape(key)):
            setup_from_toml(changed)
    with pytest.raises(SetupError, match=r"uncertainty\.eye_radius_mm"):
        setup_from_toml("[uncertainty]\neye_radius_mm = -1.0\n")


def test_a_lens_s_depth_of_field_is_read_and_a_setup_without_one_reads_as_before() -> None:
    plain = setup_from_toml("")
    assert plain.camera.aperture_mm is None and plain.camera.lens_aperture_mm == 0.0
    assert plain.camera.focus_depth_mm == pytest.approx(plain.camera.distance_mm)  # the pole's depth
    lens = "[camera]\naperture_mm = 12.5\nfocus_distance_mm = 108\n"
    setup = setup_from_toml(lens + "[calibration]\naperture_sigma_mm = 0.4")
    assert setup.camera.aperture_mm == 12.5 and setup.camera.focus_depth_mm == 108.0
    assert setup.calibration.aperture_sigma_mm == 0.4
    # A calibrated camera keeps the lens; its default focus is its own depth of the pole.
    calibrated = replace(setup.camera, focus_distance_mm=None).as_calibrated()
    assert calibrated.aperture_mm == 12.5 and calibrated.focus_depth_mm == pytest.approx(110.0)
    assert setup.camera.resized(512, 512).aperture_mm == 12.5
