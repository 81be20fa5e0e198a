"""The example setups ``spotnav scene --example NAME [--exact]`` writes: a microscope's nominal setup with the
thesis's values (:data:`MICROSCOPE_EXAMPLES`), and the thesis's simulation, whose geometry is exact
(:data:`EXAMPLES`); each also exposed as the thesis's Figure 6.16 shows (:data:`THESIS_EXPOSURE_STOPS`).

Both give the same values; they differ in ``[uncertainty]``: a microscope's geometry is known to a real one's
tolerance until ``spotnav calibrate`` measures it, a simulation rendered from the file knows it exactly (every value
0), as the studies and tests do on purpose. Standard library only: the command line's parser imports it.
"""

from __future__ import annotations

__all__ = ["EXAMPLES", "EXAMPLE_SETUP", "MICROSCOPE_EXAMPLES", "MICROSCOPE_SETUP", "THESIS_EXPOSURE_STOPS"]

_GEOMETRY = """\
# Lengths in mm, angles in degrees. The eye frame has its origin at the pole
# (lowest point of the retina), +z up toward the camera.

[eye]
radius_mm = 12.5              # retina sphere, centred at (0, 0, radius_mm)

[camera]                      # pinhole at (0, 0, distance_mm) looking down -z
width_px = 5000
height_px = 5000
sensor_width_mm = 36.0
focal_length_mm = 300.0
distance_mm = 110.0           # height of the pinhole above the pole
# response = "srgb"           # pixel values against light: "srgb" (assumed), "linear", "agx" or a gamma
# A calibrated camera replaces the three keys above with OpenCV's (spotnav scene --opencv FILE writes them):
# matrix = [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]   # pixels
# distortion = [k1, k2, p1, p2, k3]                          # 4, 5, 8, 12 or 14 values
# rotation = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]  # eye frame to camera frame
# translation_mm = [0.0, 0.0, 110.0]                         # x_cam = rotation x_eye + translation

[instrument]
insertion_point_mm = [0.0, 6.0, 20.0]   # remote centre of motion
beam_half_angle_deg = 9.0     # cone half-angle (beta), in (0, 45)
beam_count = 1                # 1 or 3
beam_tilt_deg = 15.0          # tilt of each beam from the axis when beam_count = 3
height_correction = 1.0       # thesis method only: section 5.5 height factor, 1 = none
# edge_half_angle_deg = 8.656 # precise method's edge model (default: beta with Blender's blend 0.15)
# light_radius_mm = 0.0       # precise method's edge model: the light's emitting radius (0 = a point)
# edge_band_deg = 0.69        # precise method's light model: the soft band about the edge (default 2 (beta - edge))
shaft_diameter_mm = 0.6       # precise method: ignore the edge the shaft hides (0 = no shaft)

"""
"""Every section before ``[uncertainty]``: the eye, the camera and the instrument."""

_EXACT_UNCERTAINTY = """\
[uncertainty]                 # how well the geometry above is known (1 sigma): exactly, every value 0, as a
                              # simulation rendered from this very file knows it (spotnav scene --example --exact).
                              # A microscope's is not: spotnav scene --example states a real one's, and spotnav
                              # calibrate measures it from frames at known tips and writes [calibration].
edge_half_angle_deg = 0.0
light_radius_mm = 0.0
eye_radius_mm = 0.0
camera_rotation_deg = 0.0
camera_position_mm = 0.0
focal_length_percent = 0.0
principal_point_percent = 0.0
distortion_px = 0.0
insertion_point_mm = 0.0
beam_tilt_deg = 0.0

"""

_MICROSCOPE_UNCERTAINTY = """\
[uncertainty]                 # how well the geometry above is known before calibration (1 sigma): a real operating
                              # microscope's. The precise methods add it to every pose's sigma_mm and refuse a pose
                              # it leaves over 0.03 mm uncertain (uncalibrated). spotnav calibrate measures the
                              # geometry from frames with the tip at known points and writes [calibration], which
                              # replaces these values. Every value 0 would claim the geometry exactly, as only a
                              # simulation rendered from this file knows it (spotnav scene --example --exact).
edge_half_angle_deg = 0.3     # the beam's edge (its half-angle), deg
light_radius_mm = 0.05        # the light's emitting radius
eye_radius_mm = 0.25          # the retina's radius
camera_rotation_deg = 0.5     # the camera's rotation about each of its axes
camera_position_mm = 0.5      # the camera's centre along each axis
focal_length_percent = 1.0    # the camera's scale (focal length, magnification)
principal_point_percent = 1.0 # the principal point, per cent of the image's width
distortion_px = 5.0           # the lens's distortion at the middle of the image's edge, px
insertion_point_mm = 0.5      # the insertion point along each axis
beam_tilt_deg = 0.5           # the beams' tilt from the instrument's axis (three beams; one beam has none)

"""

_SIMULATOR = """\
[light]                       # simulator only, Blender's conventions
power_w = 1.0                 # radiant intensity power_w / (4 pi) W/sr on the axis
blend = 0.15                  # soft edge over the outer part of the cone, 0 = sharp

[world]                       # simulator only: where the world differs from [eye]
# eye_radius_mm = 13.5        # true retina radius (default: eye.radius_mm)
# bumps = [{ x_mm = 0.0, y_mm = 0.0, radius_mm = 0.25, height_mm = 0.1 }]
surface = "sphere"            # "sphere" (retina) or "plane" (z = 0, thesis section 6.2)

[render]                      # simulator only: the built-in renderer
exposure_stops = 0.0          # 0: white surface 5 mm below 1 W, facing it, is full scale
ambient = 0.004               # dim ambient light, fraction of full scale
full_well_e = 10000.0         # electrons at full scale (shot noise); 0 = no noise
read_noise_e = 8.0            # Gaussian read noise, electrons
supersampling = 4             # sub-samples per pixel side along the cone's edge
texture = "retina"            # "retina" (procedural fundus) or "flat"
texture_seed = 0
bit_depth = 8                 # 8 or 16 bits per channel
tone = "camera"               # "camera" (encode by camera.response) or "agx" (a tone curve like Blender's AgX)

[faults]                      # simulator only: disturbances, all off by default
shaft = false                 # draw the shaft (instrument.shaft_diameter_mm) from the tip to the insertion point
glints = 0                    # specular glints in and around the spot
vessels = 0                   # dark vessels drawn across the spot ...
vessel_contrast = 0.8         # ... absorbing this fraction of the light
stray_light = 0.0             # a second bright source beside the spot: peak in full scales (0 = none)
motion_blur_px = 0.0          # linear motion blur of the spot, pixels
dark_patch = 0.0              # a darker patch of fundus under part of the spot's edge: albedo it lacks (0 = none)
defocus_px = 0.0              # Gaussian blur of the light (defocus), sigma in pixels
frame_blur_px = 0.0           # Gaussian blur of the encoded frame (camera or codec), sigma in pixels
glow = 0.0                    # an endo-illuminator's broad uneven glow: peak, fraction of full scale (0 = none)
"""
"""The simulator's own sections: the light, the world, the renderer and the faults."""

# The exposure at which the thesis's spots saturate (docs/methods.md, "The thesis's exposure"): its Figure 6.16
# shows the spot at (0, 0, 8) mm brightening up to 0.5 W and no more from 1 W. A spot stops brightening when it
# is white, full scale in every channel: at 1 W the median of its centre's darkest channel (blue) reaches full
# scale at +4.44 stops on spotnav's retina (spotnav.experiments.gallery.saturating_exposure_stops), and
# the preset rounds that up to the half stop.
THESIS_EXPOSURE_STOPS = 4.5

_EXPOSURE = "exposure_stops = 0.0          # 0: white surface 5 mm below 1 W, facing it, is full scale\n"
_THESIS_EXPOSURE = (
    f"exposure_stops = {THESIS_EXPOSURE_STOPS}          # the thesis's: a spot 8 mm above the retina is white"
    " from 1 W up\n"
)
_THESIS_EXPOSURE_NOTE = (
    "# Exposed as the thesis's Figure 6.16 shows: the spot is saturated (white) from 1 W up. spotnav's default\n"
    "# world is not: it keeps the edge's light.\n"
)


def _examples(header: str, uncertainty: str) -> dict[str, str]:
    """The named examples with this ``header`` (comment lines) and ``[uncertainty]`` section."""
    thesis = _GEOMETRY + uncertainty + _SIMULATOR
    return {
        "thesis": header + thesis,
        "thesis-exposure": header + _THESIS_EXPOSURE_NOTE + thesis.replace(_EXPOSURE, _THESIS_EXPOSURE),
    }


MICROSCOPE_EXAMPLES = _examples(
    "# spotnav setup: a microscope's nominal values, the thesis's (Hennerkes 2020, Table 6.8). Write your\n"
    "# microscope's into it; spotnav calibrate measures, from frames with the tip at known points, how far the\n"
    '# real geometry is from them (README, "Use").\n',
    _MICROSCOPE_UNCERTAINTY,
)
"""Named example setups for a microscope: ``spotnav scene --example NAME``."""

MICROSCOPE_SETUP = MICROSCOPE_EXAMPLES["thesis"]
"""What ``spotnav scene --example`` writes: the thesis's values as a microscope's nominal setup."""

EXAMPLES = _examples(
    "# spotnav setup: the thesis's simulation (Hennerkes 2020, Table 6.8), its geometry known exactly.\n",
    _EXACT_UNCERTAINTY,
)
"""Named example setups for the simulation, geometry exact: ``spotnav scene --example NAME --exact``."""

EXAMPLE_SETUP = EXAMPLES["thesis"]
"""The thesis's simulation, geometry exact (``spotnav scene --example --exact``): the studies' and the tests'."""
