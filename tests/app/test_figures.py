from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from spotnav.app.figures import plot_errors_by_status, plot_track_by_status
from spotnav.app.status_style import status_style


def _rgb(path: Path) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB).astype(int)


def _pixels_of(image: np.ndarray, status: str, tolerance: int = 0) -> int:
    return int((np.abs(image - np.array(status_style(status).rgb)).max(axis=2) <= tolerance).sum())


def test_errors_png_draws_each_status_in_its_own_colour(tmp_path: Path) -> None:
    statuses = ["ok", "blurred", "ok", "clipped", "no_spot", "ok", "blurred", "unreliable"]
    errors = np.array([0.01 if s == "ok" else np.nan for s in statuses])
    figure = tmp_path / "errors.png"
    plot_errors_by_status(figure, [f"f{i}.png" for i in range(len(statuses))], errors, statuses, "errors")
    image = _rgb(figure)
    for status in set(statuses):
        assert _pixels_of(image, status) > 20, status  # the frames' marks and the legend's
    absent = _pixels_of(image, "mismatch")
    assert absent == 0


def test_a_figure_of_blurred_frames_only_has_no_ok_green(tmp_path: Path) -> None:
    # The first user's report: a blurred frame drawn in ok's green.
    figure = tmp_path / "errors.png"
    plot_errors_by_status(figure, ["a.png", "b.png"], np.full(2, np.nan), ["blurred", "blurred"], "errors")
    image = _rgb(figure)
    assert _pixels_of(image, "blurred") > 20
    assert _pixels_of(image, "ok", tolerance=40) == 0


def test_track_png_marks_each_frame_by_its_status(tmp_path: Path) -> None:
    t = np.linspace(0.0, 2.0 * np.pi, 12)
    truth = np.column_stack([np.cos(t), np.sin(t), 4.0 + 0.1 * t])
    statuses = ["ok"] * 12
    statuses[3], statuses[7] = "blurred", "clipped"
    estimated = np.where(np.array([s == "ok" for s in statuses])[:, None], truth + 0.01, np.nan)
    figure = tmp_path / "track.png"
    plot_track_by_status(figure, truth, estimated, statuses, "track")
    image = _rgb(figure)
    for status in ("ok", "blurred", "clipped"):
        assert _pixels_of(image, status) > 10, status
