from __future__ import annotations

import itertools

import cv2
import numpy as np

from spotnav.app.status_style import STATUS_STYLES, status_style
from spotnav.pose.estimate import STATUSES

# Machado, Oliveira and Fernandes (2009): full dichromacy as a matrix on linear RGB.
DICHROMACIES = {
    "deuteranopia": [[0.367322, 0.860646, -0.227968], [0.280085, 0.672501, 0.047413], [-0.011820, 0.042940, 0.968881]],
    "protanopia": [[0.152286, 1.052583, -0.204868], [0.114503, 0.786281, 0.099216], [-0.003882, -0.048116, 1.051998]],
    "tritanopia": [[1.255528, -0.076749, -0.178779], [-0.078411, 0.930809, 0.147602], [0.004733, 0.691367, 0.303900]],
}


def _lab(rgb: tuple[int, int, int], seen: np.ndarray | None = None) -> np.ndarray:
    """CIELAB of an 8-bit sRGB colour, as a reader with the matrix ``seen`` (on linear RGB; default: none) sees it."""
    seen = np.eye(3) if seen is None else seen
    encoded = np.array(rgb) / 255.0
    linear = np.where(encoded <= 0.04045, encoded / 12.92, ((encoded + 0.055) / 1.055) ** 2.4)
    shown = np.clip(np.asarray(seen) @ linear, 0.0, 1.0)
    back = np.where(shown <= 0.0031308, 12.92 * shown, 1.055 * shown ** (1 / 2.4) - 0.055)
    return cv2.cvtColor(np.float32(back)[None, None], cv2.COLOR_RGB2Lab)[0, 0].astype(float)


def _hue_deg(rgb: tuple[int, int, int]) -> tuple[float, float]:
    hsv = cv2.cvtColor(np.float32(np.array(rgb) / 255.0)[None, None], cv2.COLOR_RGB2HSV)[0, 0]
    return float(hsv[0]), float(hsv[1])


def test_every_status_has_its_own_colour_and_marker_and_only_ok_is_green() -> None:
    assert tuple(STATUS_STYLES) == STATUSES
    styles = [status_style(s) for s in STATUSES]
    assert len({s.colour for s in styles}) == len(STATUSES)
    assert len({s.marker for s in styles[1:]}) == len(STATUSES) - 1
    # Visibly different: at least 20 CIELAB units apart (2.3 is a just-noticeable difference).
    nearest = min(np.linalg.norm(_lab(a.rgb) - _lab(b.rgb)) for a, b in itertools.combinations(styles, 2))
    assert nearest > 20
    hues = {s: _hue_deg(status_style(s).rgb) for s in STATUSES}
    assert [s for s, (hue, saturation) in hues.items() if 80 <= hue <= 170 and saturation > 0.3] == ["ok"]


def test_ok_stays_apart_from_every_refusal_for_a_colour_blind_reader() -> None:
    ok = status_style("ok").rgb
    for name, seen in DICHROMACIES.items():
        matrix = np.array(seen)
        gaps = {s: np.linalg.norm(_lab(ok, matrix) - _lab(status_style(s).rgb, matrix)) for s in STATUSES[1:]}
        assert min(gaps.values()) > 15, (name, min(gaps, key=gaps.__getitem__))


def test_a_status_this_version_does_not_know_gets_a_neutral_style() -> None:
    other = status_style("from_the_future")
    assert other.colour not in {s.colour for s in STATUS_STYLES.values()}
    assert status_style("blurred").rgb == (0x00, 0x72, 0xB2)
