from __future__ import annotations

import cv2
import numpy as np
import pytest
from conftest import small_setup

from spotnav.app.overlay import View, cone_edge_px
from spotnav.app.show import show_frame
from spotnav.app.status_style import status_style
from spotnav.optics.camera import project_points
from spotnav.optics.render import Renderer
from spotnav.setup.config import Setup
from spotnav.setup.geometry import InstrumentPose

GREEN, ORANGE, CYAN, YELLOW = (0, 220, 0), (255, 150, 0), (0, 230, 255), (255, 255, 0)
SIZE = 512


def _count(canvas: np.ndarray, colour: tuple[int, int, int]) -> int:
    return int(np.all(canvas == colour, axis=2).sum())


def _plain(image: np.ndarray, view: View) -> np.ndarray:
    """The same crop with nothing drawn on it."""
    return view.cut(image)


@pytest.fixture(scope="module")
def setup() -> Setup:
    return small_setup(SIZE, blend=0.15)


def _frame(setup: Setup, tip: list[float]) -> np.ndarray:
    pose = InstrumentPose.through_insertion(np.array(tip), setup.instrument.insertion_in_eye)
    return Renderer(setup).render(pose, seed=1)


def _crop_is_smaller(shown_view: View, canvas: np.ndarray) -> None:
    x0, y0, x1, y1 = shown_view.box
    assert (x1 - x0) < SIZE / 2 and (y1 - y0) < SIZE / 2  # a part of the frame ...
    assert canvas.shape[0] <= SIZE and canvas.shape[1] <= SIZE  # ... enlarged, never past the frame's size
    assert canvas.shape[:2] == ((y1 - y0) * shown_view.zoom, (x1 - x0) * shown_view.zoom)


def test_show_crop_on_an_ok_frame_draws_the_tip_and_the_cone_above_the_points(setup: Setup) -> None:
    image = _frame(setup, [0.5, 0.5, 4.0])
    shown = show_frame(image, setup, crop=True)
    estimate = shown.localization.estimate
    assert estimate.ok and shown.note == ""
    canvas, view = shown.canvas, shown.view
    _crop_is_smaller(view, canvas)
    # The tip's cross is centred on the tip's projection.
    u, v = np.round(view.to_canvas(project_points(setup.camera, estimate.tip_in_eye))).astype(int)
    assert tuple(canvas[v, u]) == YELLOW
    # The cone is drawn above the edge points: along its projected edge, cyan, with green beside it.
    assert _count(canvas, CYAN) > 100 and _count(canvas, GREEN) > 100
    curve = np.round(view.to_canvas(cone_edge_px(setup, shown.localization.cones[0]))).astype(int)
    on_curve = np.all(canvas[curve[:, 1], curve[:, 0]] == CYAN, axis=1)
    assert on_curve.mean() > 0.9
    # The status, on a dark box after ok's colour; the frame's own pixels elsewhere.
    assert tuple(canvas[8, 8]) == status_style("ok").rgb
    plain = _plain(np.asarray(image), view)
    assert np.array_equal(canvas[-3:, -3:], plain[-3:, -3:])


def test_show_crop_on_a_blurred_frame_crops_around_the_edges_it_read_and_says_why(setup: Setup) -> None:
    sharp = _frame(setup, [0.5, 0.5, 4.0])
    image = cv2.GaussianBlur(sharp, (0, 0), 2.0)
    shown = show_frame(image, setup, crop=True)
    assert shown.localization.estimate.status == "blurred"
    canvas, view = shown.canvas, shown.view
    _crop_is_smaller(view, canvas)
    # The edges the pipeline read before it refused, around the same spot as the sharp frame's.
    assert len(shown.spots) == 1 and len(shown.spots[0].edge_px) > 100
    assert _count(canvas, ORANGE) > 200 and _count(canvas, CYAN) == 0 and _count(canvas, YELLOW) == 0
    sharp_box = show_frame(sharp, setup, crop=True).view.box
    centre = np.mean(shown.spots[0].edge_px, axis=0)
    assert sharp_box[0] < centre[0] < sharp_box[2] and sharp_box[1] < centre[1] < sharp_box[3]
    assert shown.note == "orange: the edges read, not fitted"
    # The status text: where it is drawn, the picture is not the plain crop's.
    plain = _plain(image, view)
    text_rows = slice(0, 40)
    assert np.abs(canvas[text_rows].astype(int) - plain[text_rows]).mean() > 5
    assert tuple(canvas[8, 8]) == status_style("blurred").rgb


def test_show_crop_on_a_spot_off_the_fundus_crops_around_its_outline(setup: Setup) -> None:
    image = _frame(setup, [5.5, 0.0, 4.0])
    shown = show_frame(image, setup, crop=True)
    assert shown.localization.estimate.status == "clipped"
    _crop_is_smaller(shown.view, shown.canvas)
    assert shown.note == "orange: the spots' outlines, not read" and _count(shown.canvas, ORANGE) > 50
    assert tuple(shown.canvas[8, 8]) == status_style("clipped").rgb


def test_show_crop_without_a_spot_shows_the_whole_frame_and_says_so(setup: Setup) -> None:
    image = np.full((SIZE, SIZE, 3), 5, np.uint8)
    shown = show_frame(image, setup, crop=True)
    assert shown.localization.estimate.status == "no_spot" and shown.spots == ()
    assert shown.view == View((0, 0, SIZE, SIZE)) and shown.canvas.shape == (SIZE, SIZE, 3)
    assert "no spot" in shown.note and "nothing to crop around" in shown.note
    assert np.abs(shown.canvas[:40].astype(int) - 5).mean() > 5  # the text
