"""The design search: the design file, the constraints, the ranking, the verification against the bound, the CLI."""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from spotnav.cli import main
from spotnav.errors import SpotnavError
from spotnav.experiments.design import (
    EXAMPLE_DESIGN,
    Candidate,
    evaluate_candidate,
    plan_candidates,
    run_design,
)
from spotnav.experiments.design_file import DesignError, candidate_points, design_from_toml
from spotnav.experiments.design_report import AGREEMENT
from spotnav.optics.render import Renderer
from spotnav.pose.precise import localize_precise
from spotnav.setup.config import Setup, setup_from_toml
from spotnav.setup.geometry import InstrumentPose
from spotnav.setup.sections import Instrument
from spotnav.setup.values import SetupError

TINY = """\
seed = 2
candidates = 2
objective = "max"
[base]
size_px = 256
[space]
instrument.beam_count = [1]
instrument.beam_half_angle_deg = [7.0, 11.0]
light.power_w = [0.5, 1.0]
[workspace]
kind = "box"
min_mm = [-1.5, -1.5, 4.0]
max_mm = [1.5, 1.5, 5.5]
poses = 12
[constraints]
max_power_w = 3.0
min_spot_gap_deg = 1.0
[verify]
designs = 1
poses = 12
"""


def test_the_example_parses_and_draws_its_candidates_from_the_seed() -> None:
    search = design_from_toml(EXAMPLE_DESIGN)
    points = candidate_points(search)
    assert len(points) == search.candidates == 24 and points == candidate_points(search)
    assert {p["instrument.beam_count"] for p in points} == {1, 2, 3, 4}
    angles = [p["instrument.beam_half_angle_deg"] for p in points]
    assert min(angles) >= 4.0 and max(angles) <= 12.0 and len(set(angles)) == 24
    assert all("instrument.beam_tilt_deg" not in p for p in points if p["instrument.beam_count"] == 1)
    assert search.base.camera.width_px == 512 and search.workspace.tips().shape == (16, 3)
    other = design_from_toml(EXAMPLE_DESIGN.replace("seed = 0", "seed = 1"))
    assert candidate_points(other) != points


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("seed = 2", "seeds = 2"), "seeds is not a known key"),
        (("candidates = 2", "candidates = 0"), "candidates must be an integer >= 1"),
        (('objective = "max"', 'objective = "mean"'), "objective must be max or p95"),
        (("instrument.beam_count = [1]", "instrument.beam_count = [5]"), "space.instrument.beam_count"),
        (("light.power_w = [0.5, 1.0]", "light.power_w = [1.0, 0.5]"), "space.light.power_w must have low <= high"),
        (("light.power_w = [0.5, 1.0]", "light.blend = [0.0, 0.3]"), "space.light.blend must be > 0"),
        (("light.power_w = [0.5, 1.0]", "light.colour = [0.0, 0.3]"), "space.light.colour is not a known key"),
        (("[0.5, 1.0]", "[0.5, -1.0]"), "space.light.power_w"),
        (('kind = "box"', 'kind = "ring"'), "workspace.kind must be box, square or helix"),
        (("max_mm = [1.5, 1.5, 5.5]", "max_mm = [1.5, 1.5, 13.0]"), "workspace: the box's corner"),
        (("max_mm = [1.5, 1.5, 5.5]", "max_mm = [1.5, 1.5]"), "workspace.max_mm must be [x, y, z]"),
        (("max_power_w = 3.0", "max_power_w = -1.0"), "constraints.max_power_w must be >= 0"),
        (("min_spot_gap_deg = 1.0", "on_fundus = 1"), "constraints.on_fundus must be true or false"),
        (("designs = 1", "designs = -1"), "verify.designs must be an integer >= 0"),
        (("poses = 12\n[constraints]", "poses = 4\n[constraints]"), "verify.poses must be <= workspace.poses"),
        (("size_px = 256", "size_px = 8"), "camera.width_px = 8 is out of range"),
        (("[7.0, 11.0]", "[50.0, 60.0]"), "instrument.beam_half_angle_deg = 5"),
        (("[base]", "[base"), "not valid TOML"),
    ],
)
def test_a_bad_design_file_names_its_key(edit: tuple[str, str], message: str) -> None:
    assert edit[0] in TINY
    with pytest.raises((DesignError, SetupError), match=message.replace("[", r"\[")):
        design_from_toml(TINY.replace(*edit))


def test_two_and_four_beams_are_for_simulation_only() -> None:
    assert Instrument(beam_count=2).beam_count == 2 and Instrument(beam_count=4).beam_count == 4
    with pytest.raises(SetupError, match=r"instrument\.beam_count = 5 is not allowed, allowed 1 to 4"):
        Instrument(beam_count=5)
    with pytest.raises(SetupError, match=r"instrument\.beam_count = 2 is not allowed here, allowed 1 or 3"):
        setup_from_toml("[instrument]\nbeam_count = 2")  # the contract's setup file
    setup = Setup(instrument=Instrument(beam_count=4))
    setup = replace(setup, camera=setup.camera.resized(256, 256))
    pose = InstrumentPose.through_insertion(np.array([0.5, 0.0, 5.0]), setup.instrument.insertion_in_eye)
    image = Renderer(setup).render(pose)
    assert image.max() > 0
    with pytest.raises(SetupError, match=r"instrument\.beam_count = 4"):
        localize_precise(image, setup)


def _evaluate(text: str, point: dict[str, float | int], reference: bool = False) -> tuple[str, str, float]:
    result = evaluate_candidate(design_from_toml(text), Candidate(0, "probe", point, reference))
    return result.status, result.detail, result.objective_mm


def test_the_constraints_reject_touching_spots_too_much_power_and_spots_off_the_fundus() -> None:
    three = {"instrument.beam_count": 3, "instrument.beam_half_angle_deg": 9.0}
    status, detail, objective = _evaluate(TINY, three | {"instrument.beam_tilt_deg": 8.0})
    assert status == "spots_touch" and "apart" in detail and objective == np.inf
    # Three beams tilted 11 deg are 19.03 deg apart: 9 deg cones leave a gap of 1.05 deg, two beams 22 - 18 = 4.
    assert _evaluate(TINY, three | {"instrument.beam_tilt_deg": 11.0})[0] == "feasible"
    assert _evaluate(TINY.replace("min_spot_gap_deg = 1.0", "min_spot_gap_deg = 1.1"), three)[0] != "spots_touch"
    two = {"instrument.beam_count": 2, "instrument.beam_half_angle_deg": 9.0, "instrument.beam_tilt_deg": 9.4}
    assert _evaluate(TINY, two)[0] == "spots_touch"
    status, detail, _ = _evaluate(TINY, {"instrument.beam_count": 4, "light.power_w": 0.8})
    assert status == "power" and "4 x 0.8 W > 3 W" in detail
    status, detail, objective = _evaluate(TINY, {"instrument.beam_half_angle_deg": 44.0})
    assert status == "off_fundus" and "leaves" in detail and objective == np.inf
    # A thesis's design is bounded even when it breaks a constraint, to be compared.
    status, _, objective = _evaluate(TINY.replace("max_power_w = 3.0", "max_power_w = 0.5"), {}, reference=True)
    assert status == "power" and 0 < objective < 0.01


def test_the_search_ranks_by_the_objective_writes_its_files_and_verifies_against_the_bound(tmp_path: Path) -> None:
    run = run_design(TINY, tmp_path, workers=0)
    labels = [c.label for c in plan_candidates(run.search)]
    assert labels[:2] == ["thesis, 1 beam", "thesis, 3 beams"] and len(labels) == 2 + 2
    objectives = [r.objective_mm for r in run.ranked]
    assert objectives == sorted(objectives) and len(run.ranked) == 4 and 0 < objectives[0] < 0.01
    assert run.best is not None and run.best.feasible and run.best in run.ranked
    with (tmp_path / "designs.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [row["label"] for row in rows] == labels
    assert rows[0]["beams"] == "1" and rows[0]["tilt_deg"] == "" and rows[1]["tilt_deg"] == "15.0"
    assert all(row["status"] == "feasible" and float(row["max_mm"]) >= float(row["mean_mm"]) > 0 for row in rows)
    report = (tmp_path / "report.md").read_text()
    assert "| thesis, 1 beam |" in report and "| thesis, 3 beams |" in report and "in this process" in report
    for name in ("objective.png", "best_bound.png", "bound_vs_error.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert set(run.verifications) == {0, 1, run.best.candidate.index}
    check = run.verifications[run.best.candidate.index]
    assert check.precise_refused <= 2 and np.isfinite(check.fit_errors_mm).sum() >= 10
    # The model fit is the efficient estimator: its RMS comes within 30 % of the bound's over the same frames.
    assert abs(check.fit_rms_mm / check.bound_rms_mm - 1.0) < AGREEMENT
    assert check.precise_rms_mm > check.fit_rms_mm  # spotnav's localizer is far from the bound
    with (tmp_path / "verified.csv").open() as handle:
        assert len(list(csv.DictReader(handle))) == 3


def test_cli_design_prints_the_example_and_runs_a_tiny_search(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["design", "--example"]) == 0
    assert design_from_toml(capsys.readouterr().out).candidates == 24
    text = TINY.replace("candidates = 2", "candidates = 1").replace("designs = 1", "designs = 0")
    text = text.replace("poses = 12\n[constraints]", "poses = 2\n[constraints]").replace("poses = 12\n", "poses = 2\n")
    (tmp_path / "design.toml").write_text(text)
    assert main(["design", str(tmp_path / "design.toml"), "--out", str(tmp_path / "out"), "--workers", "0"]) == 0
    out = capsys.readouterr().out
    assert "1 candidates" in out and "thesis, 3 beams: feasible, bound max" in out and "model fit RMS" in out
    assert (tmp_path / "out" / "designs.csv").is_file()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["design"], "design needs FILE and --out DIR"),
        (["design", "missing.toml", "--out", "x"], "No such file"),
        (["design", "d.toml", "--out", "x", "--workers", "2", "--scheduler", "tcp://h:1"], "--workers sizes"),
        (["design", "d.toml", "--out", "x", "--workers", "-1"], "--workers must be >= 0"),
    ],
)
def test_cli_design_errors_are_one_line(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "d.toml").write_text(TINY)
    assert main(argv) == 2
    error = capsys.readouterr().err
    assert message in error and len(error.strip().splitlines()) == 1


def test_a_design_error_is_a_spotnav_error() -> None:
    assert issubclass(DesignError, SpotnavError)


def _without_seconds(path: Path) -> list[dict[str, str]]:
    with path.open() as handle:
        return [{k: v for k, v in row.items() if k != "seconds"} for row in csv.DictReader(handle)]


@pytest.mark.slow  # a design search twice, on a cluster (40 s): make test-all
def test_a_local_dask_cluster_gives_the_same_designs_and_verification_as_this_process(tmp_path: Path) -> None:
    text = TINY.replace("poses = 12\n[constraints]", "poses = 3\n[constraints]").replace("poses = 12\n", "poses = 3\n")
    lines: list[str] = []
    on_dask = run_design(text, tmp_path / "dask", workers=2, dashboard="127.0.0.1:0", log=lines.append)
    serial = run_design(text, tmp_path / "serial", workers=0)
    assert (on_dask.workers, serial.workers) == (2, 0) and lines[0].startswith("Dask dashboard: http://127.0.0.1:")
    for name in ("designs.csv", "verified.csv"):
        assert _without_seconds(tmp_path / "dask" / name) == _without_seconds(tmp_path / "serial" / name)
    assert "on 2 Dask workers" in (tmp_path / "dask" / "report.md").read_text()
