from __future__ import annotations

from pathlib import Path

import numpy as np
from conftest import small_setup

from spotnav.experiments import approximation_rows, reproduce, run_frames, summarize, working_volume_tips
from spotnav.geometry import InstrumentPose


def test_results_do_not_depend_on_workers() -> None:
    setup = small_setup(256)
    poses = [InstrumentPose.through_insertion(t, setup.instrument.insertion_in_eye) for t in working_volume_tips(3)]
    serial = run_frames(setup, poses, workers=1)
    parallel = run_frames(setup, poses, workers=2)
    for a, b in zip(serial, parallel, strict=True):
        assert a.estimate.status == b.estimate.status
        np.testing.assert_array_equal(a.error_xyz_mm, b.error_xyz_mm)


def test_summary_counts_only_ok_frames() -> None:
    setup = small_setup(256)
    poses = [
        InstrumentPose.through_insertion([0.0, 0.0, 4.0], setup.instrument.insertion_in_eye),
        InstrumentPose([0.0, 0.0, 4.0], [0.0, 0.0, 1.0]),  # points away from the retina: no spot
    ]
    results = run_frames(setup, poses)
    summary = summarize(results)
    assert summary.frames == 2 and summary.ok == 1
    assert summary.mean_mm == summary.max_mm == results[0].error_mm
    assert np.isnan(results[1].error_mm)


def test_working_volume_is_bounded_and_seeded() -> None:
    tips = working_volume_tips(200, seed=3)
    assert np.all(np.abs(tips[:, :2]) <= 2.5) and np.all((tips[:, 2] >= 3) & (tips[:, 2] <= 6))
    np.testing.assert_array_equal(tips, working_volume_tips(200, seed=3))


def test_approximation_rows_match_thesis() -> None:
    for _, thesis, gap, _, _ in approximation_rows():
        assert round(gap, 2) == thesis


def test_reproduce_writes_report(tmp_path: Path) -> None:
    lines: list[str] = []
    reproduce(tmp_path, quick=True, only=["approximation"], log=lines.append)
    report = (tmp_path / "report.md").read_text()
    assert "Table 4.1" in report and "| 9 | 0.49 | 0.494 |" in report
    assert (tmp_path / "approximation.csv").exists()
    assert lines and lines[0].startswith("approximation")
