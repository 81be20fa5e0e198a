"""Command line: ``spotnav scene|render|localize|show|track|calibrate|evaluate|analyze|reproduce|bench|sweep|...``.

``main(argv)`` returns the exit code, so tests call it in-process. Unusable
arguments or setups end with one line ``spotnav: error: ...`` and exit code 2.
"""

from __future__ import annotations

import argparse
import contextlib
import ipaddress
import os
import signal
import socket
import sys
import threading
import time
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path

import numpy as np

from spotnav import __version__
from spotnav.app.calibrate import EDGE_BAND_MARGIN, calibrate, calibrate_height_correction
from spotnav.app.evaluate import evaluate_poses, evaluation_text, write_evaluation
from spotnav.app.igtl import DEFAULT_DEVICE, DEFAULT_HOST, DEFAULT_PORT, PoseServer
from spotnav.app.overlay import crop_box, draw_overlay, fitted_spots
from spotnav.app.progress import progress
from spotnav.app.track import TrackedFrame, Tracker, frozen_heap, prepare_kernels
from spotnav.errors import SpotnavError
from spotnav.experiments import EXPERIMENTS, approximation_rows, reproduce
from spotnav.experiments.bench import bench_markdown, run_bench, run_stress, stress_markdown
from spotnav.experiments.profiling import profile_markdown, run_profile
from spotnav.experiments.sweep import EXAMPLE_SWEEP, run_sweep
from spotnav.experiments.sweep_report import write_sweep_report
from spotnav.files.capture import Frame
from spotnav.files.images import ImageReadError, display_name, read_image, write_image
from spotnav.files.poses import (
    TRACK_COLUMNS,
    PosesWriter,
    pose_row,
    read_known_poses,
    read_path_csv,
    read_poses_csv,
    track_row,
    write_truth_csv,
    write_truth_json,
)
from spotnav.files.sequences import CameraSettings, SequenceWriter, iter_frames
from spotnav.files.setup_files import read_opencv_camera, read_setup, setup_to_toml
from spotnav.optics.render import Renderer
from spotnav.pose.calibration import Calibration
from spotnav.pose.conefit.parameters import PARAMETER_GROUPS
from spotnav.pose.estimate import PoseEstimate
from spotnav.pose.known_frame import KnownFrame
from spotnav.pose.localize import DEFAULT_METHOD, METHODS, localize, localize_detailed
from spotnav.pose.self_calibration import prepare_self_calibration, self_calibrate_radius
from spotnav.setup.config import Camera, Setup
from spotnav.setup.examples import EXAMPLES
from spotnav.setup.geometry import InstrumentPose, beam_axes
from spotnav.setup.paths import helix_tips, resample_polyline, square_tips, tremor_offsets
from spotnav.setup.uncertainty import GEOMETRY_PARAMETERS

__all__ = ["main"]


class UsageError(SpotnavError):
    """Arguments that cannot be used."""


def _cmd_scene(args: argparse.Namespace) -> int:
    if (args.example is None) == (args.opencv is None):
        raise UsageError("scene needs --example (print the thesis's setup) or --opencv FILE (a calibrated camera)")
    if args.example is not None:
        sys.stdout.write(EXAMPLES[args.example])
        return 0
    base = read_setup(args.scene) if args.scene else Setup()
    width, height, matrix, distortion = read_opencv_camera(args.opencv)
    nominal = base.camera
    camera = Camera.calibrated(
        width, height, matrix, distortion, nominal.rotation_to_camera, nominal.translation_to_camera_mm
    )
    setup = replace(base, camera=camera)
    header = (
        f"written by spotnav scene --opencv {args.opencv}: OpenCV's camera matrix and distortion, the pose of "
        f"{args.scene or 'the thesis setup'}'s camera; spotnav calibrate measures the pose"
    )
    sys.stdout.write(setup_to_toml(setup, header))
    return 0


def _finite_vector(name: str, values: Sequence[float]) -> np.ndarray:
    vector = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(vector)):
        raise UsageError(f"{name} must be finite numbers, got {' '.join(map(str, values))}")
    return vector


def _cmd_render(args: argparse.Namespace) -> int:
    setup = read_setup(args.scene)
    if args.seed < 0:
        raise UsageError(f"--seed must be at least 0, got {args.seed}")
    if args.power is not None:
        if not np.isfinite(args.power) or args.power < 0:
            raise UsageError(f"--power must be a finite number >= 0, got {args.power}")
        setup = replace(setup, light=replace(setup.light, power_w=args.power))
    if args.path is not None:
        return _render_sequence(args, setup)
    if args.tip is None:
        raise UsageError("render needs --tip X Y Z (one frame) or --path (a sequence)")
    tip = _finite_vector("--tip", args.tip)
    _check_inside(setup, tip, "--tip")
    if args.axis is None:
        pose = InstrumentPose.through_insertion(tip, setup.instrument.insertion_in_eye)
    else:
        axis = _finite_vector("--axis", args.axis)
        if not np.any(axis):
            raise UsageError("--axis must not be the zero vector")
        pose = InstrumentPose(tip, axis)
    image = Renderer(setup).render(pose, seed=args.seed)
    out = Path(args.out)
    write_image(out, image)
    axes = beam_axes(pose.axis, setup.instrument.beam_count, setup.instrument.beam_tilt)
    write_truth_json(out.with_suffix(".json"), pose, axes, setup, seed=args.seed, image=out.name)
    print(f"wrote {out} and {out.with_suffix('.json')}", file=sys.stderr)
    return 0


def _check_inside(setup: Setup, tip: np.ndarray, name: str) -> None:
    if not setup.contains_point(tip):
        raise UsageError(
            f"{name} {' '.join(f'{v:g}' for v in tip)} lies outside the eye "
            f"(sphere of radius {setup.eye.radius_mm:g} mm centred at (0, 0, {setup.eye.radius_mm:g}))"
        )


def _path_tips(path: str, frames: int) -> np.ndarray:
    if path == "square":
        return square_tips(frames)
    if path == "helix":
        return helix_tips(frames)
    return resample_polyline(read_path_csv(path), frames)


def _render_sequence(args: argparse.Namespace, setup: Setup) -> int:
    if args.tip is not None or args.axis is not None:
        raise UsageError("--path renders a sequence: leave out --tip and --axis")
    if args.frames < 2:
        raise UsageError(f"--frames must be at least 2, got {args.frames}")
    if not (np.isfinite(args.fps) and args.fps > 0):
        raise UsageError(f"--fps must be a finite number > 0, got {args.fps}")
    if not (np.isfinite(args.tremor) and 0 <= args.tremor <= 1):
        raise UsageError(f"--tremor must be in [0, 1] mm, got {args.tremor}")
    tips = _path_tips(args.path, args.frames) + tremor_offsets(args.frames, args.fps, args.tremor, args.seed)
    for tip in tips:
        _check_inside(setup, tip, "a path's tip")
    renderer = Renderer(setup)
    out = Path(args.out)
    truth = []
    with SequenceWriter(out, args.fps) as writer:
        for index, tip in enumerate(progress(tips, desc="render", unit="frame")):
            pose = InstrumentPose.through_insertion(tip, setup.instrument.insertion_in_eye)
            truth.append((index, writer.write(index, renderer.render(pose, seed=args.seed + index)), pose))
    truth_path = out.with_suffix(".truth.csv") if writer.video else out / "truth.csv"  # each output its own
    write_truth_csv(truth_path, truth)
    print(f"wrote {len(tips)} frames to {out} and the truth to {truth_path}", file=sys.stderr)
    return 0


_SLOW_START_S = 2.0  # a start slower than this is compiling: say so


@contextlib.contextmanager
def _compiling_note() -> Iterator[None]:
    """Say what a slow start is doing: Numba compiles the kernels once after an install (about 20 s)."""
    note = "spotnav: compiling the numerical kernels, once after an install (about 20 s) ..."
    timer = threading.Timer(_SLOW_START_S, partial(print, note, file=sys.stderr, flush=True))
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


def _ready(setup: Setup) -> None:
    """Compile (or load) the kernels before the first frame, saying so when that takes long."""
    with _compiling_note():
        prepare_kernels(setup)


class _StopSignals:
    """SIGINT and SIGTERM ask a loop to stop after the frame in hand: a requested stop, not a failure.

    A second signal of the same kind while the first is pending ends the run at once, as
    Python's default would.
    """

    def __init__(self) -> None:
        self.received: str | None = None
        self._previous: dict[int, object] = {}

    def _handle(self, number: int, _frame: object) -> None:
        if self.received == signal.Signals(number).name:
            raise KeyboardInterrupt
        self.received = signal.Signals(number).name

    def __enter__(self) -> _StopSignals:
        for number in (signal.SIGINT, signal.SIGTERM):
            self._previous[number] = signal.signal(number, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for number, handler in self._previous.items():
            signal.signal(number, handler)


_WRONG_SIZE_STOP = 25  # consecutive frames of the wrong size that stop tracking


def _track_limits(args: argparse.Namespace) -> CameraSettings:
    """Check ``track``'s limits and camera settings; the camera settings asked for."""
    if args.max_frames is not None and args.max_frames < 1:
        raise UsageError(f"--max-frames must be at least 1, got {args.max_frames}")
    if args.duration is not None and not (np.isfinite(args.duration) and args.duration > 0):
        raise UsageError(f"--duration must be a finite number of seconds > 0, got {args.duration}")
    if args.camera_size is not None and min(args.camera_size) < 1:
        raise UsageError(f"--camera-size must be positive, got {' '.join(map(str, args.camera_size))}")
    if args.fps is not None and not (np.isfinite(args.fps) and args.fps > 0):
        raise UsageError(f"--fps must be a finite number > 0, got {args.fps}")
    if args.exposure is not None and not np.isfinite(args.exposure):
        raise UsageError(f"--exposure must be a finite number, got {args.exposure}")
    size = tuple(args.camera_size) if args.camera_size is not None else None
    return CameraSettings(size, args.fps, args.exposure)


@dataclass
class _TrackRun:
    """What a tracking run has done so far."""

    statuses: Counter[str] = field(default_factory=Counter)
    latencies: list[float] = field(default_factory=list)
    wrong_size: int = 0  # frames of the wrong size in a row
    stop: str = ""  # why it stopped before the source ended
    verdict: str = ""  # the sequence's test: what of the setup the frames contradict


def _cmd_track(args: argparse.Namespace) -> int:
    setup = read_setup(args.scene)
    camera = _track_limits(args)
    with _StopSignals() as signals:
        with _compiling_note():
            tracker = Tracker(setup, through_insertion=args.method == "precise")
        report = partial(print, file=sys.stderr)
        size = (setup.camera.width_px, setup.camera.height_px)
        # The tracker keeps no image: a frame's buffer is reused two frames later; a video is decoded in a second
        # process, and the tracker rehearses the last frame while it waits.
        source = iter_frames(
            args.source, ring=2, camera=camera, report=report, expected_size=size, while_waiting=tracker.rehearse
        )
        with contextlib.closing(source) as frames:
            server = None
            try:
                server = _igtl_server(args, signals)
                with PosesWriter(args.out, TRACK_COLUMNS) as out, _overlay_writer(args) as overlay, frozen_heap():
                    run = _track_frames(args, tracker, frames, server, signals, out, overlay)
            finally:
                if server is not None:
                    server.close()
                    extra = [f"{server.clients_dropped} dropped for not reading"] if server.clients_dropped else []
                    extra += [f"{server.clients_refused} refused (too many)"] if server.clients_refused else []
                    served = ", ".join([f"{server.clients_served} clients served", *extra])
                    print(f"OpenIGTLink: {served}", file=sys.stderr)
    counts = ", ".join(f"{n} {s}" for s, n in run.statuses.most_common()) or "no frames"
    latencies = run.latencies
    timing = (
        f"; latency median {np.median(latencies):.2f} ms, 99th percentile {np.percentile(latencies, 99):.2f} ms, "
        f"max {np.max(latencies):.2f} ms"
        if latencies
        else ""
    )
    ended = f" ({run.stop})" if run.stop else ""
    print(f"wrote {args.out}: {out.rows} frames, {counts}{timing}{ended}", file=sys.stderr)
    if run.wrong_size >= _WRONG_SIZE_STOP:
        print(f"spotnav: error: {run.wrong_size} frames in a row are not the setup's camera size", file=sys.stderr)
        return 2
    return 0


def _overlay_writer(args: argparse.Namespace) -> contextlib.AbstractContextManager[SequenceWriter | None]:
    """``track --overlay``'s video (or folder of PNGs), at ``--fps`` or 30 frames per second, or nothing."""
    if args.overlay is None:
        return contextlib.nullcontext()
    return SequenceWriter(args.overlay, args.fps or 30.0)


def _igtl_server(args: argparse.Namespace, signals: _StopSignals) -> PoseServer | None:
    """The OpenIGTLink server that ``--igtl`` asks for (None without it), with what it tells the user."""
    if args.igtl is None:
        return None
    server = PoseServer(args.igtl, host=args.igtl_host, device=args.igtl_device)
    print(
        f"OpenIGTLink: {server.device} (TRANSFORM) and {server.device}Status (STRING) on {server.host}:{server.port}",
        file=sys.stderr,
    )
    if not ipaddress.ip_address(socket.gethostbyname(server.host)).is_loopback:
        print(
            f"spotnav: warning: OpenIGTLink has no authentication: anyone who reaches {server.host}:{server.port} "
            "receives the poses",
            file=sys.stderr,
        )
    if args.igtl_wait > 0:
        print(f"OpenIGTLink: waiting up to {args.igtl_wait:g} s for a client ...", file=sys.stderr)
        connected = server.wait_for_client(args.igtl_wait, stop=lambda: bool(signals.received))
        print(f"OpenIGTLink: {'a client is connected' if connected else 'no client yet'}", file=sys.stderr)
    return server


def _track_frames(
    args: argparse.Namespace,
    tracker: Tracker,
    frames: Iterable[Frame],
    server: PoseServer | None,
    signals: _StopSignals,
    out: PosesWriter,
    overlay: SequenceWriter | None,
) -> _TrackRun:
    """Track every frame, writing each row as it is done, until the source ends or a stop is due."""
    run = _TrackRun()
    started = time.monotonic()
    bar = progress(frames, desc="track", unit="frame")
    for frame in bar:
        if signals.received:  # before the first frame (a signal while compiling or opening the source)
            run.stop = f"stopped by {signals.received}"
            break
        if frame.pixels is None:
            tracked = TrackedFrame(PoseEstimate(frame.error_status, detail=frame.error), "lost")
        else:
            tracked = tracker.update(frame.pixels)
        latency = 1000 * (time.perf_counter() - frame.ready_s)
        if server is not None:
            server.send(tracked.estimate, frame.index, frame.timestamp_s, tracked.mode)
        out.write(track_row(frame, tracked.estimate, tracked.mode, latency))
        if overlay is not None and frame.pixels is not None:
            label = f"frame {frame.index}, {tracked.mode}"
            spots = fitted_spots(tracked.edges_px)
            canvas = draw_overlay(frame.pixels, tracker.setup, tracked.estimate, spots=spots, label=label)
            overlay.write(frame.index, canvas)
        run.statuses[tracked.estimate.status] += 1
        if tracker.sequence.verdict and not run.verdict:  # said once; every frame's row and status carry it
            run.verdict = tracker.sequence.verdict
            print(f"spotnav: warning: frame {frame.index}: {run.verdict}", file=sys.stderr)
        run.latencies.append(latency)
        bar.set_postfix_str(f"{1000 / max(np.median(run.latencies[-50:]), 1e-3):.0f} Hz, {tracked.mode}")
        streamed = not frame.image  # a video's or a camera's frame, not a file of a batch
        run.wrong_size = run.wrong_size + 1 if tracked.estimate.status == "wrong_size" and streamed else 0
        if run.wrong_size == 1:
            print(f"spotnav: warning: frame {frame.index}: {tracked.estimate.detail}", file=sys.stderr)
        run.stop = _track_stop(args, signals, out.rows, time.monotonic() - started, run.wrong_size)
        if run.stop:
            break
    bar.close()
    return run


def _track_stop(args: argparse.Namespace, signals: _StopSignals, frames: int, elapsed_s: float, wrong_size: int) -> str:
    """Why tracking stops after this frame, or ``""`` to go on."""
    if signals.received:
        return f"stopped by {signals.received}"
    if args.max_frames is not None and frames >= args.max_frames:
        return f"--max-frames {args.max_frames}"
    if args.duration is not None and elapsed_s >= args.duration:
        return f"--duration {args.duration:g} s"
    if wrong_size >= _WRONG_SIZE_STOP:
        return "frames of the wrong size"
    return ""


def _cmd_localize(args: argparse.Namespace) -> int:
    setup = read_setup(args.scene)
    if args.fit_radius and args.method != "precise":
        raise UsageError("--fit-radius works with --method precise")
    statuses: Counter[str] = Counter()
    camera_size = (setup.camera.width_px, setup.camera.height_px)
    _ready(setup)
    # --fit-radius: rows wait for the joint fit; each frame's edges are kept, not the frame (memory).
    waiting: list[tuple[str, float]] = []
    done: dict[int, PoseEstimate] = {}
    shares: list[tuple[int, tuple]] = []
    with _StopSignals() as signals, PosesWriter(args.out) as out:
        for name in progress(args.images, desc="localize", unit="image"):
            if signals.received:
                break
            start = time.perf_counter()
            try:
                image = read_image(name, expected_size=camera_size)
            except ImageReadError as error:
                estimate = PoseEstimate(error.status, detail=str(error))
            else:
                if args.fit_radius:
                    shares.append((len(waiting), prepare_self_calibration(image, setup)))
                    waiting.append((name, 1000 * (time.perf_counter() - start)))
                    continue
                estimate = localize(image, setup, args.method)
            if estimate.status in ("unreadable", "wrong_size"):
                shown = display_name(name)
                detail = estimate.detail if estimate.detail.startswith(shown) else f"{shown}: {estimate.detail}"
                print(f"spotnav: warning: {detail}", file=sys.stderr)
            elapsed_ms = 1000 * (time.perf_counter() - start)
            if args.fit_radius:
                done[len(waiting)] = estimate
                waiting.append((name, elapsed_ms))
            else:
                out.write(pose_row(display_name(name), estimate, elapsed_ms))
                statuses[estimate.status] += 1
        if waiting:
            failed, share_ms = set(done), 0.0
            if signals.received:  # no joint fit: each frame's own pose
                done |= {index: estimate for index, (estimate, _) in shares}
                print("spotnav: warning: stopped before the joint radius fit: each frame's own pose", file=sys.stderr)
            else:
                start = time.perf_counter()
                fitted = self_calibrate_radius([share for _, share in shares], setup)
                share_ms = 1000 * (time.perf_counter() - start) / max(len(shares), 1)
                done |= {index: estimate for (index, _), estimate in zip(shares, fitted.estimates, strict=True)}
                print(
                    f"eye.radius_mm = {fitted.radius_mm:.4f} +- {fitted.radius_sigma_mm:.4f} (1 sigma, "
                    f"{fitted.frames} frames)"
                )
            for index, (name, elapsed_ms) in enumerate(waiting):
                out.write(pose_row(display_name(name), done[index], elapsed_ms + share_ms * (index not in failed)))
                statuses[done[index].status] += 1
    counts = ", ".join(f"{n} {s}" for s, n in statuses.most_common()) or "no images"
    ended = f" (stopped by {signals.received})" if signals.received else ""
    print(f"wrote {args.out}: {out.rows} images, {counts}{ended}", file=sys.stderr)
    return 0


def _cmd_show(args: argparse.Namespace) -> int:
    setup = read_setup(args.scene)
    image = read_image(args.frame, expected_size=(setup.camera.width_px, setup.camera.height_px))
    _ready(setup)
    result = localize_detailed(image, setup, args.method)
    canvas = draw_overlay(image, setup, result.estimate, spots=result.spots, cones=result.cones)
    if args.crop:
        x0, y0, x1, y1 = crop_box(setup, result)
        canvas = canvas[y0:y1, x0:x1]
    write_image(args.out, canvas)
    estimate = result.estimate
    if estimate.tip_in_eye is not None:
        tip = " ".join(f"{v:.4f}" for v in estimate.tip_in_eye)
        print(f"ok: tip {tip} mm, sigma {estimate.sigma_mm:.4f} mm")
    else:
        print(f"{estimate.status}: {estimate.detail}")
    for spot in result.spots:
        line = f"beam {spot.beam}: {len(spot.edge_px)} edge points"
        if len(spot.fitted_px):
            rms = float(np.sqrt(np.mean(spot.residuals_deg**2)))
            line += f", {int(spot.inliers.sum())} of {len(spot.fitted_px)} fitted points kept, RMS {rms:.4f} deg"
        print(line)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    if any(size < 128 for size in args.sizes):
        raise UsageError(f"--sizes must be at least 128 px, got {' '.join(map(str, args.sizes))}")
    if args.frames < 2:
        raise UsageError(f"--frames must be at least 2, got {args.frames}")
    if args.full_every < 1:
        raise UsageError(f"--full-every must be at least 1, got {args.full_every}")
    if not (np.isfinite(args.memory_mb) and args.memory_mb >= 0):
        raise UsageError(f"--memory-mb must be a number >= 0, got {args.memory_mb}")
    if args.passes < 1:
        raise UsageError(f"--passes must be at least 1, got {args.passes}")
    if args.profile:
        if args.stress:
            raise UsageError("--profile and --stress are two different runs: give one of them")
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
    setup = read_setup(args.scene)
    known = read_known_poses(args.poses)
    if any(pose.image == Path() for pose in known):
        raise UsageError(
            f"{args.poses} names a video's frames, not image files: calibrate reads images "
            "(render the known poses into a folder: render --path ... --out DIR)"
        )
    if args.images:
        by_path = {pose.image.resolve(): pose for pose in known}
        missing = [name for name in args.images if Path(name).resolve() not in by_path]
        if missing:
            raise UsageError(f"{missing[0]} is not in {args.poses}")
        known = [by_path[Path(name).resolve()] for name in args.images]
    frames = []
    _ready(setup)
    for pose in progress(known, desc="calibrate", unit="image"):
        try:
            image = read_image(pose.image, expected_size=(setup.camera.width_px, setup.camera.height_px))
        except ImageReadError as error:
            print(f"spotnav: warning: {error}; left out", file=sys.stderr)
            continue
        frames.append(KnownFrame(str(pose.image), image, pose.tip_in_eye, pose.axis))
    fit = list(args.fit or []) + ["eye-radius"] * args.fit_radius + ["light-radius"] * args.fit_light_radius
    result = calibrate(frames, setup, fit=sorted(set(fit)), fix=sorted(set(args.fix or [])))
    for reason in result.skipped:
        print(f"spotnav: warning: {reason}; left out", file=sys.stderr)
    lines = _calibration_lines(result)
    calibrated = result.setup
    if args.height_correction:
        height = calibrate_height_correction(frames, calibrated)
        for reason in height.skipped:
            print(f"spotnav: warning: {reason}; left out of the height correction", file=sys.stderr)
        lines.append(
            f"instrument.height_correction = {height.factor:.4f} (spread {height.spread:.4f}, "
            f"{height.frames} frames; the thesis method's section 5.5)"
        )
        calibrated = replace(calibrated, instrument=replace(calibrated.instrument, height_correction=height.factor))
    print("\n".join(lines))
    header = f"written by spotnav calibrate from {args.scene} and {args.poses}\n" + "\n".join(lines)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(setup_to_toml(calibrated, header), encoding="utf-8")
    print(f"wrote {out}", file=sys.stderr)
    return 0


_SETUP_KEYS = {
    "edge_half_angle_deg": "instrument.edge_half_angle_deg",
    "light_radius_mm": "instrument.light_radius_mm",
    "eye_radius_mm": "eye.radius_mm",
}


def _calibration_lines(result: Calibration) -> list[str]:
    """What ``calibrate`` prints: the fitted values +- 1 sigma, what stayed fixed and why, the residuals."""
    lines = [f"frames used: {result.frames} ({result.points} edge points)", "fitted (1 sigma):"]
    for name in result.fitted:
        index = GEOMETRY_PARAMETERS.index(name)
        lines.append(f"  {_SETUP_KEYS.get(name, name)} = {result.values[index]:.6g} +- {result.sigmas[index]:.2g}")
    if np.isfinite(result.insertion_rms_mm):
        lines.append(f"  (the insertion point is where the known axes meet, RMS {result.insertion_rms_mm:.4f} mm)")
    exact = [name for name, reason in result.fixed if result.sigmas[GEOMETRY_PARAMETERS.index(name)] == 0]
    others = [(name, reason) for name, reason in result.fixed if name not in exact]
    if others:
        lines.append("left at the setup's values (1 sigma):")
    for name, reason in others:
        index = GEOMETRY_PARAMETERS.index(name)
        lines.append(f"  {name} = {result.values[index]:.6g} +- {result.sigmas[index]:.2g}: {reason}")
    if exact:
        lines.append(f"known exactly ([uncertainty] 0): {', '.join(exact)}")
    lines.append(
        f"RMS angle of the edge points from their cones: {result.rms_before_deg:.4f} deg before, "
        f"{result.rms_after_deg:.4f} deg after ({result.rms_after_px:.3f} px)"
    )
    edge = result.setup.calibration.frame_edge_sigma_deg
    lines.append(f"one frame's edge strays from the model by {edge:.4f} deg (1 sigma, each frame left out in turn)")
    misses, settled = np.array(result.tip_misses_mm), f"{len(result.tip_misses_mm)} of {result.frames} frames"
    if len(misses) < 2:
        lines.append(f"the frames' tips, found from their edges alone: not checked ({settled} settled)")
    else:
        covered = (
            "within what the covariance says"
            if result.covariance_scale == 1.0
            else f"more than the covariance said: its sigmas are scaled by {result.covariance_scale:.2f}"
        )
        lines.append(
            f"the frames' tips, found from their edges alone ({settled}): mean miss {misses.mean():.4f} mm, "
            f"max {misses.max():.4f} mm, {covered}"
        )
    if result.responses:
        tried = ", ".join(f"{r} {spread:.4f}" for r, spread in result.responses if np.isfinite(spread))
        response = result.setup.camera.response
        if response is None:
            lines.append(
                f"camera.response is not stated and the edges do not tell it from sRGB (spots' RMS offset, px: "
                f"{tried}): the frames are read as sRGB; state it if the camera writes linear or gamma values"
            )
        else:
            lines.append(
                f"camera.response = {response}: estimated, its spots agree best with the edge model "
                f"(spots' RMS offset, px: {tried}); written to the calibrated setup"
            )
    band = result.setup.instrument.edge_band_deg
    if result.edge_bands:
        tried = ", ".join(f"{b:.3f} {spread:.4f}" for b, spread in result.edge_bands if np.isfinite(spread))
        margin = f"{100 * EDGE_BAND_MARGIN:.0f} %"
        how = "fitted" if band != result.edge_bands[0][0] else f"the setup's (no other agrees {margin} better)"
        lines.append(
            f"instrument.edge_band_deg = {band:.4g}: the light's soft band about the edge, {how}, from the spots "
            f"that clip (spots' RMS offset, px, by band in deg: {tried})"
        )
    else:
        lines.append(
            f"instrument.edge_band_deg = {band:.4g}: the light's soft band, the setup's, written so that frames are "
            "read as these were (not fitted: no known frame's spot was read from its flank, where the band tells)"
        )
    return lines


def _cmd_analyze(args: argparse.Namespace) -> int:
    print("Table 4.1: largest deviation of the cone-plane ellipse from the cone-sphere curve")
    print("sphere centre (3.7, 0, -6.35) mm in the cone frame, r = 12.5 mm (thesis Table 4.2)")
    print(f"{'beta [deg]':>10} {'thesis [um]':>12} {'y gap [um]':>11} {'to plane [um]':>14} {'along ray [um]':>15}")
    for beta, thesis, gap, to_plane, along in approximation_rows():
        print(f"{beta:>10} {thesis:>12.2f} {gap:>11.3f} {to_plane:>14.3f} {along:>15.3f}")
    print("y gap: the thesis's measure (Eq. 4.10 vs 4.19 at equal x); the others are full 3D distances.")
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    evaluation = evaluate_poses(read_poses_csv(args.poses), read_known_poses(args.truth))
    print(evaluation_text(evaluation))
    if args.out:
        for path in write_evaluation(Path(args.out), evaluation):
            print(f"wrote {path}", file=sys.stderr)
    return 0


def _cmd_reproduce(args: argparse.Namespace) -> int:
    if args.workers < 1:
        raise UsageError(f"--workers must be at least 1, got {args.workers}")
    out = Path(args.out or ("results/quick" if args.quick else "results/full"))
    start = time.perf_counter()
    for name in ("size", "poses"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise UsageError(f"--{name} must be at least 1, got {value}")
    reproduce(out, quick=args.quick, only=args.only or (), workers=args.workers, size_px=args.size, poses=args.poses)
    print(f"wrote {out / 'report.md'} in {time.perf_counter() - start:.0f} s")
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    if args.example:
        sys.stdout.write(EXAMPLE_SWEEP)
        return 0
    if args.file is None or args.out is None:
        raise UsageError("sweep needs FILE and --out DIR (or --example)")
    if args.scheduler is not None and args.workers is not None:
        raise UsageError("--workers sizes the local cluster; it cannot be used with --scheduler")
    if args.dashboard is not None and (args.scheduler is not None or args.workers == 0):
        raise UsageError("--dashboard serves the local Dask cluster's: not with --scheduler or --workers 0")
    path = Path(args.file)
    run = run_sweep(
        path.read_text(encoding="utf-8"),
        args.out,
        base_dir=path.parent,
        scheduler=args.scheduler,
        workers=args.workers,
        resume=args.resume,
        dashboard=args.dashboard,
        log=partial(print, file=sys.stderr),
    )
    where = "in this process" if run.workers == 0 else f"on {run.workers} Dask workers"
    resumed = f" ({run.chunks_resumed} chunks done before)" if run.chunks_resumed else ""
    print(
        f"wrote {run.table}: {run.frames} frames{resumed}; {run.frames_run} frames in {run.wall_s:.1f} s {where} "
        f"({run.frames_run / run.wall_s:.1f} frames/s)"
    )
    return 0


def _cmd_sweep_report(args: argparse.Namespace) -> int:
    print(write_sweep_report(args.directory))
    print(f"wrote {Path(args.directory) / 'summary.md'}, summary.csv and a plot per swept parameter", file=sys.stderr)
    return 0


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="spotnav", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"spotnav {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    scene = commands.add_parser("scene", help="print a setup file")
    scene.add_argument(
        "--example",
        nargs="?",
        const="thesis",
        choices=list(EXAMPLES),
        help="the thesis's setup, commented; thesis-exposure: the same with the thesis's saturated spots",
    )
    scene.add_argument(
        "--opencv",
        metavar="FILE",
        help="a setup whose camera is an OpenCV calibration (camera_matrix, distortion_coefficients, image_width, "
        "image_height in the YAML, XML or JSON that cv2.FileStorage writes)",
    )
    scene.add_argument("--scene", help="with --opencv: the setup to take the rest from (default: the thesis's)")
    scene.set_defaults(run=_cmd_scene)

    render = commands.add_parser("render", help="render a camera frame (or a moving instrument) and its truth")
    render.add_argument("--scene", required=True, help="setup TOML")
    render.add_argument("--tip", nargs=3, type=float, metavar=("X", "Y", "Z"), help="tip in mm, eye frame")
    render.add_argument(
        "--axis",
        nargs=3,
        type=float,
        metavar=("DX", "DY", "DZ"),
        help="instrument axis (default: from the insertion point)",
    )
    render.add_argument("--power", type=float, help="override light.power_w")
    render.add_argument("--seed", type=int, default=0, help="sensor noise seed (default 0)")
    render.add_argument(
        "--path",
        help="render a sequence along square, helix or FILE.csv (x_mm,y_mm,z_mm waypoints), axis through the "
        "insertion point",
    )
    render.add_argument("--frames", type=int, default=300, help="frames of a --path (default 300)")
    render.add_argument("--fps", type=float, default=100.0, help="frame rate of a --path, for tremor and video")
    render.add_argument(
        "--tremor",
        type=float,
        nargs="?",
        const=0.05,
        default=0.0,
        metavar="MM",
        help="hand tremor, 6-12 Hz, peak per axis (default off; 0.05 mm without a value)",
    )
    render.add_argument(
        "--out",
        required=True,
        help="PNG path (the truth beside it as .json); with --path a folder of PNGs (truth.csv inside) or a "
        "FILE.mkv video (FFV1; FILE.truth.csv beside it)",
    )
    render.set_defaults(run=_cmd_render)

    loc = commands.add_parser("localize", help="localize the tip in images, write poses.csv")
    loc.add_argument("--scene", required=True, help="setup TOML")
    loc.add_argument("--method", default=DEFAULT_METHOD, choices=sorted(METHODS), help=f"default {DEFAULT_METHOD}")
    loc.add_argument("--out", required=True, help="poses.csv path")
    loc.add_argument(
        "--fit-radius",
        action="store_true",
        help="fit one eye radius with all the poses (precise method, at least 20 frames)",
    )
    loc.add_argument("images", nargs="+", metavar="IMAGE")
    loc.set_defaults(run=_cmd_localize)

    track = commands.add_parser("track", help="track a moving instrument in a video, images or a camera")
    track.add_argument("--scene", required=True, help="setup TOML")
    track.add_argument(
        "source",
        metavar="SOURCE",
        help="video file, folder or glob of images, camera index, URL (rtsp://...) or GStreamer pipeline",
    )
    track.add_argument("--out", required=True, help="poses.csv path")
    track.add_argument(
        "--method",
        default="precise",
        choices=["precise", "precise-free"],
        help="default precise (axis through the insertion point)",
    )
    track.add_argument(
        "--igtl",
        type=int,
        nargs="?",
        const=DEFAULT_PORT,
        metavar="PORT",
        help=f"send each pose to OpenIGTLink clients such as 3D Slicer (default port {DEFAULT_PORT})",
    )
    track.add_argument("--igtl-wait", type=float, default=0.0, metavar="S", help="wait for a client first (s)")
    track.add_argument(
        "--igtl-host",
        default=DEFAULT_HOST,
        metavar="ADDRESS",
        help=f"address to serve OpenIGTLink on (default {DEFAULT_HOST}; the protocol has no authentication)",
    )
    track.add_argument(
        "--igtl-device",
        default=DEFAULT_DEVICE,
        metavar="NAME",
        help=f"the TRANSFORM's device name (default {DEFAULT_DEVICE}, PLUS's FromToTo convention)",
    )
    track.add_argument(
        "--overlay",
        metavar="OUT",
        help="also write every frame with its fitted cones, tip and status drawn on it: a .mkv video or a folder",
    )
    track.add_argument("--max-frames", type=int, metavar="N", help="stop after N frames")
    track.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    track.add_argument(
        "--camera-size", type=int, nargs=2, metavar=("W", "H"), help="ask a live camera for this frame size, px"
    )
    track.add_argument("--fps", type=float, help="ask a live camera for this frame rate")
    track.add_argument("--exposure", type=float, help="ask a live camera for this exposure (CAP_PROP_EXPOSURE units)")
    track.set_defaults(run=_cmd_track)

    evaluate = commands.add_parser("evaluate", help="compare a poses.csv with the truth: error statistics")
    evaluate.add_argument("poses", metavar="POSES.csv", help="poses.csv from localize or track")
    evaluate.add_argument("truth", metavar="TRUTH.csv", help="image,x_mm,y_mm,z_mm[,dir_x,dir_y,dir_z][,...]")
    evaluate.add_argument("--out", help="folder for errors.csv (per frame), errors.png and track.png (3D)")
    evaluate.set_defaults(run=_cmd_evaluate)

    show = commands.add_parser("show", help="draw a frame's edge points, fitted cones, tip and status over it")
    show.add_argument("--scene", required=True, help="setup TOML")
    show.add_argument("--method", default=DEFAULT_METHOD, choices=sorted(METHODS), help=f"default {DEFAULT_METHOD}")
    show.add_argument("--out", required=True, help="the overlay image (PNG)")
    show.add_argument("--crop", action="store_true", help="only the part of the frame around the spots")
    show.add_argument("frame", metavar="FRAME", help="the camera frame")
    show.set_defaults(run=_cmd_show)

    bench = commands.add_parser("bench", help="ms per frame: rendering, full-frame methods and tracking")
    bench.add_argument("--sizes", type=int, nargs="+", default=[1024, 2048, 5000], help="image sizes, px")
    bench.add_argument("--frames", type=int, default=100, help="consecutive helix frames per size (default 100)")
    bench.add_argument("--beams", type=int, choices=[1, 3], default=1)
    bench.add_argument(
        "--full-every",
        type=int,
        default=5,
        help="time the full-frame methods every Nth frame (on its copy in memory, else right after rendering)",
    )
    bench.add_argument(
        "--memory-mb",
        type=float,
        default=4096.0,
        help="keep this much of the rendered frames to track again (and time the full-frame methods on) from "
        "memory, as from a camera (default 4096)",
    )
    bench.add_argument(
        "--passes",
        type=int,
        default=1,
        help="track the frames in memory this many times, each frame timed by its fastest pass (a shared "
        "machine's other work slows some; default 1)",
    )
    bench.add_argument(
        "--stress",
        action="store_true",
        help="track the helix with its spot hidden every --hide-every frames: every frame's time, re-acquisitions, "
        "errors and silent failures",
    )
    bench.add_argument("--hide-every", type=int, default=8, help="with --stress, hide the spot every Nth frame")
    bench.add_argument(
        "--profile",
        action="store_true",
        help="where the time goes instead: the acquisition (right after the thesis method) and the tracked frames, "
        "function by function, split into compiled kernels, OpenCV and Python",
    )
    bench.set_defaults(run=_cmd_bench)

    cal = commands.add_parser("calibrate", help="fit the geometry that frames at known poses determine")
    cal.add_argument("--scene", required=True, help="setup TOML")
    cal.add_argument("--poses", required=True, help="known.csv: image,x_mm,y_mm,z_mm[,dir_x,dir_y,dir_z]")
    groups = ", ".join(PARAMETER_GROUPS)
    cal.add_argument(
        "--fit", action="append", choices=list(PARAMETER_GROUPS), metavar="GROUP", help=f"always fit: {groups}"
    )
    cal.add_argument("--fix", action="append", choices=list(PARAMETER_GROUPS), metavar="GROUP", help="never fit")
    cal.add_argument("--fit-radius", action="store_true", help="always fit eye.radius_mm (--fit eye-radius)")
    cal.add_argument(
        "--height-correction",
        action="store_true",
        help="also fit the thesis method's instrument.height_correction (section 5.5)",
    )
    cal.add_argument(
        "--fit-light-radius",
        action="store_true",
        help="always fit instrument.light_radius_mm (--fit light-radius)",
    )
    cal.add_argument("--out", required=True, help="the calibrated setup TOML to write")
    cal.add_argument("images", nargs="*", metavar="IMAGE", help="images to use (default: all in known.csv)")
    cal.set_defaults(run=_cmd_calibrate)

    analyze = commands.add_parser("analyze", help="analyses of the method's geometry")
    analyze.add_argument("topic", choices=["approximation"], help="approximation: Table 4.1")
    analyze.set_defaults(run=_cmd_analyze)

    rep = commands.add_parser("reproduce", help="regenerate the thesis's tables from simulation")
    rep.add_argument("--quick", action="store_true", help="1024 px and 25 poses (minutes)")
    rep.add_argument(
        "--only", action="append", choices=sorted(EXPERIMENTS), help="run only this experiment (repeatable)"
    )
    rep.add_argument("--out", help="output folder (default results/quick or results/full)")
    rep.add_argument("--size", type=int, help="image size in px (default 1024 quick, 5000 full)")
    rep.add_argument("--poses", type=int, help="poses per path (default 25 quick, 100 full)")
    rep.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="processes (default: all cores)")
    rep.set_defaults(run=_cmd_reproduce)

    sweep = commands.add_parser("sweep", help="design sweep over setups, on a Dask cluster: frames.parquet")
    sweep.add_argument("file", nargs="?", metavar="FILE", help="sweep TOML (see --example)")
    sweep.add_argument("--example", action="store_true", help="print a small, commented sweep file")
    sweep.add_argument("--out", help="output folder")
    sweep.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run on this Dask cluster")
    sweep.add_argument(
        "--workers", type=int, help="local cluster's worker processes (default: one per core; 0: no Dask)"
    )
    sweep.add_argument("--resume", action="store_true", help="finish an interrupted sweep in --out")
    sweep.add_argument(
        "--dashboard",
        nargs="?",
        const=":8787",
        metavar="ADDRESS",
        help="serve the local Dask cluster's dashboard (default address :8787) and print its link",
    )
    sweep.set_defaults(run=_cmd_sweep)

    report = commands.add_parser("sweep-report", help="summary tables and plots of a sweep's results")
    report.add_argument("directory", metavar="DIR", help="a sweep's --out folder")
    report.set_defaults(run=_cmd_sweep_report)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code."""
    args = _parser().parse_args(argv)
    try:
        return args.run(args)
    except (SpotnavError, OSError) as error:
        message = str(error).splitlines()[0] if str(error) else type(error).__name__
        print(f"spotnav: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # before a command could stop cleanly, or a second Ctrl-C
        print("spotnav: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
