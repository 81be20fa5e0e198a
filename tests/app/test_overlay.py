from __future__ import annotations

import numpy as np
from conftest import small_setup

from spotnav.app.overlay import View, box_around, cone_edge_px, crop_box, draw_overlay
from spotnav.optics.camera import project_points
from spotnav.optics.render import Renderer
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.localize import Cone, SpotDetail, localize_detailed
from spotnav.setup.geometry import InstrumentPose

GREEN, CYAN, YELLOW = (0, 220, 0), (0, 230, 255), (255, 255, 0)


def _count(canvas: np.ndarray, colour: tuple[int, int, int]) -> int:
    return int(np.all(canvas == colour, axis=2).sum())


def test_the_overlay_draws_the_edge_the_cones_the_tip_and_leaves_the_frame_alone() -> None:
    setup = small_setup(512, blend=0.15)
    pose = InstrumentPose.through_insertion(np.array([0.5, 0.5, 4.0]), setup.instrument.insertion_in_eye)
    image = Renderer(setup).render(pose, seed=1)
    before = image.copy()
    result = localize_detailed(image, setup)
    assert result.estimate.ok
    canvas = draw_overlay(image, setup, result.estimate, spots=result.spots, cones=result.cones, label="frame 7")
    np.testing.assert_array_equal(image, before)
    assert canvas.shape == image.shape and canvas.dtype == np.uint8
    assert _count(canvas, GREEN) > 50 and _count(canvas, YELLOW) > 5
    cones_only = draw_overlay(image, setup, result.estimate, cones=result.cones)
    assert _count(cones_only, CYAN) > 100 and _count(cones_only, GREEN) == 0
    # The green points sit on the spot's edge: between its bright inside and the dark outside.
    green = np.argwhere(np.all(canvas == GREEN, axis=2))
    brightness = image.astype(float).mean(axis=2)
    centre = green.mean(axis=0)
    inside = brightness[tuple(np.round(centre + 0.8 * (green - centre)).astype(int).T)]
    outside = brightness[tuple(np.clip(np.round(centre + 1.2 * (green - centre)).astype(int), 0, 511).T)]
    assert np.median(inside) > 2 * np.median(outside)
    x0, y0, x1, y1 = crop_box(setup, result)
    assert 0 <= x0 < centre[1] < x1 <= 512 and 0 <= y0 < centre[0] < y1 <= 512 and (x1 - x0) < 256


def test_a_frame_without_a_pose_shows_its_status_and_no_cone() -> None:
    setup = small_setup(256)
    image = np.zeros((256, 256), np.uint16)
    refused = PoseEstimate("no_spot", detail="nothing bright")
    canvas = draw_overlay(image, setup, refused)
    assert canvas.shape == (256, 256, 3) and _count(canvas, CYAN) == 0 and _count(canvas, YELLOW) == 0
    assert canvas.max() > 0  # the status text


def test_a_cone_whose_apex_lies_outside_the_eye_has_no_edge_to_draw() -> None:
    setup = small_setup(256)
    radius = setup.eye.radius_mm
    outside = Cone(setup.eye.center_in_eye + np.array([0.0, 0.0, radius + 1.0]), np.array([0.0, 0.0, -1.0]), 9.0)
    on_the_wall = Cone(setup.eye.center_in_eye + np.array([0.0, 0.0, radius]), np.array([0.0, 0.0, -1.0]), 9.0)
    inside = Cone(np.array([0.0, 0.0, 4.0]), np.array([0.0, 0.0, -1.0]), 9.0)
    assert cone_edge_px(setup, outside).shape == cone_edge_px(setup, on_the_wall).shape == (0, 2)
    assert len(cone_edge_px(setup, inside)) > 0


def test_a_view_enlarges_its_box_by_a_whole_factor_and_maps_pixel_centres() -> None:
    view = View.enlarged((100, 50, 180, 110), (512, 512))
    assert view.zoom == 3  # 80 px: within half the frame, 256 // 80 = 3
    assert View.enlarged((100, 50, 180, 110), (5000, 5000)).zoom == 10  # within 800 px
    assert View.enlarged((0, 0, 300, 40), (512, 512)).zoom == 1
    frame = np.arange(512 * 512 * 3, dtype=np.uint32).reshape(512, 512, 3).astype(np.uint8)
    canvas = view.cut(frame)
    assert canvas.shape == (60 * 3, 80 * 3, 3)
    # A frame pixel's centre lands in the middle of its 3 x 3 block, which holds that pixel's value.
    u, v = np.round(view.to_canvas(np.array([123.0, 77.0]))).astype(int)
    assert np.array_equal(canvas[v, u], frame[77, 123]) and (u, v) == ((123 - 100) * 3 + 1, (77 - 50) * 3 + 1)


def test_a_box_around_points_has_room_for_the_text_and_stays_inside_the_frame() -> None:
    assert box_around([np.array([[200.0, 200.0], [260.0, 260.0]])], (512, 512)) == (110, 110, 350, 350)
    assert box_around([np.array([[0.0, 500.0], [3.0, 511.0]])], (512, 512)) == (0, 271, 241, 512)  # moved in
    assert box_around([np.array([[np.nan, 1.0]])], (512, 256)) == (0, 0, 512, 256)  # nothing to frame


def test_the_cones_edge_is_drawn_above_edge_points_that_lie_on_it() -> None:
    setup = small_setup(256)
    cone = Cone(np.array([0.0, 0.0, 4.0]), np.array([0.0, 0.0, -1.0]), 9.0)
    curve = cone_edge_px(setup, cone)
    on_it = SpotDetail(0, curve, curve, np.ones(len(curve), bool), np.zeros(len(curve)))
    estimate = PoseEstimate("unreliable", detail="a test")
    canvas = draw_overlay(np.zeros((256, 256), np.uint8), setup, estimate, spots=[on_it], cones=[cone])
    pixels = np.round(curve).astype(int)
    assert np.all(canvas[pixels[:, 1], pixels[:, 0]] == CYAN, axis=1).mean() > 0.9
    assert _count(canvas, GREEN) > 50  # the points still show beside the line
    # A refused fit's cones place the tip's cross at their apex.
    u, v = np.round(project_points(setup.camera, cone.apex_in_eye)).astype(int)
    assert tuple(canvas[v, u]) == YELLOW
