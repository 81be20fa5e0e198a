"""The fault-injection study and the precise method under disturbances: right, or a refusal."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from spotnav.experiments import faults, reproduce
from spotnav.experiments.scenes import thesis_world, with_true_edge
from spotnav.optics.camera import project_points
from spotnav.optics.render import Renderer
from spotnav.pose.localize import localize
from spotnav.pose.shaft import hidden_by_shaft
from spotnav.setup.geometry import InstrumentPose

ABOVE = (0.0, 1.0, 24.0)  # an insertion point above the working volume: the shaft crosses the spot


def _world(size_px: int = 768, **changes: object) -> object:
    world = thesis_world(size_px, 1)
    for section, values in changes.items():
        world = replace(world, **{section: replace(getattr(world, section), **values)})
    return with_true_edge(world)


@pytest.mark.parametrize(("tip", "seed"), [((0.5, 0.5, 4.0), 1), ((-1.0, 1.5, 5.0), 2), ((1.2, -0.8, 3.5), 3)])
def test_the_shaft_hides_part_of_the_spot_and_the_rest_gives_the_pose(tip: tuple, seed: int) -> None:
    world = _world(instrument={"insertion_point_mm": ABOVE}, faults={"shaft": True})
    pose = InstrumentPose.through_insertion(list(tip), world.instrument.insertion_in_eye)
    image = Renderer(world).render(pose, seed=seed)
    estimate = localize(image, world, "precise")
    assert estimate.ok, estimate.detail
    assert np.linalg.norm(estimate.tip_in_eye - pose.tip_in_eye) < 0.03
    edges = [np.asarray(project_points(world.camera, pose.tip_in_eye + np.outer([-0.5, -1.0], pose.axis)))]
    assert hidden_by_shaft(world, edges, pose.tip_in_eye, pose.axis)[0].all()  # the shaft lies over the spot


@pytest.mark.parametrize(
    ("changes", "statuses", "detail"),
    [
        (
            {"instrument": {"insertion_point_mm": ABOVE, "shaft_diameter_mm": 2.5}, "faults": {"shaft": True}},
            ("occluded", "unreliable"),
            "",
        ),
        ({"render": {"full_well_e": 625.0, "read_noise_e": 128.0}}, ("unreliable",), "noise"),
        ({"render": {"exposure_stops": 4.0}}, ("unreliable",), "full scale"),
        ({"faults": {"stray_light": 8.0}}, ("ambiguous", "unreliable", "clipped"), ""),
    ],
)
def test_disturbances_beyond_the_method_are_refused_with_a_reason(changes: dict, statuses: tuple, detail: str) -> None:
    world = _world(**changes)
    for seed, tip in enumerate([(0.5, 0.5, 4.0), (-1.0, 1.0, 5.0), (1.0, -1.0, 3.5)]):
        pose = InstrumentPose.through_insertion(list(tip), world.instrument.insertion_in_eye)
        estimate = localize(Renderer(world).render(pose, seed=seed), world, "precise")
        if estimate.ok:  # a pose only when it is right
            assert np.linalg.norm(estimate.tip_in_eye - pose.tip_in_eye) < 0.1
        else:
            assert estimate.status in statuses and detail in estimate.detail, estimate


def test_fault_study_smoke(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(faults, "MIN_FRAMES", len(faults.FAULT_CASES))  # one frame per case
    experiments = reproduce(tmp_path, size_px=384, poses=1, workers=1, only=["faults"], log=print)
    report = (tmp_path / "report.md").read_text()
    for case in faults.FAULT_CASES:
        assert f"| {case.category} | {case.severity} | precise |" in report
    limits = [case for case in faults.FAULT_CASES if case.limit]
    frames = f"in {len(faults.FAULT_CASES) - len(limits)} frames outside the known limits"
    assert f"0 silent failures {frames}" in report
    assert f"0 silent failures (ok, over {faults.SILENT_ERROR_MM} mm off) {frames}" in experiments[0].summary
    for case in limits:  # shown, not hidden
        assert f"{case.category} {case.severity}: " in experiments[0].summary
        assert f"{case.category} {case.severity}: " in report and case.limit in report
    assert (tmp_path / "faults.png").stat().st_size > 10000


def test_every_category_of_the_issue_is_in_the_study() -> None:
    categories = {case.category for case in faults.FAULT_CASES}
    assert categories == {
        "none",
        "shaft",
        "glints",
        "vessels",
        "second source",
        "motion blur",
        "sensor noise",
        "exposure",
        "outside the image",
        "touching beams",
        "dark patch",
        "defocus",
        "frame blur",
        "encoding",
        "glow",
        "combined",
    }
    assert all(sum(c.default for c in faults.FAULT_CASES if c.category == k) == 1 for k in categories)
    assert len(faults.FAULT_CASES) * -(-faults.MIN_FRAMES // len(faults.FAULT_CASES)) >= 1000
