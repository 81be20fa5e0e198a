"""Which geometry parameters a calibration's frames determine, and in words why the others stay at the setup's values.

:class:`Pinning` tells how well the known frames alone pin some of the parameters (each one's sigma over its prior,
with those fitted and the rest held); :func:`choose` picks, in the order of :data:`PRIORITY`, the parameters the
frames determine (under :data:`DETERMINED_RATIO` of the prior). :func:`left_reason` says why a parameter stays at the
setup's value (how badly the frames pin it against what the setup states, what it looks like in them, or what known
frames would determine it) and :func:`refusal` why a forced group cannot be fitted, each in one sentence a user reads.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from spotnav.pose.conefit.covariance import scatter_covariance
from spotnav.pose.conefit.parameters import (
    EDGE_CONTOUR_SIGMA,
    PARAMETER_GROUPS,
    SHARED_SIZE,
    geometry_to_file_units,
    group_of,
)
from spotnav.pose.conefit.solution import ConeSolution
from spotnav.pose.known_frame import KnownFrameEdges
from spotnav.setup.config import Setup
from spotnav.setup.uncertainty import GEOMETRY_PARAMETERS

__all__ = [
    "DETERMINED_RATIO",
    "PRIORITY",
    "UNCERTAINTY_KEYS",
    "Pinning",
    "choose",
    "left_reason",
    "refusal",
    "unit_of",
    "worse_than_stated",
]

# A parameter is fitted when the frames alone pin it to this fraction of how well it was known before.
DETERMINED_RATIO = 0.25
# The order in which parameters may join the fit: what a microscope most often gets wrong first. Of two that look
# alike (a tilt and a shift of the camera, its focal length and its height) the first is fitted.
PRIORITY: tuple[int, ...] = (
    *PARAMETER_GROUPS["edge-angle"],
    *PARAMETER_GROUPS["beam-tilt"],
    *PARAMETER_GROUPS["camera-rotation"],
    *PARAMETER_GROUPS["focal-length"],
    *PARAMETER_GROUPS["light-radius"],
    *PARAMETER_GROUPS["insertion-point"],
    *PARAMETER_GROUPS["distortion"][:1],
    *PARAMETER_GROUPS["eye-radius"],
    *PARAMETER_GROUPS["camera-position"][::-1],
    *PARAMETER_GROUPS["principal-point"],
    *PARAMETER_GROUPS["distortion"][1:],
)


def _dense(solution: ConeSolution) -> np.ndarray:
    matrix = solution.problem.jacobian_matrix(solution.x, solution.inliers)
    return matrix if isinstance(matrix, np.ndarray) else matrix.toarray()


class Pinning:
    """How well the frames alone pin some of a calibration's candidate parameters: each one's sigma over its prior,
    with those given fitted and the other candidates held at their values.

    ``solution`` is the fit with every candidate free, held by its prior (in
    ``candidates``' order, then the frames' own parameters, always fitted).
    The uncertainty from the frames alone: the points' scatter
    (correlation-inflated) and each spot's whole-edge shift.
    """

    def __init__(self, solution: ConeSolution, candidates: Sequence[int]) -> None:
        self._jacobian = _dense(solution)
        self._residuals = solution.residuals[solution.inliers]
        self._spots = solution.problem.points.spot[solution.inliers]
        self._own = list(range(len(candidates), self._jacobian.shape[1]))
        self.candidates = list(candidates)
        self.prior = np.sqrt(np.diag(solution.problem.prior))  # (SHARED_SIZE,), engine units

    def __call__(self, chosen: Sequence[int]) -> np.ndarray:
        columns = [self.candidates.index(i) for i in chosen] + self._own
        size = self._jacobian.shape[1]
        covariance = scatter_covariance(
            self._jacobian[:, columns], self._residuals, self._spots, EDGE_CONTOUR_SIGMA, size
        )[0]
        ratios: np.ndarray = np.sqrt(np.diag(covariance)[: len(chosen)]) / self.prior[list(chosen)]
        return ratios


def choose(ratios: Pinning, candidates: Sequence[int], forced: Sequence[int]) -> tuple[list[int], np.ndarray]:
    """The candidates (in :data:`PRIORITY` order) the frames determine, and each one's sigma over its prior.

    The ``forced`` ones first; then a parameter joins when the frames alone
    (:class:`Pinning`), with the parameters chosen before it, pin it to
    under :data:`DETERMINED_RATIO` of its prior and still pin every one chosen
    before that they pinned (a forced one included).
    """
    chosen = list(forced)
    current = ratios(chosen) if chosen else np.zeros(0)
    tried = np.full(SHARED_SIZE, np.nan)
    for index in candidates:
        if index in chosen:
            continue
        trial = [*chosen, index]
        trial_ratios = ratios(trial)
        tried[index] = trial_ratios[-1]
        pinned = current < DETERMINED_RATIO
        if trial_ratios[-1] < DETERMINED_RATIO and np.all(trial_ratios[:-1][pinned] < DETERMINED_RATIO):
            chosen, current = trial, trial_ratios
    if chosen:
        tried[chosen] = current
    return chosen, tried


def _describe_poses(frames: list[KnownFrameEdges]) -> str:
    tips = np.array([f.tip for f in frames])
    spread = float(np.max(np.ptp(tips[:, :2], axis=0)))
    return f"tips {spread:.2f} mm apart in x, y, {tips[:, 2].min():.2f}-{tips[:, 2].max():.2f} mm above the pole"


# The [uncertainty] key of each parameter group.
UNCERTAINTY_KEYS = {
    "edge-angle": "edge_half_angle_deg",
    "light-radius": "light_radius_mm",
    "eye-radius": "eye_radius_mm",
    "camera-rotation": "camera_rotation_deg",
    "camera-position": "camera_position_mm",
    "focal-length": "focal_length_percent",
    "principal-point": "principal_point_percent",
    "distortion": "distortion_px",
    "insertion-point": "insertion_point_mm",
    "beam-tilt": "beam_tilt_deg",
}
_UNITS = {"deg": "deg", "mm": "mm", "percent": "%", "px": "px"}
# The known frames that determine each group when the others are held (by what moves its parameters in an image).
_DETERMINING_FRAMES = {
    "edge-angle": "known frames at more varied heights",
    "light-radius": "known frames at more varied heights (the spot grows from the light's own size with the height)",
    "eye-radius": "known frames whose spots lie further from the pole (tips further out in x, y), or three beams",
    "camera-rotation": "known frames spread wider over the image",
    "camera-position": "known frames spread wider over the image",
    "focal-length": "known frames spread wider over the image",
    "principal-point": "known frames spread wider over the image",
    "distortion": "known frames out to the image's edges",
    "insertion-point": "known axes (known.csv's dir_x, dir_y, dir_z: the insertion point is where they meet)",
    "beam-tilt": "known frames at more varied heights (the three spots move apart with the height)",
}
_MORE_FRAMES = "more known frames, spread wider in x, y and height"


def unit_of(name: str) -> str:
    """The unit of a :data:`~spotnav.setup.uncertainty.GEOMETRY_PARAMETERS` (or ``[uncertainty]``) name, as
    printed: ``deg``, ``mm``, ``%``, ``px`` or ``""`` (a distortion coefficient)."""
    return _UNITS.get(name.rsplit("_", 1)[-1], "")


def _in_file_units(index: int, sigma: float) -> str:
    """A 1-sigma of parameter ``index`` (engine units) as printed: ``+-0.5 mm``."""
    sd = float(geometry_to_file_units(np.where(np.arange(SHARED_SIZE) == index, sigma, 0.0))[index])
    return f"+-{sd:.2g} {unit_of(GEOMETRY_PARAMETERS[index])}".rstrip()


def _stated(setup: Setup, index: int, prior: float) -> str:
    """How well the setup states parameter ``index`` (its prior ``prior``, engine units), for a sentence."""
    name, group = GEOMETRY_PARAMETERS[index], group_of(index)
    key = UNCERTAINTY_KEYS.get(group)
    if name in setup.calibration.parameters or key is None:
        return _in_file_units(index, prior)
    return f"+-{getattr(setup.uncertainty, key):g} {unit_of(key)}"


def _pinned(ratio: float, stated: str, what: str = "it") -> str:
    """How well the frames pin a parameter (``what``) against its stated uncertainty, in words."""
    if ratio >= 1.0:
        times = f"{ratio:.1f}" if ratio < 10.0 else f"{ratio:.0f}"
        return f"the frames pin {what} {times} times worse than the setup's stated {stated}"
    return (
        f"the frames pin {what} to {ratio:.2f} of the setup's stated {stated} (a fit needs under {DETERMINED_RATIO:g})"
    )


def _partner(ratios: Pinning, index: int, chosen: Sequence[int]) -> str | None:
    """The group among ``chosen``'s that keeps the frames from pinning ``index``: the one whose leaving most
    improves it, when without it they pin it; None when nothing chosen does."""
    groups = sorted({group_of(i) for i in chosen} - {group_of(index)})
    best, best_ratio = None, np.inf
    for group in groups:
        others = [i for i in chosen if group_of(i) != group and i != index]
        ratio = float(ratios([*others, index])[-1])
        if ratio < best_ratio:
            best, best_ratio = group, ratio
    return best if best_ratio < DETERMINED_RATIO else None


def left_reason(ratios: Pinning, setup: Setup, index: int, ratio: float, chosen: Sequence[int]) -> str:
    """Why a parameter the frames do not determine stays at the setup's value, and what would determine it."""
    pinned = _pinned(ratio, _stated(setup, index, float(ratios.prior[index])))
    partner = _partner(ratios, index, chosen)
    if partner is not None:
        return f"{pinned}, as it looks like {partner} in them, which takes it up: kept at the setup's value"
    more = _DETERMINING_FRAMES.get(group_of(index), _MORE_FRAMES)
    return f"{pinned}: kept at the setup's value; {more} would determine it"


def refusal(
    ratios: Pinning,
    setup: Setup,
    index: int,
    forced: Sequence[int],
    edges: list[KnownFrameEdges],
) -> str:
    """The one sentence that refuses a forced parameter the frames do not determine: why, and what would."""
    group = group_of(index)
    own = [i for i in forced if group_of(i) == group]
    alone = float(ratios(own)[own.index(index)])
    stated = _stated(setup, index, float(ratios.prior[index]))
    more, poses = _DETERMINING_FRAMES.get(group, _MORE_FRAMES), _describe_poses(edges)
    if alone >= DETERMINED_RATIO:
        pinned = _pinned(alone, stated, GEOMETRY_PARAMETERS[index])
        return f"the known frames cannot determine {group}: {pinned} even with the rest held ({poses}); {more} would"
    partner = _partner(ratios, index, forced)
    if partner is None:
        return (
            f"the known frames cannot determine {group} with the other groups forced ({poses}): force fewer groups at "
            "once"
        )
    pinned = _pinned(float(ratios(forced)[forced.index(index)]), stated)
    return (
        f"the known frames cannot determine {group} and {partner} together: {GEOMETRY_PARAMETERS[index]} looks like "
        f"{partner} in them ({pinned}; {poses}): fit one of them (leave --fit {partner} out), or {more} would tell "
        "them apart"
    )


def worse_than_stated(
    ratios: Pinning, setup: Setup, forced: Sequence[int], chosen: Sequence[int], sigmas: np.ndarray
) -> str | None:
    """The sentence that refuses a forced parameter whose calibrated 1-sigma (``sigmas``, engine units, in
    ``chosen``'s order, the uncertainty of the parameters left at the setup's values included) is no better than
    the setup states: what it looks like among those left, and what frames would determine it; None when every
    forced one is better."""
    order = list(chosen)
    for index in forced:
        sigma = float(sigmas[order.index(index)])
        if sigma < ratios.prior[index]:
            continue
        group = group_of(index)
        left = {
            group_of(i): [j for j in ratios.candidates if group_of(j) == group_of(i) and j not in order]
            for i in ratios.candidates
            if i not in order
        }
        like = max(left, key=lambda name: float(ratios([*order, *left[name]])[order.index(index)])) if left else None
        looks = f", as it looks like {like} in them, which they do not pin" if like else ""
        stated = _stated(setup, index, float(ratios.prior[index]))
        more = _DETERMINING_FRAMES.get(group, _MORE_FRAMES)
        return (
            f"the known frames cannot determine {group}: fitted, {GEOMETRY_PARAMETERS[index]} would be known to "
            f"{_in_file_units(index, sigma)}, no better than the setup's stated {stated}{looks}; {more} would"
        )
    return None
