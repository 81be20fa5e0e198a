"""What a sequence of frames says about the setup that no single frame can: where the instrument's axes meet.

A one-beam frame fitted through the insertion point bends no edge when that
point (or the camera) is not where the setup says: the fit slides the tip
along its line. But the instrument pivots about the true insertion point, so
the axes fitted freely (:func:`axis_line`, the precise method's cross-check)
of a moving instrument all pass through it. :class:`AxesMeeting` keeps the
weighted least-squares point where every line heard so far crosses the plane
through the setup's insertion point across them, in running sums (constant
time a frame), and says once, when that point lies further from the insertion
point than the lines' scatter explains, which quantity does not fit and the
command that calibrates it.

It hears a pose, not a frame. A free axis errs by what its edge model misses
(the fundus and the pixels under the edge) as much as by the frame's noise, and
that part is the pose's: the lines of two frames whose tips lie 0.03 mm apart
share 40-55 % of their error, 0.1-0.3 mm apart 7-14 %, 0.5 mm apart none (a
helix tracked at 512 px, one beam, 1000 and 3000 frames). Lines of one pose
averaged over many frames keep that error, so their meeting point's sigma,
shrinking as one over the root of the frames, fell below it: 19 frames of a
3000-frame helix (0.2 mm of it) passed 0.80 mm from the true insertion point, 6
sigma. So a line is heard only when its pose's tip lies :data:`POSE_SPACING_MM`
or more from every tip heard before: the lines heard are independent, their
scatter (the reduced chi-square) is their whole error, and the sigma shrinks
with the poses visited, never with the frames a still hand adds. The tips heard
are kept in cells of that size: memory bounded by the eye's working volume.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spotnav.pose.conefit.solution import ConeSolution
from spotnav.setup.config import Setup

__all__ = ["MEETING_SIGMAS", "MIN_LINES", "POSE_SPACING_MM", "AxesMeeting", "AxisLine", "axis_line"]

MIN_LINES = 10  # lines (poses) before the test may speak: a few poses' axes barely span the pivot
POSE_SPACING_MM = 0.5  # tips closer than this share their lines' edge-model error (the module's docstring)
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
    spacing_mm : float
        A pose is heard only this far (mm) from every tip heard before; 0: every frame is heard, as if each
        frame's line had an error of its own.

    Attributes
    ----------
    lines : int
        The lines heard: one a pose, each tip :attr:`spacing_mm` or more from the others.
    verdict : str
        Empty until the test speaks, then what it said.
    """

    setup: Setup
    spacing_mm: float = POSE_SPACING_MM
    lines: int = field(default=0, init=False)
    verdict: str = field(default="", init=False)
    _normal: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)), init=False, repr=False)
    _right: np.ndarray = field(default_factory=lambda: np.zeros(3), init=False, repr=False)
    _square: float = field(default=0.0, init=False, repr=False)
    _heard: dict[tuple[int, int, int], list[np.ndarray]] = field(default_factory=dict, init=False, repr=False)

    def is_new(self, tip_in_eye: np.ndarray) -> bool:
        """Whether a pose with its tip here (mm, eye frame) would be heard: no tip heard lies within
        :attr:`spacing_mm` of it (and the test has not spoken). Cheap: ask before fitting the line."""
        tip = np.asarray(tip_in_eye, dtype=float)
        if self.verdict or not np.all(np.isfinite(tip)):
            return False
        if self.spacing_mm <= 0.0:
            return True
        cell = self._cell(tip)
        for step in np.ndindex(3, 3, 3):
            key = (cell[0] + step[0] - 1, cell[1] + step[1] - 1, cell[2] + step[2] - 1)
            if any(np.sum((heard - tip) ** 2) < self.spacing_mm**2 for heard in self._heard.get(key, ())):
                return False
        return True

    def _cell(self, tip: np.ndarray) -> tuple[int, int, int]:
        """The cell of side :attr:`spacing_mm` that holds a tip: a tip heard within the spacing lies in it or one
        of its 26 neighbours."""
        x, y, z = (int(v) for v in np.floor(tip / self.spacing_mm))
        return x, y, z

    def add(self, line: AxisLine, pose_tip: np.ndarray | None = None) -> str:
        """Add one frame's line if its pose is new (:meth:`is_new`); return the verdict when this line makes the
        test speak, else ``""``.

        Once spoken, the test keeps its verdict (:attr:`verdict`) and adds no more lines.

        Parameters
        ----------
        line : AxisLine
        pose_tip : ndarray, shape (3,), optional
            Where the frame's pose puts the tip, mm, eye frame (the fit through the insertion point, more precise
            than the free fit's): the pose the line is heard for. Default: the line's own tip.
        """
        tip = np.asarray(line.tip_in_eye if pose_tip is None else pose_tip, dtype=float)
        if not self.is_new(tip):
            return ""
        insertion = self.setup.instrument.insertion_in_eye
        direction = np.asarray(line.axis, dtype=float)
        variance = float(np.sum((insertion - line.tip_in_eye) ** 2)) * line.angle_variance + line.tip_variance
        if not (np.isfinite(variance) and variance > 0.0 and np.all(np.isfinite(line.tip_in_eye))):
            return ""
        if self.spacing_mm > 0.0:
            self._heard.setdefault(self._cell(tip), []).append(tip)
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
            f"the instrument's axes over {self.lines} poses pass {distance:.2f} mm from the setup's insertion point "
            f"(at [{where}] mm, {sigmas:.0f} sigma): the insertion point or the camera is not where the setup says; "
            "calibrate them from frames at known poses with their axes (spotnav calibrate --poses known.csv, its "
            "dir_x, dir_y, dir_z given: the insertion point is where the axes meet)"
        )
