"""What a sequence of frames says about the setup that no single frame can: where the instrument's axes meet.

A one-beam frame fitted through the insertion point bends no edge when that
point (or the camera) is not where the setup says: the fit slides the tip
along its line. But the instrument pivots about the true insertion point, so
the axes fitted freely (:func:`axis_line`, the precise method's cross-check)
of a moving instrument all pass through it. :class:`AxesMeeting` keeps the
weighted least-squares point where every line seen so far crosses the plane
through the setup's insertion point across them, in running sums (constant
memory and time a frame), and says once, when that point lies further from the
insertion point than the lines' scatter explains, which quantity does not fit
and the command that calibrates it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spotnav.pose.conefit.solution import ConeSolution
from spotnav.setup.config import Setup

__all__ = ["MEETING_SIGMAS", "MIN_LINES", "AxesMeeting", "AxisLine", "axis_line"]

MIN_LINES = 10  # lines before the test may speak: a few frames' axes barely span the pivot
MEETING_SIGMAS = 5.0  # the meeting point this many of its sigmas from the setup's insertion point ...
_MIN_MISS_MM = 0.1  # ... and this far (mm) across the axes: a miss the tips would feel


@dataclass(frozen=True)
class AxisLine:
    """One frame's instrument axis fitted freely, as a line in the eye frame.

    Attributes
    ----------
    tip_in_eye : ndarray, shape (3,)
        A point of the line (the fitted tip), mm.
    axis : ndarray, shape (3,)
        Its unit direction.
    angle_variance : float
        The direction's variance about each of the two axes across it, rad^2.
    tip_variance : float
        The point's variance across the line, each of the two directions, mm^2.
    """

    tip_in_eye: np.ndarray
    axis: np.ndarray
    angle_variance: float
    tip_variance: float


def axis_line(free: ConeSolution) -> AxisLine:
    """A one-frame fit's free axis as a line (:func:`spotnav.pose.pipeline.refit_free_axis`, the precise method's
    cross-check), with its uncertainty."""
    about = free.frame_covariance((3, 4), geometry=False)
    # The angles about y and z: the second turns the axis by sin(about y) of itself.
    variance = 0.5 * (about[0, 0] + np.sin(free.frames[0, 3]) ** 2 * about[1, 1])
    return AxisLine(free.tip(), free.axis(), float(variance), float(np.trace(free.tip_covariance(geometry=False)) / 3))


@dataclass
class AxesMeeting:
    """A running test of where the instrument's axes meet, against the setup's insertion point.

    Each line ``i`` adds its projector across itself ``M_i = I - d_i d_i^T``
    over its variance ``s_i^2`` at the insertion point (its angle's times the
    squared distance, plus its point's) to ``A`` and ``M_i p_i / s_i^2`` to
    ``b``; the meeting point, held to the plane through the insertion point
    ``I`` across the lines (spanned by ``E``, ``A``'s two largest
    directions), is ``I + E (E^T A E)^-1 E^T (b - A I)``, and its covariance
    ``E (E^T A E)^-1 E^T`` times the lines' reduced chi-square where that is
    over 1 (lines that scatter more than their sigmas say).

    Parameters
    ----------
    setup : Setup
        Its ``instrument.insertion_in_eye`` is tested.
    """

    setup: Setup
    lines: int = field(default=0, init=False)
    verdict: str = field(default="", init=False)
    _normal: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)), init=False, repr=False)
    _right: np.ndarray = field(default_factory=lambda: np.zeros(3), init=False, repr=False)
    _square: float = field(default=0.0, init=False, repr=False)

    def add(self, line: AxisLine) -> str:
        """Add one frame's line; return the verdict when this line makes the test speak, else ``""``.

        Once spoken, the test keeps its verdict (:attr:`verdict`) and adds no more lines.
        """
        if self.verdict:
            return ""
        insertion = self.setup.instrument.insertion_in_eye
        direction = np.asarray(line.axis, dtype=float)
        variance = float(np.sum((insertion - line.tip_in_eye) ** 2)) * line.angle_variance + line.tip_variance
        if not (np.isfinite(variance) and variance > 0.0 and np.all(np.isfinite(line.tip_in_eye))):
            return ""
        across = (np.eye(3) - np.outer(direction, direction)) / variance
        self._normal += across
        self._right += across @ line.tip_in_eye
        self._square += float(line.tip_in_eye @ across @ line.tip_in_eye)
        self.lines += 1
        if self.lines < MIN_LINES:
            return ""
        self.verdict = self._judge(insertion)
        return self.verdict

    def meeting_point(self) -> tuple[np.ndarray, np.ndarray]:
        """Where the lines so far cross the plane through the setup's insertion point across their mean direction
        (mm, shape (3,)), and its covariance (3, 3), mm^2 (none along that direction).

        Along their own direction the lines of an instrument that pivots by a
        few degrees barely fix where they meet; across it they do.
        """
        across, shift, covariance = self._crossing()
        return self.setup.instrument.insertion_in_eye + across @ shift, across @ covariance @ across.T

    def _crossing(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The two directions across the lines (3, 2), the normal matrix's largest; the meeting point's shift from
        the insertion point along them (2,), mm; and its covariance (2, 2), mm^2."""
        insertion = self.setup.instrument.insertion_in_eye
        across = np.linalg.eigh(self._normal)[1][:, 1:]
        normal = across.T @ self._normal @ across
        shift = np.linalg.solve(normal, across.T @ (self._right - self._normal @ insertion))
        point = insertion + across @ shift
        chi_square = self._square - 2.0 * point @ self._right + point @ self._normal @ point
        scale = max(chi_square / max(2 * self.lines - 2, 1), 1.0)
        return across, shift, scale * np.linalg.inv(normal)

    def _judge(self, insertion: np.ndarray) -> str:
        """The verdict (``""``: the lines fit the setup's insertion point)."""
        across, shift, covariance = self._crossing()
        sigmas = float(np.sqrt(shift @ np.linalg.solve(covariance, shift)))
        distance = float(np.linalg.norm(shift))
        if sigmas <= MEETING_SIGMAS or distance <= _MIN_MISS_MM:
            return ""
        where = ", ".join(f"{v:.2f}" for v in insertion + across @ shift)
        return (
            f"the instrument's axes over {self.lines} frames pass {distance:.2f} mm from the setup's insertion point "
            f"(at [{where}] mm, {sigmas:.0f} sigma): the insertion point or the camera is not where the setup says; "
            "calibrate them from frames at known poses with their axes (spotnav calibrate --poses known.csv, its "
            "dir_x, dir_y, dir_z given: the insertion point is where the axes meet)"
        )
