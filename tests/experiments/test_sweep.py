"""Design sweeps: the sweep file, the plan, Dask runs (worker count, a killed worker, resume), each refusal's detail
and the report."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from distributed import LocalCluster
from hypothesis import given, settings
from hypothesis import strategies as st

from spotnav.cli import main
from spotnav.experiments.sweep import EXAMPLE_SWEEP, TIMING_COLUMNS, Chunk, plan_chunks, read_sweep_table, run_sweep
from spotnav.experiments.sweep_file import (
    SWEEP_PARAMETERS,
    SweepError,
    apply_parameters,
    design_points,
    sweep_from_toml,
)
from spotnav.experiments.sweep_report import availability_curves, error_curves, summary_rows, write_sweep_report
from spotnav.setup.config import Setup
from spotnav.setup.values import SetupError

TINY = """\
seed = 3
[grid]
size_px = [256]
instrument.beam_half_angle_deg = [8.0, 10.0]
[random]
samples = 2
light.power_w = [0.5, 1.5]
[frames]
paths = ["helix"]
count = 3
methods = ["thesis", "precise"]
chunk = 1
"""
TINY_FRAMES = 2 * 2 * 3  # angles x samples x frames
# Two design points: a light too dim to see (every frame no_spot, with its reason) and one that localizes.
DARK = (
    TINY.replace("instrument.beam_half_angle_deg = [8.0, 10.0]", "light.power_w = [0.00001, 1.0]")
    .replace("[random]\nsamples = 2\nlight.power_w = [0.5, 1.5]\n", "")
    .replace("count = 3", "count = 2")
)


def _same_results(a: pa.Table, b: pa.Table) -> bool:
    """Equal in every column but the timings (NaN equals NaN)."""
    if a.column_names != b.column_names or a.num_rows != b.num_rows:
        return False
    for name in a.column_names:
        if name in TIMING_COLUMNS:
            continue
        x, y = a[name].to_numpy(zero_copy_only=False), b[name].to_numpy(zero_copy_only=False)
        same = np.array_equal(x, y, equal_nan=True) if x.dtype.kind == "f" else bool(np.all(x == y))
        if not same:
            return False
    return True


def _each_frame_once(table: pa.Table, frames: int, methods: int) -> bool:
    keys = zip(*(table[c].to_pylist() for c in ("point", "path", "frame", "method")), strict=True)
    return table.num_rows == frames * methods and len(set(keys)) == table.num_rows


def test_the_example_parses_and_plans_its_frames() -> None:
    sweep = sweep_from_toml(EXAMPLE_SWEEP)
    points = design_points(sweep)
    assert len(points) == 3 * 2 * 2
    assert points[0] == {
        "size_px": 512,
        "instrument.beam_half_angle_deg": 6.0,
        "instrument.beam_count": 1,
        "light.power_w": 0.1,
    }
    chunks = plan_chunks(sweep)
    assert sum(c.stop - c.start for c in chunks) == 12 * 20
    assert chunks[1] == Chunk(1, 0, "helix", 10, 20)


def test_random_draws_are_seeded_and_within_their_ranges() -> None:
    text = TINY.replace("[grid]", "[grid]\ninstrument.beam_count = [1, 3]").replace("samples = 2", "samples = 25")
    text = text.replace("size_px = [256]", "").replace("[random]", "[random]\nsize_px = [200, 300]")
    sweep = sweep_from_toml(text)
    points = design_points(sweep)
    assert points == design_points(sweep_from_toml(text))
    powers = np.array([p["light.power_w"] for p in points])
    assert len(points) == 100 and np.all((powers >= 0.5) & (powers <= 1.5)) and len(np.unique(powers)) == 100
    assert {p["instrument.beam_count"] for p in points} == {1, 3}
    sizes = [p["size_px"] for p in points]
    assert all(isinstance(n, int) and 200 <= n <= 300 for n in sizes) and len(set(sizes)) > 10
    other = design_points(sweep_from_toml(text.replace("seed = 3", "seed = 4")))
    assert [p["light.power_w"] for p in other] != list(powers)


@pytest.mark.parametrize("name", list(SWEEP_PARAMETERS))
def test_every_sweep_parameter_sets_its_setup_key(name: str) -> None:
    value = {
        "size_px": 300,
        "instrument.beam_half_angle_deg": 7.0,
        "instrument.beam_count": 3,
        "instrument.beam_tilt_deg": 12.0,
        "light.power_w": 0.5,
        "light.blend": 0.3,
        "render.full_well_e": 5000.0,
        "render.read_noise_e": 4.0,
        "render.exposure_stops": 1.0,
        "eye.radius_mm": 12.0,
        "world.eye_radius_mm": 13.0,
    }[name]
    setup = apply_parameters(Setup(), {name: value})
    if name == "size_px":
        assert (setup.camera.width_px, setup.camera.height_px) == (300, 300)
    else:
        section, key = name.split(".")
        assert getattr(getattr(setup, section), key) == value
        assert getattr(getattr(Setup(), section), key) != value


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("seed = 3", "seeds = 3"), "seeds is not a known key"),
        (("seed = 3", "seed = -1"), "seed must be an integer >= 0"),
        (("size_px = [256]", "size_px = []"), "grid.size_px must be a non-empty list"),
        (("size_px = [256]", "size_px = [256.5]"), "grid.size_px must hold integers"),
        (("size_px = [256]", "size_px = [8]"), "camera.width_px = 8 is out of range"),
        (("size_px = [256]", "light.colour = [1]"), "grid.light.colour is not a sweep parameter"),
        (("[0.5, 1.5]", "[1.5, 0.5]"), "random.light.power_w must have low <= high"),
        (("[0.5, 1.5]", "[0.5]"), "random.light.power_w must be [low, high]"),
        (("[0.5, 1.5]", '[0.5, "x"]'), "random.light.power_w must hold finite numbers"),
        (("samples = 2", "samples = 0"), "random.samples must be an integer >= 1"),
        (('"thesis", "precise"', '"thesis", "magic"'), "frames.methods must be a non-empty list"),
        (('paths = ["helix"]', 'paths = ["nowhere.csv"]'), "frames.paths: "),
        (("count = 3", "count = 0"), "frames.count must be an integer >= 1"),
        (("chunk = 1", "chunks = 1"), "frames.chunks is not a known key"),
        (("[grid]", "[grid"), "not valid TOML"),
        (("seed = 3", 'seed = 3\nsetup = "missing.toml"'), "setup: cannot read"),
    ],
)
def test_a_bad_sweep_file_names_its_key(edit: tuple[str, str], message: str, tmp_path: Path) -> None:
    with pytest.raises((SweepError, SetupError), match=message.replace("[", r"\[").replace("(", r"\(")):
        sweep_from_toml(TINY.replace(*edit), tmp_path)


@settings(max_examples=60, deadline=None)
@given(st.text(max_size=200))
def test_random_text_parses_or_raises_a_sweep_error(text: str) -> None:
    try:
        sweep_from_toml(text)
    except (SweepError, SetupError) as error:
        assert str(error)


@pytest.mark.slow  # a sweep on clusters of 1 and 2 workers (30 s): make test-all
def test_results_do_not_depend_on_the_number_of_workers(tmp_path: Path) -> None:
    lines: list[str] = []
    one = run_sweep(TINY, tmp_path / "one", workers=1, dashboard="127.0.0.1:0", log=lines.append)
    assert len(lines) == 1 and lines[0].startswith("Dask dashboard: http://127.0.0.1:")  # issue 20
    two = run_sweep(TINY, tmp_path / "two", workers=2)
    serial = run_sweep(TINY, tmp_path / "serial", workers=0)
    assert (one.workers, two.workers, serial.workers) == (1, 2, 0)
    tables = [read_sweep_table(r.table.parent) for r in (one, two, serial)]
    assert _each_frame_once(tables[0], TINY_FRAMES, 2)
    assert _same_results(tables[0], tables[1]) and _same_results(tables[0], tables[2])
    statuses = tables[0]["status"].to_numpy(zero_copy_only=False)
    errors = tables[0]["error_mm"].to_numpy()
    assert np.mean(statuses == "ok") >= 0.9 and np.nanmax(errors) < 0.5  # 256 px: a real localization


def test_a_killed_worker_loses_no_frame_and_repeats_none(tmp_path: Path) -> None:
    text = TINY.replace("count = 3", "count = 5")
    # No client of the test's own: a second client in this process raced the sweep's on its event loop.
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        killed: list[int] = []

        def kill_one_worker(chunk: Chunk) -> None:
            if not killed:
                pid = next(iter(cluster.workers.values())).pid  # the first worker's process, under its nanny
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)

        lines: list[str] = []
        out = tmp_path / "out"
        run = run_sweep(text, out, scheduler=cluster.scheduler_address, on_chunk=kill_one_worker, log=lines.append)
    assert killed and run.chunks_run == 2 * 2 * 5
    assert any(line.endswith("left mid-run: its tasks run again on the 1 left") for line in lines)  # issue 61
    table = read_sweep_table(tmp_path / "out")
    assert _each_frame_once(table, 2 * 2 * 5, 2)
    assert _same_results(table, read_sweep_table(run_sweep(text, tmp_path / "serial", workers=0).table.parent))


def test_resume_runs_only_the_missing_chunks(tmp_path: Path) -> None:
    out = tmp_path / "out"
    first = read_sweep_table(run_sweep(TINY, out, workers=0).table.parent)
    with pytest.raises(SweepError, match="pass --resume"):
        run_sweep(TINY, out, workers=0)
    (out / "frames.parquet").unlink()
    for name in ("chunk-000002.parquet", "chunk-000007.parquet"):
        (out / "chunks" / name).unlink()
    assert read_sweep_table(out).num_rows == (TINY_FRAMES - 2) * 2  # the chunks written so far
    resumed = run_sweep(TINY, out, workers=0, resume=True)
    assert (resumed.chunks_run, resumed.chunks_resumed, resumed.frames_run) == (2, TINY_FRAMES - 2, 2)
    assert _same_results(first, read_sweep_table(out))
    with pytest.raises(SweepError, match="holds a different sweep"):
        run_sweep(TINY.replace("seed = 3", "seed = 4"), out, workers=0, resume=True)


def test_each_refusal_keeps_its_detail_and_the_report_counts_and_plots_the_statuses(tmp_path: Path) -> None:
    run_sweep(DARK, tmp_path, workers=0)
    table = read_sweep_table(tmp_path)
    assert table.column_names[table.column_names.index("status") + 1] == "detail"
    power, statuses, details = (table[c].to_numpy(zero_copy_only=False) for c in ("light.power_w", "status", "detail"))
    dim = power < 0.01
    assert np.all(statuses[dim] == "no_spot") and np.all(statuses[~dim] == "ok")
    assert all(d.startswith("no region brighter than the background") for d in details[dim])
    assert all(d == "" for d in details[~dim])
    header, rows = summary_rows(table)
    assert [(row[header.index("method")], row[header.index("refused")]) for row in rows] == [
        ("thesis", "2 no_spot"),
        ("precise", "2 no_spot"),
        ("thesis", "none"),
        ("precise", "none"),
    ]
    x, fractions = availability_curves(table, "light.power_w")["1 beam, precise"]
    assert list(x) == [0.00001, 1.0] and sorted(fractions) == ["no_spot", "ok"]
    assert list(fractions["no_spot"]) == [1.0, 0.0] and list(fractions["ok"]) == [0.0, 1.0]
    assert list(error_curves(table, "light.power_w")["1 beam, precise"][0]) == [1.0]  # the error: ok frames only
    text = write_sweep_report(tmp_path)
    assert "Statuses: 4 no_spot, 4 ok." in text and "| 1e-05 | helix | thesis | 2 | 0 | 0 | 2 no_spot | nan |" in text
    assert "| thesis | no_spot | 2 | no region brighter than the background (contrast " in text
    assert (tmp_path / "error_vs_power.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_sweep_from_before_the_detail_column_resumes_and_says_so(tmp_path: Path) -> None:
    out = tmp_path / "out"
    first = read_sweep_table(run_sweep(DARK, out, workers=0).table.parent)
    (out / "frames.parquet").unlink()
    chunks = sorted((out / "chunks").glob("chunk-*.parquet"))
    for chunk in chunks[:2]:  # as a spotnav without the column wrote them
        pq.write_table(pq.read_table(chunk).drop_columns(["detail"]), chunk)
    chunks[-1].unlink()
    lines: list[str] = []
    resumed = run_sweep(DARK, out, workers=0, resume=True, log=lines.append)
    assert resumed.chunks_run == 1 and lines == [
        "2 chunks were written by an older spotnav, without the detail column: theirs is left empty (null)"
    ]
    table = read_sweep_table(out)
    assert table.column_names == first.column_names
    assert table["detail"].to_pylist() == [None] * 4 + first["detail"].to_pylist()[4:]
    assert _same_results(table.drop_columns(["detail"]), first.drop_columns(["detail"]))
    assert "| thesis | no_spot | 2 | (not kept: written by a spotnav without the detail column) |" in (
        write_sweep_report(out)
    )


def test_the_report_summarises_each_design_point_and_plots_both_curves(tmp_path: Path) -> None:
    text = TINY.replace("samples = 2", "samples = 1").replace("light.power_w = [0.5, 1.5]", "")
    text = text.replace("[random]", "[random]\n").replace("[grid]", "[grid]\nlight.power_w = [0.3, 1.0]")
    run_sweep(text, tmp_path, workers=0)
    table = read_sweep_table(tmp_path)
    header, rows = summary_rows(table)
    assert header[:2] == ["instrument.beam_half_angle_deg", "light.power_w"]
    assert len(rows) == 2 * 2 * 2 and all(row[header.index("frames")] == 3 for row in rows)
    curves = error_curves(table, "instrument.beam_half_angle_deg")
    assert set(curves) == {"1 beam, thesis", "1 beam, precise"}
    assert list(curves["1 beam, precise"][0]) == [8.0, 10.0]
    assert np.all(curves["1 beam, precise"][1] < curves["1 beam, thesis"][1])  # the precise method is better
    text = write_sweep_report(tmp_path)
    assert "| 8 | 0.3 | helix | precise | 3 |" in text and "| availability | refused | mean_mm |" in text
    for name in ("error_vs_cone_angle.png", "error_vs_power.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and (tmp_path / name).stat().st_size > 20000
    assert "](error_vs_power.png)" in text
    assert (tmp_path / "summary.csv").read_text().splitlines()[0].startswith("instrument.beam_half_angle_deg,")


def test_the_report_plots_against_what_was_swept(tmp_path: Path) -> None:
    # Issue 20: a sweep over size and read noise plots against size and read noise, not angle and power.
    text = TINY.replace("samples = 2", "samples = 1").replace("light.power_w = [0.5, 1.5]", "")
    text = text.replace("size_px = [256]", "size_px = [256, 384]\nrender.read_noise_e = [2.0, 30.0]")
    text = text.replace("instrument.beam_half_angle_deg = [8.0, 10.0]", "")
    run_sweep(text, tmp_path, workers=0)
    report = write_sweep_report(tmp_path)
    assert sorted(p.name for p in tmp_path.glob("error_vs_*.png")) == ["error_vs_read_noise.png", "error_vs_size.png"]
    assert "](error_vs_size.png)" in report and "](error_vs_read_noise.png)" in report


def test_cli_sweep_example_runs_serially_and_reports(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sweep", "--example"]) == 0
    example = capsys.readouterr().out
    assert sweep_from_toml(example).frames == 20
    (tmp_path / "sweep.toml").write_text(TINY)
    assert main(["sweep", str(tmp_path / "sweep.toml"), "--out", str(tmp_path / "out"), "--workers", "0"]) == 0
    assert f"{TINY_FRAMES} frames" in capsys.readouterr().out
    assert main(["sweep-report", str(tmp_path / "out")]) == 0
    assert "# Sweep: 24 localizations" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["sweep"], "sweep needs FILE and --out DIR"),
        (["sweep", "missing.toml", "--out", "x"], "No such file"),
        (["sweep", "s.toml", "--out", "x", "--workers", "2", "--scheduler", "tcp://h:1"], "--workers sizes"),
        (["sweep-report", "nowhere"], "holds no sweep results"),
    ],
)
def test_cli_sweep_errors_are_one_line(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    error = capsys.readouterr().err
    assert message in error and len(error.strip().splitlines()) == 1
