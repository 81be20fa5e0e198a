"""One frame's pipeline, in stages that every method configures (``docs/methods.md``, "One frame pipeline").

1. *Find*: where each spot's edge is to be read, which beam made it and the
   pose its light is modelled from (a :class:`SpotPlan`): from the spots found
   on the whole frame and the thesis's start (:mod:`spotnav.pose.precise`), from a
   predicted pose (:mod:`spotnav.app.track`), or from a known one
   (:mod:`spotnav.pose.known_frame`).
2. *Read the light*: each spot's edge along its rays, with its beam's light
   model where the plateau clips, and judged (:func:`read_light`).
3. *Fit*: the pose to the edge points the shaft leaves visible
   (:func:`fit_visible`; calibration fits its frames' points together).
4. *Judge*: the fit's checks (:func:`spotnav.pose.checks.judge_fit`).

Every stage returns its result or a status: a :class:`~spotnav.pose.estimate.PoseEstimate` that is not ``ok``, with
its reason.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from spotnav.image.photometry import edge_light
from spotnav.image.rays import SpotEdge, detect_edge_along_rays, rays_around_spot
from spotnav.image.spots import Spot
from spotnav.optics.light import edge_angle
from spotnav.pose.checks import judge_edge
from spotnav.pose.conefit.problem import ConeProblem, EdgePoints, cone_problem
from spotnav.pose.conefit.solution import ConeSolution
from spotnav.pose.conefit.solvers import fit_cones
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.shaft import visible_edge_points
from spotnav.setup.config import Setup
from spotnav.setup.geometry import beam_axes

__all__ = [
    "LightReading",
    "RayFan",
    "SpotPlan",
    "fit_visible",
    "fitted_edges_px",
    "plan_found_spots",
    "pose_problem",
    "read_light",
    "read_spot_edge",
    "refit_free_axis",
]


@dataclass(frozen=True)
class RayFan:
    """Where one spot's edge is read: rays from a centre across the edge.

    Attributes
    ----------
    centre_px : ndarray, shape (2,)
        Where the rays start, pixels.
    ray_angles : ndarray, shape (R,)
        Their directions, radians.
    radii_px : ndarray, shape (R,)
        Where each ray is expected to cross the edge, pixels from the centre.
    align : bool
        Whether each ray is read around its own radius (a predicted curve)
        rather than the spot's median one (:func:`spotnav.image.rays.detect_edge_along_rays`).
    """

    centre_px: np.ndarray
    ray_angles: np.ndarray
    radii_px: np.ndarray
    align: bool = False


@dataclass(frozen=True)
class SpotPlan:
    """The find stage's result: where each spot is read, and what light made it.

    Attributes
    ----------
    fans : tuple of RayFan
        One per spot.
    beams : tuple of int
        The beam that made each spot.
    radii_px : tuple of float
        Each spot's radius, pixels: a shift of its whole edge by ``s`` pixels
        turns its edge by about ``s / radius`` of the edge angle.
    tip_in_eye : ndarray, shape (3,)
        The pose the light is modelled from (a start, a prediction or a known tip), eye frame, mm.
    beam_axes_in_eye : ndarray, shape (B, 3)
        Every beam's axis at that pose, unit, indexed by beam.
    """

    fans: tuple[RayFan, ...]
    beams: tuple[int, ...]
    radii_px: tuple[float, ...]
    tip_in_eye: np.ndarray
    beam_axes_in_eye: np.ndarray


@dataclass(frozen=True)
class LightReading:
    """The read stage's result: each spot's edge, judged.

    Attributes
    ----------
    edges : tuple of SpotEdge
        Each spot's edge as read.
    sigmas : tuple of float
        Each spot's own whole-edge uncertainty, radians (:func:`spotnav.pose.checks.judge_edge`).
    beams : tuple of int
        The beam that made each spot.
    """

    edges: tuple[SpotEdge, ...]
    sigmas: tuple[float, ...]
    beams: tuple[int, ...]

    @property
    def edges_px(self) -> tuple[np.ndarray, ...]:
        """Each spot's sub-pixel edge points, in order around it, pixels, shapes (N_k, 2)."""
        return tuple(edge.pixels for edge in self.edges)


def plan_found_spots(
    setup: Setup,
    spots: Sequence[Spot],
    beams: Sequence[int],
    tip_in_eye: np.ndarray,
    axis: np.ndarray,
    roll: float,
    max_rays: int,
) -> SpotPlan:
    """The find stage of spots found on the frame: rays across each one's outline
    (:func:`spotnav.image.rays.rays_around_spot`, at most ``max_rays``), its radius from its area, and the light
    modelled from a pose (eye frame, mm; the instrument's ``axis`` and ``roll``, radians)."""
    instrument = setup.instrument
    return SpotPlan(
        fans=tuple(RayFan(*rays_around_spot(spot, max_rays)) for spot in spots),
        beams=tuple(beams),
        radii_px=tuple(float(np.sqrt(spot.area_px / np.pi)) for spot in spots),
        tip_in_eye=np.asarray(tip_in_eye, dtype=float),
        beam_axes_in_eye=beam_axes(axis, instrument.beam_count, instrument.beam_tilt, roll),
    )


def read_light(
    image: np.ndarray,
    setup: Setup,
    plan: SpotPlan,
    *,
    min_edge_fraction: float = 0.0,
    noise_pools: Sequence[np.ndarray] | None = None,
) -> LightReading | PoseEstimate:
    """Read each planned spot's edge and judge it.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) or (H, W)
        The frame, as the camera encoded it (``camera.response``).
    setup : Setup
    plan : SpotPlan
    min_edge_fraction : float
        Where the spot was predicted, not found: a spot whose edge (read or
        misshapen by a vessel) is on fewer of its rays than this is not there.
    noise_pools : sequence of ndarray, optional
        A stream's noise beside each beam's spot over its last frames, by beam
        (:func:`spotnav.optics.pixelnoise.new_noise_pool`; see
        :func:`spotnav.image.rays.detect_edge_along_rays`).

    Returns
    -------
    LightReading or PoseEstimate
        The edges, or why one cannot be used: ``unreliable`` or ``blurred`` (:func:`spotnav.pose.checks.judge_edge`).
    """
    angle = edge_angle(setup)
    edges, sigmas = [], []
    for index, (beam, radius_px) in enumerate(zip(plan.beams, plan.radii_px, strict=True)):
        edge = read_spot_edge(image, setup, plan, index, None if noise_pools is None else noise_pools[beam])
        found = (len(edge.pixels) + edge.misshapen_rays) / edge.rays
        if found < min_edge_fraction:
            detail = f"an edge on only {100 * found:.0f} % of the rays near the predicted spot"
            return PoseEstimate("unreliable", spots=len(plan.fans), detail=detail)
        verdict = judge_edge(edge, setup, radius_px, angle)
        if not verdict.ok:
            return PoseEstimate(verdict.status, spots=len(plan.fans), detail=verdict.detail)
        edges.append(edge)
        sigmas.append(verdict.sigma)
    return LightReading(tuple(edges), tuple(sigmas), plan.beams)


def read_spot_edge(
    image: np.ndarray, setup: Setup, plan: SpotPlan, index: int, noise_pool: np.ndarray | None = None
) -> SpotEdge:
    """One planned spot's edge along its rays, with its beam's light model, not judged (:func:`read_light` judges it;
    ``spotnav show`` draws it on a frame that was refused)."""
    fan, beam = plan.fans[index], plan.beams[index]
    return detect_edge_along_rays(
        image,
        fan.centre_px,
        fan.ray_angles,
        fan.radii_px,
        align=fan.align,
        response=setup.camera.pixel_response,
        light=edge_light(setup, plan.tip_in_eye, plan.beam_axes_in_eye[beam]),
        noise_pool=noise_pool,
    )


def pose_problem(
    setup: Setup,
    edges_px: Sequence[np.ndarray],
    beams: Sequence[int],
    tip_in_eye: np.ndarray,
    axis: np.ndarray,
    roll: float,
    *,
    through_insertion: bool = True,
    edge_sigmas: Sequence[float] | None = None,
) -> ConeProblem:
    """One frame's pose as a cone problem: its spots' edges (and their own whole-edge sigmas, radians), a start,
    the axis through the insertion point or free."""
    points = EdgePoints.of_frames([edges_px], [beams], None if edge_sigmas is None else [edge_sigmas])
    return cone_problem(
        setup,
        points,
        np.asarray(tip_in_eye, dtype=float)[None],
        np.asarray(axis, dtype=float)[None],
        np.array([roll]),
        axis="insertion" if through_insertion else "free",
    )


def fit_visible(
    setup: Setup,
    reading: LightReading,
    hidden: Sequence[np.ndarray],
    tip_in_eye: np.ndarray,
    axis: np.ndarray,
    roll: float,
    *,
    through_insertion: bool = True,
    solver: str = "levenberg-marquardt",
) -> ConeSolution | PoseEstimate:
    """The fit stage: one pose fitted to the read edge points that are not ``hidden`` (per spot, (N_k,) bool: the
    shaft's, :func:`spotnav.pose.shaft.hidden_by_shaft`) and lie on the retina, from a start (eye frame, mm; radians).

    Returns the fit, or ``occluded`` when the shaft hides too much of a spot's edge
    (:func:`spotnav.pose.shaft.visible_edge_points`).
    """
    visible = visible_edge_points(setup, reading.edges_px, hidden)
    if not visible.ok:
        return PoseEstimate(visible.status, spots=len(reading.edges_px), detail=visible.detail)
    problem = pose_problem(
        setup,
        visible.edges_px,
        reading.beams,
        tip_in_eye,
        axis,
        roll,
        through_insertion=through_insertion,
        edge_sigmas=reading.sigmas,
    )
    return fit_cones(problem, solver=solver)


def refit_free_axis(setup: Setup, constrained: ConeSolution, solver: str = "gauss-newton") -> ConeSolution:
    """The cross-check: a one-frame fit through the insertion point fitted again on its own points with the axis
    free, from its pose (Gauss-Newton's few steps by default; ``levenberg-marquardt`` settles it)."""
    tip, axis, roll = constrained.tip(), constrained.axis(), constrained.roll()
    problem = cone_problem(setup, constrained.problem.points, tip[None], axis[None], np.array([roll]), axis="free")
    return fit_cones(problem, solver=solver)


def fitted_edges_px(solution: ConeSolution) -> tuple[np.ndarray, ...]:
    """The edge points a one-frame fit used, per spot in order, pixels, shapes (N_k, 2)."""
    points = solution.problem.points
    return tuple(points.pixels[points.spot == spot] for spot in np.unique(points.spot))
