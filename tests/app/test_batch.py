from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
from test_cli import read_poses, write_scene

from spotnav.app.batch import localize_batch
from spotnav.cli import main
from spotnav.errors import SpotnavError
from spotnav.files.setup_files import read_setup
from spotnav.setup.config import setup_from_toml


def test_localize_keeps_going_past_bad_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene = write_scene(tmp_path / "setup.toml", size_px=384)
    good = tmp_path / "good.png"
    assert main(["render", "--scene", str(scene), "--tip", "0", "0", "4", "--out", str(good)]) == 0
    dark = tmp_path / "dark.png"
    assert main(["render", "--scene", str(scene), "--tip", "0", "0", "4", "--power", "0", "--out", str(dark)]) == 0
    (tmp_path / "empty.png").write_bytes(b"")
    images = [str(good), str(tmp_path / "missing.png"), str(tmp_path / "empty.png"), str(dark)]
    batch = localize_batch(images, read_setup(scene), "precise", tmp_path / "poses.csv")
    rows = read_poses(tmp_path / "poses.csv")
    assert [r["image"] for r in rows] == images
    assert [r["status"] for r in rows] == ["ok", "unreadable", "unreadable", "no_spot"]
    assert all(r["x_mm"] == "" for r in rows[1:])
    err = capsys.readouterr().err
    assert "missing.png: no such file" in err
    assert batch.rows == 4 and batch.statuses == {"ok": 1, "unreadable": 2, "no_spot": 1}
    assert batch.stopped_by is None and batch.radius is None
    assert batch.all_failed is None and batch.exit_code == 0  # one frame has a pose


class _InterruptedAt(list[str]):
    """Images that send SIGINT to this process as the one at ``at`` is taken: a Ctrl-C during the image before it."""

    def __init__(self, images: list[str], at: int, number: signal.Signals = signal.SIGINT) -> None:
        super().__init__(images)
        self.at, self.number = at, number

    def __iter__(self) -> Iterator[str]:
        for index, name in enumerate(list.__iter__(self)):
            if index == self.at:
                os.kill(os.getpid(), self.number)
            yield name


def test_a_signal_stops_the_batch_with_its_rows_and_exit_130(tmp_path: Path) -> None:
    # Issue 61: one exit for an interrupt: localize once begun exited 0. Now 130, with every finished row.
    scene = write_scene(tmp_path / "setup.toml", size_px=384)
    frame = tmp_path / "f.png"
    assert main(["render", "--scene", str(scene), "--tip", "0", "0", "4", "--out", str(frame)]) == 0
    images = _InterruptedAt([str(frame)] * 5, at=2, number=signal.SIGTERM)
    batch = localize_batch(images, read_setup(scene), "precise", tmp_path / "poses.csv")
    assert (batch.rows, batch.stopped_by, batch.exit_code) == (2, "SIGTERM", 130)
    assert [row["status"] for row in read_poses(tmp_path / "poses.csv")] == ["ok", "ok"]
    batch = localize_batch(_InterruptedAt([str(tmp_path / "none.png")] * 3, at=1), read_setup(scene), "thesis",
                           tmp_path / "poses.csv")  # fmt: skip
    assert (batch.rows, batch.none_read, batch.exit_code) == (1, True, 130)  # the interrupt, not the files


def test_localize_fit_radius_needs_the_precise_method_and_20_frames(tmp_path: Path) -> None:
    scene = write_scene(tmp_path / "setup.toml", size_px=384)
    frame = tmp_path / "f.png"
    assert main(["render", "--scene", str(scene), "--tip", "0", "0", "4", "--out", str(frame)]) == 0
    setup = read_setup(scene)
    with pytest.raises(SpotnavError, match="--fit-radius works with --method precise"):
        localize_batch([str(frame)], setup, "thesis", tmp_path / "p.csv", fit_radius=True)
    with pytest.raises(SpotnavError, match="at least 20 frames"):
        localize_batch([str(frame)], setup, "precise", tmp_path / "p.csv", fit_radius=True)


def _black_frames(folder: Path, count: int, size_px: int) -> list[str]:
    names = [str(folder / f"black{i}.png") for i in range(count)]
    for name in names:
        cv2.imwrite(name, np.zeros((size_px, size_px, 3), np.uint8))
    return names


def test_a_batch_that_reads_none_of_its_images_exits_2_with_one_line(tmp_path: Path) -> None:
    # Issue 44: a setup of the wrong camera size made every frame wrong_size, and the batch exited 0.
    setup = setup_from_toml("[camera]\nwidth_px = 128\nheight_px = 128\n")
    images = [*_black_frames(tmp_path, 2, 64), str(tmp_path / "missing.png")]
    batch = localize_batch(images, setup, "precise", tmp_path / "poses.csv", report=lambda _: None)
    assert batch.statuses == {"wrong_size": 2, "unreadable": 1} and batch.exit_code == 2
    assert batch.all_failed == (
        "spotnav: error: none of the 3 images could be localized (unreadable: 1, wrong_size: 2): check the image "
        "files and the setup's camera.width_px and camera.height_px"
    )


def test_a_batch_read_without_a_pose_keeps_the_contract_s_exit_0_and_warns(tmp_path: Path) -> None:
    # The contract: localize exits 0 when it processed every image, even where no tip could be found. A batch
    # with no pose at all still says so in one line.
    setup = setup_from_toml("[camera]\nwidth_px = 64\nheight_px = 64\n")
    batch = localize_batch(_black_frames(tmp_path, 2, 64), setup, "precise", tmp_path / "poses.csv")
    assert batch.statuses == {"no_spot": 2} and batch.exit_code == 0
    assert batch.all_failed == (
        "spotnav: warning: no pose in any of the 2 images (no_spot: 2): each row's detail says why"
    )
