"""What ``track --record`` costs the tracker: a session's tracked frames' latency with and without the recording.

:func:`run_recording_cost` renders a helix video and tracks it with :class:`~spotnav.app.session.TrackSession`
(the video decoded in a second process, as ``spotnav track`` does), alternately without and with a recording, so
that a shared machine's other work falls on both alike; :func:`recording_cost_markdown` tells the ratios.
"""

from __future__ import annotations

import csv
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path

from spotnav.app.sequence_render import render_sequence
from spotnav.app.session import TrackSession
from spotnav.experiments.bench import BenchRow
from spotnav.experiments.scenes import thesis_world, with_true_edge

__all__ = ["RECORDING_STAGES", "VIDEO_FPS", "recording_cost_markdown", "run_recording_cost"]

RECORDING_STAGES = ("tracking a video", "tracking a video, --record")
VIDEO_FPS = 100.0  # the helix video's frame rate (the session decodes it as fast as it can)


def run_recording_cost(sizes: Sequence[int], frames: int = 300, passes: int = 3, beams: int = 1) -> list[BenchRow]:
    """The tracked frames' latency (``poses.csv``'s ``latency_ms``, mode ``tracked``) over ``passes`` sessions
    without a recording and ``passes`` with one, alternating (without first in even passes, with first in odd
    ones), on a ``frames``-frame helix video at each size; a row for each of :data:`RECORDING_STAGES` and size,
    every pass's tracked frames together.

    The video and the recordings go to a temporary folder, each recording deleted after its pass.
    """
    if frames < 2 or passes < 1:
        raise ValueError(f"frames must be >= 2 and passes >= 1, got {frames} and {passes}")
    rows = []
    with tempfile.TemporaryDirectory(prefix="spotnav-recording-cost-") as temporary:
        folder = Path(temporary)
        for size in sizes:
            setup = thesis_world(size, beams)
            localizer = with_true_edge(setup)  # the simulation knows its geometry
            video = folder / f"helix_{size}.mkv"
            render_sequence(setup, "helix", video, frames=frames, fps=VIDEO_FPS, tremor_mm=0.0, seed=0)
            times: dict[str, list[float]] = {stage: [] for stage in RECORDING_STAGES}
            for number in range(passes):
                for recorded in (False, True) if number % 2 == 0 else (True, False):
                    kept = folder / f"recording_{size}_{number}" if recorded else None
                    out = folder / "poses.csv"
                    TrackSession(localizer, str(video), out, record=kept, report=lambda line: None).run()
                    times[RECORDING_STAGES[recorded]] += _tracked_latencies(out)
                    if kept is not None:
                        shutil.rmtree(kept)
            rows += [BenchRow.of_times(size, stage, values) for stage, values in times.items() if values]
    return rows


def _tracked_latencies(poses_csv: Path) -> list[float]:
    """``latency_ms`` of a session's frames whose mode is ``tracked``."""
    with poses_csv.open(newline="", encoding="utf-8") as handle:
        return [float(row["latency_ms"]) for row in csv.DictReader(handle) if row["mode"] == "tracked"]


def recording_cost_markdown(rows: Sequence[BenchRow]) -> str:
    """The rows as a markdown table, and each size's median and 99th percentile with the recording as a ratio to
    those without."""
    lines = [
        "| size px | session | median ms | p99 ms | max ms | tracked frames |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    lines += [
        f"| {r.size_px} | {r.stage} | {r.median_ms:.2f} | {r.p99_ms:.2f} | {r.max_ms:.2f} | {r.frames} |" for r in rows
    ]
    by_key = {(r.size_px, r.stage): r for r in rows}
    for size in sorted({r.size_px for r in rows}):
        without, recorded = (by_key.get((size, stage)) for stage in RECORDING_STAGES)
        if without and recorded:
            median, p99 = recorded.median_ms / without.median_ms, recorded.p99_ms / without.p99_ms
            lines.append(
                f"\n{size} px: with --record, the tracked frame's median is x{median:.2f} and its 99th percentile "
                f"x{p99:.2f} of tracking without it."
            )
    return "\n".join(lines)
