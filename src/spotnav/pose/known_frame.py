"""A calibration frame at a known pose and its light read there: the find and read stages of the one frame pipeline.

With the tip known (a robot reports it, and often the instrument's axis too),
the spots found on the frame are told apart by that pose and the roll they
show, and each one's edge is read with its beam's light model
(:func:`spotnav.pose.pipeline.read_light`). :func:`read_known_frame` returns one
result, :class:`KnownFrameEdges`, whose status says why a frame cannot be used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spotnav.optics.camera import unproject_pixels_to_sphere
from spotnav.pose.checks import check_image_size
from spotnav.pose.estimate import STATUSES, PoseEstimate
from spotnav.pose.pipeline import LightReading, plan_found_spots, read_light
from spotnav.pose.precise import detect_spots
from spotnav.setup.config import Setup
from spotnav.setup.geometry import assign_beams, normalize
from spotnav.setup.sections import check_localized_beams

__all__ = ["FIND_RADIUS_PX", "RAYS", "KnownFrame", "KnownFrameEdges", "read_known_frame"]

# One ray per pixel of each spot's outline (up to this many): calibration pools its frames' edges into the geometry,
# where more points do tell (a frame's own fit reads at most 256).
RAYS = 2048
# The spots are found on a frame shrunk less than a frame's own detection shrinks it (precise._FIND_SPOT_RADIUS_PX):
# the outlines place the rays, and the calibration, which every later frame carries, keeps the finer placement.
FIND_RADIUS_PX = 6.0


@dataclass(frozen=True)
class KnownFrame:
    """A calibration frame and where the instrument was.

    Attributes
    ----------
    name : str
        For messages.
    image : ndarray
        The frame, sRGB-encoded RGB or grey.
    tip_in_eye : ndarray, shape (3,)
        The known tip, mm.
    axis : ndarray, shape (3,), or None
        The known instrument axis; ``None``: from the insertion point to the tip.
    """

    name: str
    image: np.ndarray
    tip_in_eye: np.ndarray
    axis: np.ndarray | None = None


@dataclass(frozen=True)
class KnownFrameEdges:
    """A known frame's light read (:func:`read_known_frame`) at its known tip and axis and the roll its spots show,
    or why the frame cannot be used.

    Attributes
    ----------
    status : str
        ``ok``, or one of :data:`~spotnav.pose.estimate.STATUSES` saying why the frame cannot be used.
    tip : ndarray, shape (3,)
        The known tip, mm.
    axis : ndarray, shape (3,)
        The known instrument axis (unit), or the one from the insertion point to the tip.
    spots : int
        Spots found.
    detail : str
        Why the frame cannot be used, naming it; empty when ``ok``.
    reading : LightReading or None
        Each spot's edge as read; ``None`` unless ``status == "ok"``.
    roll : float
        Three beams: the roll the spots show, radians (0 for one beam).
    """

    status: str
    tip: np.ndarray
    axis: np.ndarray
    spots: int = 0
    detail: str = ""
    reading: LightReading | None = None
    roll: float = 0.0

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {STATUSES}, got {self.status!r}")
        if (self.status == "ok") != (self.reading is not None):
            raise ValueError("a reading is given exactly when status is 'ok'")

    @property
    def ok(self) -> bool:
        """Whether the frame's edges were read."""
        return self.status == "ok"

    def light(self) -> LightReading:
        """The light read on an ``ok`` frame.

        Raises
        ------
        ValueError
            For a frame that was not read (a bug in the caller: check :attr:`ok` first).
        """
        if self.reading is None:
            raise ValueError(f"a {self.status!r} frame has no reading")
        return self.reading

    @property
    def edges_px(self) -> tuple[np.ndarray, ...]:
        """Each spot's sub-pixel edge points, pixels (an ``ok`` frame's)."""
        return self.light().edges_px

    @property
    def beams(self) -> tuple[int, ...]:
        """The beam that made each spot (an ``ok`` frame's)."""
        return self.light().beams


def read_known_frame(frame: KnownFrame, setup: Setup) -> KnownFrameEdges:
    """The frame's pipeline up to its fit: the find stage from the known pose (its spots, the beam of each and the
    starting roll) and the spots' light read (:func:`spotnav.pose.pipeline.read_light`); or, as its status, why the
    frame cannot be used (its detail names the frame).

    Raises
    ------
    SetupError
        For 2 or 4 beams (simulation only, :func:`~spotnav.setup.sections.check_localized_beams`).
    """
    instrument = setup.instrument
    check_localized_beams(instrument)
    tip = np.asarray(frame.tip_in_eye, dtype=float)
    axis = normalize(frame.axis if frame.axis is not None else tip - instrument.insertion_in_eye)
    wrong = check_image_size(frame.image, setup)
    if wrong is not None:
        return _refused(wrong, frame, tip, axis)
    detection = detect_spots(frame.image, setup, FIND_RADIUS_PX)
    spots = detection.spots
    whole = [spot for spot in spots if not spot.touches_border]
    if len(spots) != instrument.beam_count or len(whole) != len(spots):
        cut = f", {len(spots) - len(whole)} cut by the border" if len(whole) != len(spots) else ""
        status = "clipped" if cut else "ambiguous" if len(spots) > instrument.beam_count else "too_few_spots"
        detail = f"{frame.name}: {detection.regions}{cut}, {instrument.beam_count} beams"
        return KnownFrameEdges(status, tip, axis, spots=len(spots), detail=detail)
    beams, roll = [0], 0.0
    if len(spots) > 1:
        centres = np.array(
            [
                unproject_pixels_to_sphere(setup.camera, spot.contour_px.mean(axis=0), setup.eye.radius_mm)
                for spot in spots
            ]
        )
        # Around their centroid, not the tip: a camera that is not where the setup says moves them all alike.
        assignment = assign_beams(centres - centres.mean(axis=0), axis)
        if not assignment.ok:
            detail = f"{frame.name}: cannot tell which spot each beam made"
            return KnownFrameEdges(assignment.status, tip, axis, spots=len(spots), detail=detail)
        beams, roll = list(assignment.beams), assignment.roll
    # Each spot's edge is read knowing its beam: where the spot clips, the beam's soft band is the light's model.
    reading = read_light(frame.image, setup, plan_found_spots(setup, spots, beams, tip, axis, roll, RAYS))
    if isinstance(reading, PoseEstimate):
        return _refused(reading, frame, tip, axis)
    return KnownFrameEdges("ok", tip, axis, spots=len(spots), reading=reading, roll=roll)


def _refused(refusal: PoseEstimate, frame: KnownFrame, tip: np.ndarray, axis: np.ndarray) -> KnownFrameEdges:
    """A pipeline stage's refusal as the known frame's status, its detail naming the frame."""
    return KnownFrameEdges(refusal.status, tip, axis, spots=refusal.spots, detail=f"{frame.name}: {refusal.detail}")
