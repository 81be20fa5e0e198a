"""The report's opening (``spotnav.experiments.summary``): one table of the thesis's figures beside spotnav's, no
``nan`` anywhere without a word why, and a console line per study that says what its numbers are."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from spotnav.experiments import reproduce
from spotnav.experiments.ellipse import ELLIPSE_TIP, axis_miss
from spotnav.experiments.report import Experiment, Headline
from spotnav.experiments.runner import FrameResult, error_cells, summarize
from spotnav.experiments.summary import anchor, pair_text, ratio_verdict, summary_lines
from spotnav.pose.estimate import PoseEstimate
from spotnav.setup.geometry import InstrumentPose
from spotnav.setup.sections import Instrument

NAN = re.compile(r"\bnan\b", re.IGNORECASE)
FIRST_SCREEN = 40  # lines


def _result(status: str, error_mm: float = 0.0) -> FrameResult:
    truth = InstrumentPose(np.array([0.0, 0.0, 4.0]), np.array([0.0, 0.0, -1.0]))
    if status != "ok":
        return FrameResult(truth, PoseEstimate(status, detail="why"), 1.0, 1.0)
    tip = truth.tip_in_eye + np.array([error_mm, 0.0, 0.0])
    return FrameResult(truth, PoseEstimate("ok", tip_in_eye=tip, axis=truth.axis, sigma_mm=0.01), 1.0, 1.0)


def test_a_figure_without_an_ok_frame_says_why() -> None:
    refused = summarize([_result("mismatch"), _result("mismatch"), _result("blurred")])
    assert refused.why_none == "no ok frame: 0/3; blurred 1, mismatch 2"
    assert error_cells(refused) == ["- (no ok frame: 0/3; blurred 1, mismatch 2)"] * 3
    assert pair_text(refused) == "- (no ok frame: 0/3; blurred 1, mismatch 2)"
    some = summarize([_result("ok", 0.02), _result("ok", 0.06), _result("blurred")])
    assert pair_text(some) == "0.040 / 0.060 (2/3 ok; blurred 1)"
    assert error_cells(some) == ["0.0400", "0.0600", "50 %"]  # sigma 10 um per axis: 20 um within 3 sigma in 3-D
    # (52 um), 60 um not


def test_verdicts_and_anchors() -> None:
    assert ratio_verdict(0.03, 0.026) == "as printed (1.2 x)"
    assert ratio_verdict(0.26, 0.026) == "over (10 x)"
    assert ratio_verdict(0.01, 0.026) == "under (0.38 x)"
    # GitHub's anchors: lower case, punctuation dropped, spaces to hyphens.
    assert anchor("Thesis's exposure (+4.5 stops)") == "#thesiss-exposure-45-stops"
    assert anchor("Sections 6.2-6.3: the ellipse tests (Tables 6.1-6.6)") == (
        "#sections-62-63-the-ellipse-tests-tables-61-66"
    )


def test_the_summary_links_each_row_and_each_section() -> None:
    row = Headline("Table 9.9: x", "1.000 / 2.000", "1.1 / 2.1", "0.1 / 0.2", "as printed (1.1 x)", "Part A: x")
    lines = summary_lines([Experiment("a", "## Part A: x\n\ntext", "", (row,)), Experiment("b", "## Part B", "")])
    table = [line for line in lines if line.startswith("| Table 9.9")]
    cells = "Table 9.9: x | 1.000 / 2.000 | 1.1 / 2.1 | 0.1 / 0.2 | as printed (1.1 x) | [Part A](#part-a-x)"
    assert table == [f"| {cells} |"]
    assert "Full tables below: [Part A](#part-a-x) · [Part B](#part-b)." in lines
    assert not any(line.startswith("|") for line in summary_lines([Experiment("b", "## Part B", "")]))


def test_section_6_3_pose_misses_the_insertion_point() -> None:
    # Why the precise method, which puts the axis through the insertion point (0, 6, 20), refuses 6.3's frames:
    # the pose, straight down at (3, 3, 5), passes sqrt(3^2 + 3^2) mm from it.
    pose = InstrumentPose(np.array(ELLIPSE_TIP), np.array([0.0, 0.0, -1.0]))
    miss, angle = axis_miss(pose, Instrument().insertion_in_eye)
    assert miss == pytest.approx(np.sqrt(18.0))
    assert angle == pytest.approx(np.degrees(np.arctan2(np.sqrt(18.0), 15.0)))
    through = InstrumentPose.through_insertion(np.array(ELLIPSE_TIP), Instrument().insertion_in_eye)
    assert axis_miss(through, Instrument().insertion_in_eye) == pytest.approx((0.0, 0.0), abs=1e-9)


def test_report_opens_with_the_summary_and_has_no_bare_nan(tmp_path: Path) -> None:
    # The cheap studies at a small size: Table 4.1, the ellipse tests (section 6.3's precise refusals among them)
    # and the working volume (whose straight-down pose's precise-free frame is refused).
    lines: list[str] = []
    reproduce(tmp_path, size_px=384, poses=2, only=["approximation", "ellipse", "volume"], log=lines.append)
    report = (tmp_path / "report.md").read_text()
    head = report.splitlines()[:FIRST_SCREEN]
    assert head[0].startswith("# spotnav reproduction") and "## Summary: the thesis's figures beside spotnav's" in head
    rows = [line for line in head if line.startswith("| Table ")]
    assert [row.split(":")[0] for row in rows] == ["| Table 4.1", *(f"| Table 6.{n}" for n in range(1, 7))]
    headings = {anchor(line.lstrip("#").strip()) for line in report.splitlines() if line.startswith("#")}
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert len(cells) == 6 and all(cells), row
        link = re.fullmatch(r"\[.+\]\((#.+)\)", cells[-1])
        assert link and link.group(1) in headings, row
    where = next(line for line in head if line.startswith("Full tables below:"))
    assert where.count("](#") == 3
    assert not NAN.search(report), NAN.findall(report)
    # Section 6.3's precise cells say why they are refused, and precise-free's columns are there.
    sphere = next(line for line in report.splitlines() if line.startswith("| sphere, perpendicular") and "/" in line)
    assert "| mismatch (right: the axis misses the insertion point; precise-free beside it; note 1) |" in sphere
    assert "its axis passes 4.2 mm from that point, 15.8 deg from the line the method assumes" in report
    assert "precise-free, 3 beams" in report
    for line in lines:
        assert not NAN.search(line), line
    volume = next(line for line in lines if line.startswith("volume"))
    answer = r"(no ok frame: 0/1; \w+ 1|mean [\d.]+ mm, max [\d.]+ mm \(1/1 )"  # a refusal names its status
    straight = r"straight down, sharp edge, precise-free: " + answer
    assert re.search(straight, volume), volume


def test_console_says_what_its_ratios_are(tmp_path: Path) -> None:
    lines: list[str] = []
    reproduce(tmp_path, size_px=256, poses=2, only=["efficiency"], log=lines.append)
    (line,) = lines
    assert line.startswith("efficiency (")
    assert "RMS tip error over the Cramer-Rao bound's RMS on the same frames: 1 beam, default exposure: " in line
    assert re.search(r"precise [\d.]+ x \(bound [\d.e+-]+ mm, \d+ frames\)", line), line
    assert not NAN.search(line) and not NAN.search((tmp_path / "report.md").read_text())
