from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from spotnav.app.evaluate import _errors_title, evaluate_poses, evaluation_text
from spotnav.cli import main
from spotnav.errors import SpotnavError
from spotnav.files.poses import KnownPose, PoseRow, read_poses_csv

AXIS = np.array([0.0, 0.0, -1.0])


def truth(count: int) -> list[KnownPose]:
    return [KnownPose(Path(f"/data/frames/test_{i:02d}.png"), np.array([i, 0.0, 4.0]), AXIS) for i in range(count)]


def tilted(angle_deg: float) -> np.ndarray:
    angle = np.radians(angle_deg)
    return np.array([np.sin(angle), 0.0, -np.cos(angle)])


def test_errors_bias_and_axis_angle_are_measured_over_the_ok_rows() -> None:
    known = truth(5)
    offsets = [[0.01, 0, 0], [0, 0.02, 0], [0, 0, -0.03], [0.04, 0, 0]]
    poses = [PoseRow(f"test_{i:02d}.png", "ok", known[i].tip_in_eye + o, tilted(i)) for i, o in enumerate(offsets)]
    poses.append(PoseRow("test_04.png", "unreliable", None, None))
    evaluation = evaluate_poses(poses, known)
    assert evaluation.counts == {"ok": 4, "unreliable": 1}
    assert evaluation.mean_mm == pytest.approx(0.025)
    assert evaluation.median_mm == pytest.approx(0.025)
    assert evaluation.max_mm == pytest.approx(0.04)
    assert evaluation.p95_mm == pytest.approx(np.percentile([0.01, 0.02, 0.03, 0.04], 95))
    np.testing.assert_allclose(evaluation.bias_mm, [0.0125, 0.005, -0.0075], atol=1e-12)
    assert evaluation.axis_max_deg == pytest.approx(3.0)
    assert evaluation.axis_mean_deg == pytest.approx(1.5)
    assert np.isnan(evaluation.frames[4].error_mm)
    assert "4 ok, 1 unreliable" in evaluation_text(evaluation)


def test_a_pose_without_truth_is_named_and_truth_without_a_pose_is_counted() -> None:
    known = truth(3)
    poses = [PoseRow(f"test_{i:02d}.png", "ok", known[i].tip_in_eye, AXIS) for i in range(2)]
    stopped_early = evaluate_poses(poses, known)  # issue 20: a run stopped by Ctrl-C or --max-frames
    assert len(stopped_early.frames) == 2 and stopped_early.unposed == 1
    assert "1 truth rows have no pose row" in evaluation_text(stopped_early)
    extra = [*poses, PoseRow("test_02.png", "ok", known[2].tip_in_eye, AXIS)]
    extra.append(PoseRow("other.png", "no_spot", None, None))
    with pytest.raises(SpotnavError, match=r"no truth for 1 image\(s\): other.png"):
        evaluate_poses(extra, known)


def test_an_image_listed_twice_is_an_error() -> None:
    known = truth(1)
    poses = [PoseRow("a/test_00.png", "ok", known[0].tip_in_eye, AXIS), PoseRow("b/test_00.png", "ok", None, None)]
    with pytest.raises(SpotnavError, match=r"test_00\.png appears twice"):
        evaluate_poses(poses, known)


def test_a_videos_rows_join_on_the_frame() -> None:
    known = [KnownPose(Path(""), np.array([i, 0.0, 4.0]), AXIS, frame=i) for i in range(3)]
    poses = [PoseRow("", "ok", known[i].tip_in_eye + np.array([0, 0, 0.01 * i]), AXIS, frame=i) for i in (2, 0, 1)]
    evaluation = evaluate_poses(poses, known)
    assert [f.image for f in evaluation.frames] == ["frame 2", "frame 0", "frame 1"]
    assert [f.error_mm for f in evaluation.frames] == pytest.approx([0.02, 0.0, 0.01])
    with pytest.raises(SpotnavError, match=r"no truth for 1 image\(s\): frame 7"):
        evaluate_poses([*poses, PoseRow("", "no_spot", None, None, frame=7)], known)
    with pytest.raises(SpotnavError, match="frame 1 appears twice"):
        evaluate_poses([*poses, PoseRow("", "no_spot", None, None, frame=1)], known)


def test_an_ok_row_without_a_pose_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "poses.csv"
    path.write_text("image,status,x_mm,y_mm,z_mm,dir_x,dir_y,dir_z\na.png,ok,1,2,,0,0,-1\n")
    with pytest.raises(SpotnavError, match="line 2: the pose must be six numbers"):
        read_poses_csv(path)


def test_evaluate_command_joins_on_file_names_and_writes_its_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    poses = tmp_path / "poses.csv"
    poses.write_text(
        "image,status,x_mm,y_mm,z_mm,dir_x,dir_y,dir_z,spots\n"
        "frames/test_00.png,ok,0.000000,0.010000,4.000000,0,0,-1,1\n"
        "frames/test_01.png,no_spot,,,,,,,0\n"
    )
    truth_csv = tmp_path / "truth.csv"  # a truth file may carry more columns
    truth_csv.write_text(
        "image,x_mm,y_mm,z_mm,dir_x,dir_y,dir_z,note\ntest_00.png,0,0,4,0,0,-1,a\ntest_01.png,1,0,4,0,0,-1,b\n"
    )
    out = tmp_path / "evaluation"
    assert main(["evaluate", str(poses), str(truth_csv), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "frames: 2 (1 ok, 1 no_spot)" in printed and "max 0.0100" in printed
    rows = (out / "errors.csv").read_text().splitlines()
    assert rows[1].startswith("test_00.png,ok,0.010000") and rows[2] == "test_01.png,no_spot,,,,,"
    assert (out / "errors.png").stat().st_size > 0 and (out / "track.png").read_bytes()[:4] == b"\x89PNG"
    truth_csv.write_text("image,x_mm,y_mm,z_mm\ntest_00.png,0,0,4\n")
    assert main(["evaluate", str(poses), str(truth_csv)]) == 2
    assert "no truth for 1 image(s): test_01.png" in capsys.readouterr().err


def test_the_errors_figure_says_when_no_frame_is_ok() -> None:
    # Review: errors.png's title read "mean nan mm, max nan mm" for a run without an ok frame.
    known = truth(3)
    refused = evaluate_poses([PoseRow(f"test_{i:02d}.png", "uncalibrated", None, None) for i in range(3)], known)
    assert _errors_title(refused) == "tip error per frame: no ok frame among 3"
    some = evaluate_poses([PoseRow("test_00.png", "ok", known[0].tip_in_eye + np.array([0.01, 0, 0]), AXIS)], known)
    assert "nan" not in _errors_title(some) and "mean 0.0100 mm" in _errors_title(some)
