"""``analyze bound``'s application: the bound of one pose or along a path, its text, CSV and plot."""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import numpy as np

from spotnav.app.bound import BOUND_COLUMNS, bound_text, run_bound, write_bound
from spotnav.app.paths import path_poses
from spotnav.experiments.scenes import thesis_world
from spotnav.setup.geometry import InstrumentPose


def test_a_path_gives_a_row_per_pose_and_its_summary(tmp_path: Path) -> None:
    world = thesis_world(256, 1, 1.0)
    poses = path_poses("helix", 4, world.instrument.insertion_in_eye)
    run = run_bound(world, poses)
    assert [b.status for b in run.bounds] == ["ok"] * 4
    text = bound_text(run)
    rms = np.sqrt(np.mean(run.totals_mm() ** 2))
    assert f"RMS {rms:.3g} mm" in text and "axis through the insertion point" in text
    written = write_bound(tmp_path, run)
    assert [p.name for p in written] == ["bound.csv", "bound.png"]
    with (tmp_path / "bound.csv").open(encoding="utf-8") as stream:
        rows = list(csv.DictReader(stream))
    assert tuple(rows[0]) == BOUND_COLUMNS and len(rows) == 4
    assert float(rows[2]["bound_tip_mm"]) == np.float64(f"{run.bounds[2].tip_mm:.6g}")


def test_one_pose_in_full_and_a_pose_without_light_said() -> None:
    world = thesis_world(256, 3, 1.0)
    pose = InstrumentPose.through_insertion(np.array([1.0, 0.5, 5.0]), world.instrument.insertion_in_eye)
    text = bound_text(run_bound(world, [pose], through_insertion=False))
    assert "axis unknown; the light's power, the beams' roll unknown" in text
    assert "tip sd (x y z)" in text and "axis sd" in text
    away = InstrumentPose(np.array([1.0, 0.5, 5.0]), np.array([0.0, 0.0, 1.0]))
    assert "no bound: no_light" in bound_text(run_bound(world, [away], through_insertion=False))


def test_a_path_tip_outside_the_eye_and_the_faults_left_out_are_said() -> None:
    world = thesis_world(256, 1, 1.0)
    world = replace(world, faults=replace(world.faults, glints=2, defocus_px=1.0))
    outside = InstrumentPose.through_insertion(np.array([0.0, 0.0, 30.0]), world.instrument.insertion_in_eye)
    inside = InstrumentPose.through_insertion(np.array([1.0, 0.5, 5.0]), world.instrument.insertion_in_eye)
    run = run_bound(world, [inside, outside])
    assert [b.status for b in run.bounds] == ["ok", "outside_eye"]
    assert run.ignored_faults == ("glints",)  # defocus is in the model
    assert "not in the bound: the setup's faults glints" in bound_text(run)
