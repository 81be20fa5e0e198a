"""A localize batch: ``localize``'s application, a list of images into ``poses.csv``.

:func:`localize_batch` localizes each image with a setup and a method and writes
its row as it is done; with ``fit_radius`` the precise method's frames wait for
one joint fit of the eye's radius (each frame's edges kept, not the frame), and
their rows are written after it. An image that cannot be read is a row with its
status, never a stop; SIGINT or SIGTERM stops after the image in hand (exit 130). It
returns a :class:`BatchResult` for the caller to print, with the batch's exit code: a
batch that could read none of its images (each ``unreadable`` or ``wrong_size``) did
not run, and says so in one line; one that read them exits 0 even if none has a pose,
as the contract says.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from spotnav.app.progress import progress
from spotnav.app.session import StopSignals, ready, to_stderr
from spotnav.errors import SpotnavError
from spotnav.files.images import ImageReadError, display_name, read_image
from spotnav.files.poses import PosesWriter, pose_row
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.localize import localize
from spotnav.pose.precise import EdgeFrame
from spotnav.pose.self_calibration import RadiusSelfCalibration, prepare_self_calibration, self_calibrate_radius
from spotnav.setup.config import Setup

__all__ = ["UNREAD", "BatchResult", "localize_batch"]

UNREAD = frozenset({"unreadable", "wrong_size"})  # the statuses of an image that was never localized


@dataclass
class BatchResult:
    """What a localize batch did.

    Attributes
    ----------
    out : Path
        The ``poses.csv`` written.
    rows : int
        Images written.
    statuses : Counter
        Images per status.
    stopped_by : str or None
        The signal that stopped the batch before its last image (None: it did them all).
    radius : RadiusSelfCalibration or None
        The joint radius fit (None without ``fit_radius``, or when stopped before it).
    """

    out: Path
    rows: int = 0
    statuses: Counter[str] = field(default_factory=Counter)
    stopped_by: str | None = None
    radius: RadiusSelfCalibration | None = None

    @property
    def exit_code(self) -> int:
        """130 when a signal stopped the batch (whatever its rows), 2 when it could read none of its images (each
        ``unreadable`` or ``wrong_size``), else 0."""
        if self.stopped_by:
            return 130
        return 2 if self.none_read else 0

    @property
    def none_read(self) -> bool:
        """Whether the batch could read none of its images (each ``unreadable`` or ``wrong_size``)."""
        return bool(self.rows) and set(self.statuses) <= UNREAD

    @property
    def all_failed(self) -> str | None:
        """One line when no image has a pose: how many, by status, and what to check; None when one has.

        ``spotnav: error: ...`` when none could be read (:attr:`none_read`: exit 2), ``spotnav: warning: ...`` when
        they were read and localized without a pose (exit 0: each row says why).
        """
        if not self.rows or self.statuses["ok"]:
            return None
        counts = ", ".join(f"{status}: {n}" for status, n in sorted(self.statuses.items()))
        if self.none_read:
            hint = "check the image files and the setup's camera.width_px and camera.height_px"
            return f"spotnav: error: none of the {self.rows} images could be localized ({counts}): {hint}"
        return f"spotnav: warning: no pose in any of the {self.rows} images ({counts}): each row's detail says why"


def localize_batch(
    images: Sequence[str],
    setup: Setup,
    method: str,
    out: str | Path,
    *,
    fit_radius: bool = False,
    report: Callable[[str], None] = to_stderr,
) -> BatchResult:
    """Localize ``images`` into ``out`` (``poses.csv``), a row each in their order.

    Parameters
    ----------
    images : sequence of str
        Image paths.
    setup : Setup
    method : str
        One of :data:`spotnav.pose.localize.METHODS`.
    out : str or Path
    fit_radius : bool
        Fit one eye radius with all the poses (precise method, at least 20 frames).
    report : callable
        Takes each warning during the run (default: stderr).

    Raises
    ------
    SpotnavError
        For ``fit_radius`` with a method other than precise, too few frames for the joint fit, or an output
        that cannot be written.
    """
    if fit_radius and method != "precise":
        raise SpotnavError("--fit-radius works with --method precise")
    result = BatchResult(Path(out))
    camera_size = (setup.camera.width_px, setup.camera.height_px)
    ready(setup)
    # fit_radius: rows wait for the joint fit; each frame's edges are kept, not the frame (memory).
    waiting: list[tuple[str, float]] = []
    done: dict[int, PoseEstimate] = {}
    shares: list[tuple[int, tuple[PoseEstimate, EdgeFrame | None]]] = []
    with StopSignals() as signals, PosesWriter(out) as writer:
        for name in progress(images, desc="localize", unit="image"):
            if signals.received:
                break
            start = time.perf_counter()
            try:
                image = read_image(name, expected_size=camera_size)
            except ImageReadError as error:
                estimate = PoseEstimate(error.status, detail=str(error))
            else:
                if fit_radius:
                    shares.append((len(waiting), prepare_self_calibration(image, setup)))
                    waiting.append((name, 1000 * (time.perf_counter() - start)))
                    continue
                estimate = localize(image, setup, method)
            if estimate.status in ("unreadable", "wrong_size"):
                shown = display_name(name)
                detail = estimate.detail if estimate.detail.startswith(shown) else f"{shown}: {estimate.detail}"
                report(f"spotnav: warning: {detail}")
            elapsed_ms = 1000 * (time.perf_counter() - start)
            if fit_radius:
                done[len(waiting)] = estimate
                waiting.append((name, elapsed_ms))
            else:
                writer.write(pose_row(display_name(name), estimate, elapsed_ms))
                result.statuses[estimate.status] += 1
        if waiting:
            failed, share_ms = set(done), 0.0
            if signals.received:  # no joint fit: each frame's own pose
                done |= {index: estimate for index, (estimate, _) in shares}
                report("spotnav: warning: stopped before the joint radius fit: each frame's own pose")
            else:
                start = time.perf_counter()
                fitted = self_calibrate_radius([share for _, share in shares], setup)
                share_ms = 1000 * (time.perf_counter() - start) / max(len(shares), 1)
                done |= {index: estimate for (index, _), estimate in zip(shares, fitted.estimates, strict=True)}
                result.radius = fitted
            for index, (name, elapsed_ms) in enumerate(waiting):
                writer.write(pose_row(display_name(name), done[index], elapsed_ms + share_ms * (index not in failed)))
                result.statuses[done[index].status] += 1
    result.rows, result.stopped_by = writer.rows, signals.received
    return result
