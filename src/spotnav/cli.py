"""Command line: ``spotnav scene|render|localize|show|track|calibrate|evaluate|analyze|reproduce|bench|sweep|...``.

``main(argv)`` returns the exit code, so tests call it in-process. Unusable arguments or setups end with one line
``spotnav: error: ...`` and exit code 2. It only parses (:mod:`spotnav.arguments`) and prints; :mod:`spotnav.app` works.
"""

from __future__ import annotations

import sys

from spotnav.errors import SpotnavError

TYPE_CHECKING = False  # mypy reads the block below; at run time the start imports as little as it can
if TYPE_CHECKING:
    import argparse
    from collections.abc import Callable, Sequence
    from typing import Any

    import numpy as np

    from spotnav.setup.config import Setup
    from spotnav.setup.geometry import InstrumentPose

__all__ = ["main"]


class UsageError(SpotnavError):
    """Arguments that cannot be used."""


def _cmd_scene(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from spotnav.files.setup_files import read_opencv_camera, read_setup, setup_to_toml
    from spotnav.setup.config import Setup
    from spotnav.setup.examples import EXAMPLES, MICROSCOPE_EXAMPLES
    from spotnav.setup.microscope import Camera

    if (args.example is None) == (args.opencv is None) or (args.exact and args.example is None):
        raise UsageError("scene needs --example [--exact] (a setup with the thesis's values) or --opencv FILE")
    if args.example is not None:
        sys.stdout.write((EXAMPLES if args.exact else MICROSCOPE_EXAMPLES)[args.example])
        return 0
    base = read_setup(args.scene) if args.scene else Setup()
    width, height, matrix, distortion = read_opencv_camera(args.opencv)
    nominal = base.camera
    camera = Camera.calibrated(
        width, height, matrix, distortion, nominal.rotation_to_camera, nominal.translation_to_camera_mm
    ).with_lens_of(nominal)
    setup = replace(base, camera=camera)
    header = (
        f"written by spotnav scene --opencv {args.opencv}: OpenCV's camera matrix and distortion, the pose of "
        f"{args.scene or 'the thesis setup'}'s camera; spotnav calibrate measures the pose"
    )
    sys.stdout.write(setup_to_toml(setup, header))
    return 0


def _at_least(least: int, **options: int | None) -> None:
    """Refuse an option (``full_every``: ``--full-every``) given below ``least``."""
    for name, value in options.items():
        if value is not None and value < least:
            raise UsageError(f"--{name.replace('_', '-')} must be at least {least}, got {value}")


def _finite_vector(name: str, values: Sequence[float]) -> np.ndarray:
    import numpy as np

    vector = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(vector)):
        raise UsageError(f"{name} must be finite numbers, got {' '.join(map(str, values))}")
    return vector


def _pose(args: argparse.Namespace, setup: Setup) -> InstrumentPose:
    """The pose of ``--tip`` (inside the eye) and ``--axis`` (default: from the insertion point)."""
    from spotnav.app.sequence_render import check_inside
    from spotnav.setup.geometry import InstrumentPose

    tip = _finite_vector("--tip", args.tip)
    check_inside(setup, tip, "--tip")
    if args.axis is None:
        return InstrumentPose.through_insertion(tip, setup.instrument.insertion_in_eye)
    axis = _finite_vector("--axis", args.axis)
    if not axis.any():
        raise UsageError("--axis must not be the zero vector")
    return InstrumentPose(tip, axis)


def _cmd_render(args: argparse.Namespace) -> int:
    from dataclasses import replace
    from pathlib import Path

    import numpy as np

    from spotnav.app.sequence_render import render_sequence
    from spotnav.files.images import write_image
    from spotnav.files.poses import write_truth_json
    from spotnav.files.setup_files import read_setup
    from spotnav.optics.render import Renderer
    from spotnav.setup.geometry import beam_axes

    setup = read_setup(args.scene)
    if args.seed < 0:
        raise UsageError(f"--seed must be at least 0, got {args.seed}")
    if args.power is not None:
        if not np.isfinite(args.power) or args.power < 0:
            raise UsageError(f"--power must be a finite number >= 0, got {args.power}")
        setup = replace(setup, light=replace(setup.light, power_w=args.power))
    if args.path is not None:
        if args.tip is not None or args.axis is not None:
            raise UsageError("--path renders a sequence: leave out --tip and --axis")
        rendered = render_sequence(
            setup, args.path, args.out, frames=args.frames, fps=args.fps, tremor_mm=args.tremor, seed=args.seed
        )
        print(f"wrote {rendered.frames} frames to {rendered.out} and the truth to {rendered.truth}", file=sys.stderr)
        return 0
    if args.tip is None:
        raise UsageError("render needs --tip X Y Z (one frame) or --path (a sequence)")
    pose = _pose(args, setup)
    image = Renderer(setup).render(pose, seed=args.seed)
    out = Path(args.out)
    write_image(out, image)
    axes = beam_axes(pose.axis, setup.instrument.beam_count, setup.instrument.beam_tilt)
    write_truth_json(out.with_suffix(".json"), pose, axes, setup, seed=args.seed, image=out.name)
    print(f"wrote {out} and {out.with_suffix('.json')}", file=sys.stderr)
    return 0


def _cmd_track(args: argparse.Namespace) -> int:
    from spotnav.app.session import IgtlSettings, TrackLimits, TrackSession, camera_settings, replay_speed
    from spotnav.files.setup_files import read_setup

    setup = read_setup(args.scene, localizing=True)
    limits = TrackLimits(args.max_frames, args.duration)
    camera = camera_settings(args.camera_size, args.fps, args.exposure)
    igtl_args = (args.igtl_host, args.igtl_device, args.igtl_wait, args.igtl_stale)
    igtl = None if args.igtl is None else IgtlSettings(args.igtl, *igtl_args)
    session = TrackSession(
        setup,
        args.source,
        args.out,
        through_insertion=args.method == "precise",
        limits=limits,
        camera=camera,
        igtl=igtl,
        overlay=args.overlay,
        record=args.record,
        replay_speed=replay_speed(args.replay_speed),
    )
    run = session.run()
    print(f"wrote {args.out}: {run.summary()}", file=sys.stderr)
    if run.wrong_size_stop:
        print(f"spotnav: error: {run.wrong_size} frames in a row are not the setup's camera size", file=sys.stderr)
    return run.exit_code


def _cmd_localize(args: argparse.Namespace) -> int:
    from spotnav.app.batch import localize_batch
    from spotnav.app.status_style import status_counts
    from spotnav.files.setup_files import read_setup

    setup = read_setup(args.scene, localizing=True)
    batch = localize_batch(args.images, setup, args.method, args.out, fit_radius=args.fit_radius)
    if batch.radius is not None:
        fitted = batch.radius
        print(
            f"eye.radius_mm = {fitted.radius_mm:.4f} +- {fitted.radius_sigma_mm:.4f} (1 sigma, {fitted.frames} frames)"
        )
    ended = f" (stopped by {batch.stopped_by})" if batch.stopped_by else ""
    print(
        f"wrote {args.out}: {batch.rows} images, {status_counts(batch.statuses, 'no images')}{ended}", file=sys.stderr
    )
    if batch.all_failed:
        print(batch.all_failed, file=sys.stderr)
    return batch.exit_code


def _cmd_show(args: argparse.Namespace) -> int:
    from spotnav.app.session import ready
    from spotnav.app.show import show_frame
    from spotnav.files.images import read_image, write_image
    from spotnav.files.setup_files import read_setup

    setup = read_setup(args.scene, localizing=True)
    image = read_image(args.frame, expected_size=(setup.camera.width_px, setup.camera.height_px))
    ready(setup)
    shown = show_frame(image, setup, args.method, crop=args.crop)
    write_image(args.out, shown.canvas)
    print(shown.text())
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    import numpy as np

    from spotnav.experiments.bench import bench_markdown, run_bench, run_stress, stress_markdown
    from spotnav.experiments.profiling import profile_markdown, run_profile
    from spotnav.experiments.recording_cost import recording_cost_markdown, run_recording_cost

    if any(size < 128 for size in args.sizes):
        raise UsageError(f"--sizes must be at least 128 px, got {' '.join(map(str, args.sizes))}")
    _at_least(2, frames=args.frames)
    _at_least(1, full_every=args.full_every, passes=args.passes)
    if not (np.isfinite(args.memory_mb) and args.memory_mb >= 0):
        raise UsageError(f"--memory-mb must be a number >= 0, got {args.memory_mb}")
    if sum((args.profile, args.stress, args.record)) > 1:
        raise UsageError("--profile, --stress and --record are different runs: give one of them")
    if args.record:
        print(recording_cost_markdown(run_recording_cost(args.sizes, args.frames, args.passes, args.beams)))
        return 0
    if args.profile:
        print(profile_markdown(run_profile(args.sizes, frames=args.frames, beams=args.beams)))
        return 0
    if args.stress:
        if args.hide_every < 2:
            raise UsageError(f"--hide-every must be at least 2, got {args.hide_every}")
        print(stress_markdown([run_stress(size, args.frames, args.hide_every, args.beams) for size in args.sizes]))
        return 0
    rows = run_bench(
        args.sizes,
        frames=args.frames,
        beams=args.beams,
        full_every=args.full_every,
        memory_mb=args.memory_mb,
        passes=args.passes,
    )
    print(bench_markdown(rows))
    return 0


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from pathlib import Path

    from spotnav.app.calibration_job import run_calibration
    from spotnav.files.setup_files import read_setup, setup_to_toml

    setup = read_setup(args.scene)
    fit = list(args.fit or []) + ["eye-radius"] * args.fit_radius + ["light-radius"] * args.fit_light_radius
    job = run_calibration(
        setup, args.poses, args.images, fit=fit, fix=args.fix or [], height_correction=args.height_correction
    )
    header = f"written by spotnav calibrate from {args.scene} and {args.poses}\n" + "\n".join(job.lines)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(setup_to_toml(job.setup, header), encoding="utf-8")
    print("\n".join(job.lines))
    print(f"wrote {out}", file=sys.stderr)
    return 0


def _cmd_analyze(args: argparse.Namespace) -> int:
    from pathlib import Path

    from spotnav.app.bound import bound_text, run_bound, write_bound
    from spotnav.app.paths import path_poses
    from spotnav.experiments.core import approximation_text
    from spotnav.files.setup_files import read_setup

    if args.topic == "approximation":
        print(approximation_text())
        return 0
    if args.scene is None or (args.tip is None) == (args.path is None) or (args.path and args.axis):
        raise UsageError("analyze bound needs --scene SETUP.toml and either --tip X Y Z [--axis] or --path")
    _at_least(1, poses=args.poses)
    setup = read_setup(args.scene)
    path = None if args.path is None else path_poses(args.path, args.poses, setup.instrument.insertion_in_eye)
    run = run_bound(setup, path or [_pose(args, setup)], through_insertion=not (args.free_axis or args.axis))
    written = write_bound(Path(args.out), run) if args.out else []
    print(bound_text(run))
    if written:
        print(f"wrote {', '.join(map(str, written))}", file=sys.stderr)
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from pathlib import Path

    from spotnav.app.evaluate import evaluate_poses, evaluation_text, write_evaluation
    from spotnav.files.poses import read_known_poses, read_poses_csv

    evaluation = evaluate_poses(read_poses_csv(args.poses), read_known_poses(args.truth))
    written = write_evaluation(Path(args.out), evaluation) if args.out else []  # the files first: stdout may close
    print(evaluation_text(evaluation))
    if written:
        print(f"wrote {', '.join(map(str, written))}")
    return 0


def _cmd_reproduce(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from spotnav.experiments import reproduce

    _at_least(1, workers=args.workers, size=args.size, poses=args.poses)
    out = Path(args.out or ("results/quick" if args.quick else "results/full"))
    start = time.perf_counter()
    reproduce(out, quick=args.quick, only=args.only or (), workers=args.workers, size_px=args.size, poses=args.poses)
    print(f"wrote {out / 'report.md'} in {time.perf_counter() - start:.0f} s")
    return 0


def _cluster(args: argparse.Namespace) -> dict[str, Any]:
    """``sweep``'s and ``design``'s cluster options, checked before their file is read, and their log."""
    from spotnav.experiments.cluster import check_cluster_options

    check_cluster_options(args.scheduler, args.workers, args.dashboard, args.scheduler_timeout)
    options = {"scheduler": args.scheduler, "workers": args.workers, "dashboard": args.dashboard}
    return options | {"scheduler_timeout_s": args.scheduler_timeout, "log": lambda line: print(line, file=sys.stderr)}


def _cmd_sweep(args: argparse.Namespace) -> int:
    from pathlib import Path

    from spotnav.experiments.sweep import EXAMPLE_SWEEP, run_sweep

    if args.example:
        sys.stdout.write(EXAMPLE_SWEEP)
        return 0
    if args.file is None or args.out is None:
        raise UsageError("sweep needs FILE and --out DIR (or --example)")
    options, path = _cluster(args), Path(args.file)
    run = run_sweep(path.read_text(encoding="utf-8"), args.out, base_dir=path.parent, resume=args.resume, **options)
    print(run.summary())
    return 0


def _cmd_sweep_report(args: argparse.Namespace) -> int:
    from pathlib import Path

    from spotnav.experiments.sweep_report import write_sweep_report

    print(write_sweep_report(args.directory))
    print(f"wrote {Path(args.directory) / 'summary.md'}, summary.csv and a plot per swept parameter", file=sys.stderr)
    return 0


def _cmd_design(args: argparse.Namespace) -> int:
    from pathlib import Path

    from spotnav.experiments.design import EXAMPLE_DESIGN, run_design

    if args.example:
        sys.stdout.write(EXAMPLE_DESIGN)
        return 0
    if args.file is None or args.out is None:
        raise UsageError("design needs FILE and --out DIR (or --example)")
    options, path = _cluster(args), Path(args.file)
    print(run_design(path.read_text(encoding="utf-8"), args.out, base_dir=path.parent, **options).summary())
    return 0


_COMMANDS: dict[str, Callable[[argparse.Namespace], int]] = {
    "scene": _cmd_scene,
    "render": _cmd_render,
    "localize": _cmd_localize,
    "track": _cmd_track,
    "evaluate": _cmd_evaluate,
    "show": _cmd_show,
    "bench": _cmd_bench,
    "calibrate": _cmd_calibrate,
    "analyze": _cmd_analyze,
    "reproduce": _cmd_reproduce,
    "sweep": _cmd_sweep,
    "sweep-report": _cmd_sweep_report,
    "design": _cmd_design,
}


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (130: Ctrl-C or SIGTERM, at any moment: ``track`` and
    ``localize`` end after the frame in hand with every finished row and their summary, or, before their run began,
    with ``spotnav: interrupted`` and ``--out poses.csv``'s header; README, "Use")."""
    words = list(sys.argv[1:] if argv is None else argv)
    try:
        from spotnav.app import start

        with start.terminate_as_interrupt(), start.header_on_interrupt(words):
            from spotnav.arguments import build_parser

            args = build_parser().parse_args(words)
            start.compile_kernels_once(args, report=lambda line: print(line, file=sys.stderr, flush=True))
            code = _COMMANDS[args.command](args)
            sys.stdout.flush()  # a reader that left (| head) shows here, not at the interpreter's exit
            return code
    except (SpotnavError, OSError) as error:
        if isinstance(error, BrokenPipeError) and start.end_stdout_if_left():  # | head: all asked is written
            return 0
        message = str(error).splitlines()[0] if str(error) else type(error).__name__
        print(f"spotnav: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # before a command could stop cleanly, or a second Ctrl-C
        print("spotnav: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
