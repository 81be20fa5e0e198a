"""Experiments: render known poses, localize them, measure the error and write the report.

This layer may do I/O (CSV, Markdown, PNG figures, progress bars); the algorithm
modules below it do none. Frames are seeded per pose, so results do not depend
on the number of worker processes.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path

from spotnav.errors import InputError
from spotnav.experiments.calibration import run_calibration
from spotnav.experiments.chapter6 import run_paths, run_world
from spotnav.experiments.core import approximation_rows, run_approximation, run_volume
from spotnav.experiments.defocus import run_defocus
from spotnav.experiments.efficiency import run_efficiency
from spotnav.experiments.ellipse import run_ellipse
from spotnav.experiments.faults import run_faults
from spotnav.experiments.geometry import run_geometry
from spotnav.experiments.light import run_light
from spotnav.experiments.mismatch import run_mismatch
from spotnav.experiments.report import Experiment, Options
from spotnav.experiments.runner import FrameRunner
from spotnav.experiments.summary import summary_lines

__all__ = ["EXPERIMENTS", "ON_REQUEST", "approximation_rows", "reproduce"]

EXPERIMENTS: dict[str, Callable[[Options], Experiment]] = {
    "approximation": run_approximation,
    "ellipse": run_ellipse,
    "paths": run_paths,
    "efficiency": run_efficiency,
    "bumps": partial(run_world, "bumps"),
    "radius": partial(run_world, "radius"),
    "calibration": run_calibration,
    "volume": run_volume,
    "faults": run_faults,
    "light": run_light,
    "geometry": run_geometry,
    "mismatch": run_mismatch,
    "defocus": run_defocus,
}

# Studies that run only when named (--only): the mismatch study renders some 3000 frames and calibrates 32 times, the
# defocus study calibrates 6 times through 8 lenses each.
ON_REQUEST = frozenset({"mismatch", "defocus"})


def reproduce(
    out: Path,
    *,
    quick: bool = False,
    only: Sequence[str] = (),
    workers: int = 1,
    size_px: int | None = None,
    poses: int | None = None,
    log: Callable[[str], None] = print,
) -> list[Experiment]:
    """Run the experiments and write their CSVs, figures and ``report.md`` into ``out``.

    ``report.md`` opens with the summary table (:func:`spotnav.experiments.summary.summary_lines`), then each
    experiment's section in order.

    Parameters
    ----------
    out : Path
    quick : bool
        1024 px and 25 poses per path instead of 5000 px and 100.
    only : sequence of str
        Experiment names (default: all of :data:`EXPERIMENTS` but :data:`ON_REQUEST`, in its order).
    workers : int
        Processes for rendering and localizing.
    size_px, poses : int, optional
        Override the image size and the number of poses per path.
    log : callable
        Receives one line per finished experiment.
    """
    unknown = sorted(set(only) - set(EXPERIMENTS))
    if unknown:
        raise InputError(f"unknown experiment {unknown[0]!r}, allowed: {', '.join(EXPERIMENTS)}")
    out.mkdir(parents=True, exist_ok=True)
    size_px = size_px or (1024 if quick else 5000)
    count = poses or (25 if quick else 100)
    done = []
    started = time.perf_counter()
    with FrameRunner(workers) as runner:
        options = Options(out, size_px, count, runner)
        for name, run in EXPERIMENTS.items():
            if (only and name not in only) or (not only and name in ON_REQUEST):
                continue
            start = time.perf_counter()
            experiment = run(options)
            done.append(experiment)
            log(f"{experiment.name} ({time.perf_counter() - start:.0f} s): {experiment.summary}")
    command = "spotnav reproduce" + (" --quick" if quick else "")
    header = [
        "# spotnav reproduction of Hennerkes (2020)",
        "",
        f"Mode: {'quick' if quick else 'full'}, {size_px} px, {count} poses per path, "
        f"{workers} worker{'s' * (workers != 1)}, "
        f"{time.perf_counter() - started:.0f} s. Regenerate with `{command}`.",
        "",
        *summary_lines(done),
        "",
    ]
    (out / "report.md").write_text("\n".join(header) + "\n\n".join(e.markdown for e in done) + "\n", encoding="utf-8")
    return done
