"""The light as the camera records it: the precise method on the helix over exposure and over a blur of the frame.

Two tables. Exposure (``render.exposure_stops``): from the example's, through
the thesis's (+4.5: every channel clipped inside the spots), to +6 stops,
where the clipped spots are read from their flanks. A Gaussian blur of the
encoded frame (``faults.frame_blur_px``: a codec, a soft lens or a camera's
sharpening undone), which the noise beside each spot measures. Each row: the
frames answered, the error of the ``ok`` frames, their share within 3
``sigma_mm`` and the refusals.
"""

from __future__ import annotations

from dataclasses import replace

from spotnav.app.paths import path_poses
from spotnav.experiments.report import Experiment, Options, markdown_table
from spotnav.experiments.runner import (
    FrameJob,
    FrameResult,
    Variant,
    count_refusals,
    error_cells,
    run_frame,
    summarize,
)
from spotnav.experiments.scenes import thesis_world, with_true_edge
from spotnav.setup.config import Setup

__all__ = ["EXPOSURE_STOPS", "FRAME_BLURS_PX", "run_light"]

EXPOSURE_STOPS = (0.0, 2.0, 3.0, 4.5, 6.0)
FRAME_BLURS_PX = (1.0, 1.5, 2.0, 3.0)  # and none: the exposure's +0 row


def run_light(options: Options) -> Experiment:
    """Both tables on ``options.count`` helix tips at ``options.size_px``, one beam, 1 W, the exact setup.

    The exposure's +0 row is the frame blur's 0 px row (the same frames).
    """
    header = ["disturbance", "ok", "mean [mm]", "max [mm]", "within 3 sigma", "refusals"]
    rows: list[list[str]] = []
    answered = {"exposure": [0, 0], "blur": [0, 0]}
    worst = {"exposure": 0.0, "blur": 0.0}
    cases: list[tuple[str, str, Setup]] = []
    for stops in EXPOSURE_STOPS:
        label = f"{stops:+.1f} stops" + (" (no blur)" if stops == 0.0 else "")
        cases.append(("exposure", label, thesis_world(options.size_px, 1, exposure_stops=stops)))
    for blur_px in FRAME_BLURS_PX:
        world = thesis_world(options.size_px, 1)
        cases.append(("blur", f"{blur_px:.1f} px", replace(world, faults=replace(world.faults, frame_blur_px=blur_px))))
    for index, (kind, label, world) in enumerate(cases):
        results = _helix(options, world, 1000 * index, f"light: {kind} {label}")
        summary = summarize(results)
        row = [f"{kind} {label}", f"{summary.ok}/{summary.frames}", *error_cells(summary), count_refusals(results)]
        rows.append(row)
        answered[kind] = [answered[kind][0] + summary.ok, answered[kind][1] + summary.frames]
        if summary.ok:
            worst[kind] = max(worst[kind], summary.max_mm)
    lines = [
        "## The light as the camera records it: exposure and blur",
        "",
        f"The helix ({options.count} tips per row, {options.size_px} px, 1 W, one beam, the exact setup) by the "
        "precise method. Exposure in stops over the example's (+4.5: the thesis's, every channel clipped inside "
        "the spots); blur: a Gaussian of that sigma applied to the encoded 8-bit frame (none in the exposure rows).",
        "",
        *markdown_table(header, rows),
    ]
    summary_line = "light: " + "; ".join(
        f"{kind}: {answered[kind][0]}/{answered[kind][1]} frames ok"
        + (f", max error {worst[kind]:.4f} mm" if answered[kind][0] else "")
        for kind in answered
    )
    return Experiment("light", "\n".join(lines), summary_line)


def _helix(options: Options, world: Setup, seed: int, label: str) -> list[FrameResult]:
    """The helix's ``options.count`` tips rendered in ``world`` (noise seeds from ``seed``), localized by the precise
    method with the world as its setup."""
    poses = path_poses("helix", options.count, world.instrument.insertion_in_eye)
    variants = (Variant("precise", with_true_edge(world), "precise"),)
    jobs = [FrameJob(world, pose, seed + i, variants) for i, pose in enumerate(poses)]
    return [output[0] for output in options.runner.map(run_frame, jobs, label)]
