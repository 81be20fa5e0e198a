"""The command line's arguments: every subcommand's options, their names, defaults and help (an outside contract).

:func:`build_parser` builds the ``argparse`` parser of :mod:`spotnav.cli`; the
parsed namespace's ``command`` names the subcommand. Options that several
subcommands share (``--scene``, ``--out``, ``--method``) are added by small helpers.
"""

from __future__ import annotations

import argparse
import os
import textwrap
from typing import Any

from spotnav import __version__
from spotnav.setup.examples import EXAMPLES

__all__ = ["DESCRIPTION", "build_parser"]

DESCRIPTION = (
    "Localize a surgical instrument inside the eye from the cone of light it projects on the retina, as a "
    "microscope camera sees it: simulate frames, localize the tip, track, calibrate and evaluate."
)

# The names the options accept, written out so that parsing imports the standard library only (``spotnav
# --version`` and ``--help`` start at once); tests/test_arguments.py checks them against the modules that define them:
# spotnav.pose.localize.METHODS, spotnav.pose.conefit.parameters.PARAMETER_GROUPS, spotnav.experiments.EXPERIMENTS
# and spotnav.app.igtl's defaults.
METHODS = ("precise", "precise-free", "thesis")
DEFAULT_METHOD = "precise"
PARAMETER_GROUPS = (
    *("edge-angle", "light-radius", "eye-radius", "camera-rotation", "camera-position", "focal-length"),
    *("principal-point", "distortion", "insertion-point", "beam-tilt"),
)
EXPERIMENTS = (
    *("approximation", "ellipse", "paths", "efficiency", "bumps", "radius", "calibration", "volume", "faults", "light"),
    *("geometry", "mismatch", "defocus"),
)
DEFAULT_PORT, DEFAULT_HOST, DEFAULT_DEVICE, DEFAULT_STALE_S = 18944, "127.0.0.1", "TipToEye", 0.5

_Parser = argparse.ArgumentParser


class _PlainFormatter(argparse.HelpFormatter):
    """argparse's help, wrapped between words only: a long word or a hyphenated option is never split."""

    def _split_lines(self, text: str, width: int) -> list[str]:
        return textwrap.wrap(" ".join(text.split()), width, break_long_words=False, break_on_hyphens=False)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return textwrap.fill(
            " ".join(text.split()),
            width,
            initial_indent=indent,
            subsequent_indent=indent,
            break_long_words=False,
            break_on_hyphens=False,
        )


def _scene(parser: _Parser) -> None:
    parser.add_argument("--scene", required=True, metavar="SETUP.toml", help="the setup file (TOML)")


def _out(parser: _Parser, text: str, *, required: bool = True) -> None:
    parser.add_argument("--out", required=required, help=text)


def _method(parser: _Parser) -> None:
    method_help = "the localization method (default %(default)s)"
    parser.add_argument("--method", default=DEFAULT_METHOD, choices=sorted(METHODS), help=method_help)


def _flag(parser: _Parser, name: str, text: str) -> None:
    parser.add_argument(name, action="store_true", help=text)


def _option(parser: _Parser, name: str, kind: type, text: str, **more: Any) -> None:
    parser.add_argument(name, type=kind, help=text, **more)


def _cluster(parser: _Parser) -> None:
    """``--scheduler``, ``--workers`` and ``--dashboard``: where a study's Dask tasks run (sweep, design)."""
    parser.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run on this Dask cluster")
    timeout_help = "with --scheduler: seconds to wait for it to answer, for a worker, for one back (default 20)"
    _option(parser, "--scheduler-timeout", float, timeout_help, metavar="S")
    _option(parser, "--workers", int, "local cluster's worker processes (default: one per core; 0: no Dask)")
    dashboard_help = "serve the local Dask cluster's dashboard (default address :8787) and print its link"
    parser.add_argument("--dashboard", nargs="?", const=":8787", metavar="ADDRESS", help=dashboard_help)


def _scene_command(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    scene = commands.add_parser("scene", help="print a setup file")
    scene.add_argument(
        "--example",
        nargs="?",
        const="thesis",
        choices=list(EXAMPLES),
        help="a microscope's nominal setup with the thesis's values, commented, its geometry to be calibrated; "
        "thesis-exposure: the same with the thesis's saturated spots",
    )
    exact_help = "with --example: the simulation's own setup, its geometry exact (every [uncertainty] value 0)"
    scene.add_argument("--exact", action="store_true", help=exact_help)
    scene.add_argument(
        "--opencv",
        metavar="FILE",
        help="a setup whose camera is an OpenCV calibration (camera_matrix, distortion_coefficients, image_width, "
        "image_height in the YAML, XML or JSON that cv2.FileStorage writes)",
    )
    rest_help = "with --opencv: the setup to take the rest from (default: the thesis's)"
    scene.add_argument("--scene", metavar="SETUP.toml", help=rest_help)


def _render_command(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    render = commands.add_parser("render", help="render a camera frame (or a moving instrument) and its truth")
    _scene(render)
    render.add_argument("--tip", nargs=3, type=float, metavar=("X", "Y", "Z"), help="tip in mm, eye frame")
    axis_help = "instrument axis (default: from the insertion point)"
    render.add_argument("--axis", nargs=3, type=float, metavar=("DX", "DY", "DZ"), help=axis_help)
    _option(render, "--power", float, "override light.power_w")
    _option(render, "--seed", int, "sensor noise seed (default 0)", default=0)
    render.add_argument(
        "--path",
        help="render a sequence along square, helix or FILE.csv (x_mm,y_mm,z_mm waypoints), axis through the "
        "insertion point",
    )
    _option(render, "--frames", int, "frames of a --path (default 300)", default=300)
    _option(render, "--fps", float, "frame rate of a --path, for tremor and video (default %(default)g)", default=100.0)
    tremor_help = "hand tremor, 6-12 Hz, peak per axis (default off; 0.05 mm without a value)"
    _option(render, "--tremor", float, tremor_help, nargs="?", const=0.05, default=0.0, metavar="MM")
    _out(
        render,
        "PNG path (the truth beside it as .json); with --path a folder of PNGs (truth.csv inside) or a "
        "FILE.mkv video (FFV1; FILE.truth.csv beside it)",
    )


def _localize_command(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    loc = commands.add_parser("localize", help="localize the tip in images, write poses.csv")
    _scene(loc)
    _method(loc)
    _out(loc, "poses.csv path")
    _flag(loc, "--fit-radius", "fit one eye radius with all the poses (precise method, at least 20 frames)")
    images_help = "the frames to localize: 8- or 16-bit PNG, TIFF or JPEG files of the setup's camera size"
    loc.add_argument("images", nargs="+", metavar="IMAGE", help=images_help)


def _track_command(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    track = commands.add_parser("track", help="track a moving instrument in a video, images or a camera")
    _scene(track)
    source_help = "video file, folder or glob of images, camera index, URL (rtsp://...) or GStreamer pipeline"
    track.add_argument("source", metavar="SOURCE", help=source_help)
    _out(track, "poses.csv path")
    method_help = "default precise (axis through the insertion point)"
    track.add_argument("--method", default="precise", choices=["precise", "precise-free"], help=method_help)
    igtl_help = f"send each pose to OpenIGTLink clients such as 3D Slicer (default port {DEFAULT_PORT})"
    _option(track, "--igtl", int, igtl_help, nargs="?", const=DEFAULT_PORT, metavar="PORT")
    _option(track, "--igtl-wait", float, "wait this long for a client first, s (default 0)", default=0.0, metavar="S")
    host_help = f"address to serve OpenIGTLink on (default {DEFAULT_HOST}; the protocol has no authentication)"
    track.add_argument("--igtl-host", default=DEFAULT_HOST, metavar="ADDRESS", help=host_help)
    device_help = f"the TRANSFORM's device name (default {DEFAULT_DEVICE}, PLUS's FromToTo convention)"
    track.add_argument("--igtl-device", default=DEFAULT_DEVICE, metavar="NAME", help=device_help)
    overlay_help = "also write every frame with its fitted cones, tip and status drawn on it: a .mkv video or a folder"
    track.add_argument("--overlay", metavar="OUT", help=overlay_help)
    _option(track, "--max-frames", int, "stop after N frames", metavar="N")
    _option(track, "--duration", float, "stop after S seconds", metavar="S")
    size_help = "ask a live camera for this frame size, px"
    _option(track, "--camera-size", int, size_help, nargs=2, metavar=("W", "H"))
    _option(track, "--fps", float, "ask a live camera for this frame rate; the overlay's if the source has none (30)")
    _option(track, "--exposure", float, "ask a live camera for this exposure (CAP_PROP_EXPOSURE units)")
    record_help = "also keep every frame losslessly with its capture time in this new folder; replay it: track DIR"
    track.add_argument("--record", metavar="DIR", help=record_help)
    speed_help = "a recording's pace: 1 as recorded (default), 2 twice as fast, fast: as fast as it decodes"
    track.add_argument("--replay-speed", default="1", metavar="fast|X", help=speed_help)
    stale_help = f"mark the OpenIGTLink pose INVALID after S s without a frame (default {DEFAULT_STALE_S:g}; 0: never)"
    _option(track, "--igtl-stale", float, stale_help, default=DEFAULT_STALE_S, metavar="S")


def _evaluate_and_show_commands(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    evaluate = commands.add_parser("evaluate", help="compare a poses.csv with the truth: error statistics")
    evaluate.add_argument("poses", metavar="POSES.csv", help="poses.csv from localize or track")
    truth_help = (
        "the truth: a CSV with columns image,x_mm,y_mm,z_mm[,dir_x,dir_y,dir_z][,...] (render's truth.csv), or the "
        "frame.json that render writes beside one frame"
    )
    evaluate.add_argument("truth", metavar="TRUTH", help=truth_help)
    _out(evaluate, "folder for errors.csv (per frame), errors.png and track.png (3D)", required=False)

    show = commands.add_parser("show", help="draw a frame's edge points, fitted cones, tip and status over it")
    _scene(show)
    _method(show)
    _out(show, "the overlay image (PNG)")
    _flag(show, "--crop", "only the part of the frame around the spots (a refused frame's too), enlarged if small")
    show.add_argument("frame", metavar="FRAME", help="the camera frame")


def _bench_command(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    bench = commands.add_parser("bench", help="ms per frame: rendering, full-frame methods and tracking")
    _option(bench, "--sizes", int, "image sizes, px (default 1024 2048 5000)", nargs="+", default=[1024, 2048, 5000])
    _option(bench, "--frames", int, "consecutive helix frames per size (default 100)", default=100)
    bench.add_argument("--beams", type=int, choices=[1, 3], default=1, help="beams of the instrument (default 1)")
    full_help = (
        "time the full-frame methods every Nth frame (on its copy in memory, else right after rendering; default 5)"
    )
    _option(bench, "--full-every", int, full_help, default=5)
    memory_help = (
        "keep this much of the rendered frames to track again (and time the full-frame methods on) from "
        "memory, as from a camera (default 4096)"
    )
    _option(bench, "--memory-mb", float, memory_help, default=4096.0)
    passes_help = (
        "track the frames in memory this many times, each frame timed by its fastest pass (a shared "
        "machine's other work slows some; default 1)"
    )
    _option(bench, "--passes", int, passes_help, default=1)
    _flag(
        bench,
        "--stress",
        "track the helix with its spot hidden every --hide-every frames: every frame's time, re-acquisitions, "
        "errors and silent failures",
    )
    _option(bench, "--hide-every", int, "with --stress, hide the spot every Nth frame (default 8)", default=8)
    _flag(
        bench,
        "--record",
        "what track --record costs instead: a helix video's tracked frames' latency, --passes sessions without a "
        "recording and as many with one, alternating",
    )
    _flag(
        bench,
        "--profile",
        "where the time goes instead: the acquisition (right after the thesis method) and the tracked frames, "
        "function by function, split into compiled kernels, OpenCV and Python",
    )


def _calibrate_command(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    cal = commands.add_parser("calibrate", help="fit the geometry that frames at known poses determine")
    _scene(cal)
    cal.add_argument("--poses", required=True, help="known.csv: image,x_mm,y_mm,z_mm[,dir_x,dir_y,dir_z]")
    groups = ", ".join(PARAMETER_GROUPS)
    for flag, meaning in (("--fit", f"always fit: {groups}"), ("--fix", "never fit")):
        cal.add_argument(flag, action="append", choices=list(PARAMETER_GROUPS), metavar="GROUP", help=meaning)
    _flag(cal, "--fit-radius", "always fit eye.radius_mm (--fit eye-radius)")
    _flag(cal, "--height-correction", "also fit the thesis method's instrument.height_correction (section 5.5)")
    _flag(cal, "--fit-light-radius", "always fit instrument.light_radius_mm (--fit light-radius)")
    _out(cal, "the calibrated setup TOML to write")
    cal.add_argument("images", nargs="*", metavar="IMAGE", help="images to use (default: all in known.csv)")


def _experiment_commands(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    analyze = commands.add_parser("analyze", help="analyses of the method's geometry and of the light's precision")
    topic_help = "approximation: Table 4.1; bound: the Cramer-Rao bound of a pose (needs --scene and --tip or --path)"
    analyze.add_argument("topic", choices=["approximation", "bound"], help=topic_help)
    analyze.add_argument("--scene", metavar="SETUP.toml", help="bound: the setup file (TOML)")
    analyze.add_argument("--tip", nargs=3, type=float, metavar=("X", "Y", "Z"), help="bound: tip in mm, eye frame")
    axis_help = "bound: instrument axis, then fitted too (default: from the insertion point, and known to run so)"
    analyze.add_argument("--axis", nargs=3, type=float, metavar=("DX", "DY", "DZ"), help=axis_help)
    _flag(analyze, "--free-axis", "bound: the localizer does not know the insertion point (it fits the axis too)")
    analyze.add_argument("--path", help="bound: along square, helix or FILE.csv, axis through the insertion point")
    _option(analyze, "--poses", int, "bound: poses along a --path (default %(default)s)", default=25)
    _out(analyze, "bound: a folder for bound.csv (and bound.png along a --path)", required=False)

    rep = commands.add_parser("reproduce", help="regenerate the thesis's tables from simulation")
    _flag(rep, "--quick", "1024 px and 25 poses (minutes)")
    only_help = "run only this experiment (repeatable)"
    rep.add_argument("--only", action="append", choices=sorted(EXPERIMENTS), help=only_help)
    _out(rep, "output folder (default results/quick or results/full)", required=False)
    _option(rep, "--size", int, "image size in px (default 1024 quick, 5000 full)")
    _option(rep, "--poses", int, "poses per path (default 25 quick, 100 full)")
    cores = os.cpu_count() or 1
    _option(rep, "--workers", int, f"processes (default: all cores, {cores} here)", default=cores)

    sweep = commands.add_parser("sweep", help="design sweep over setups, on a Dask cluster: frames.parquet")
    sweep.add_argument("file", nargs="?", metavar="SWEEP.toml", help="the sweep file (see --example)")
    _flag(sweep, "--example", "print a small, commented sweep file")
    _out(sweep, "output folder", required=False)
    _cluster(sweep)
    _flag(sweep, "--resume", "finish an interrupted sweep in --out")

    report = commands.add_parser("sweep-report", help="summary tables and plots of a sweep's results")
    report.add_argument("directory", metavar="DIR", help="a sweep's --out folder")

    design = commands.add_parser("design", help="search the light (beams, angles, power, camera) with the best bound")
    design.add_argument("file", nargs="?", metavar="DESIGN.toml", help="the design file (see --example)")
    _flag(design, "--example", "print a small, commented design file")
    _out(design, "output folder: designs.csv, verified.csv, report.md and plots", required=False)
    _cluster(design)


def build_parser(description: str = DESCRIPTION) -> argparse.ArgumentParser:
    """``spotnav``'s parser, its summary line ``description`` (plain text); ``command`` names the subcommand parsed."""
    parser = argparse.ArgumentParser(
        prog="spotnav", description=description, formatter_class=_PlainFormatter, allow_abbrev=False
    )
    parser.add_argument("--version", action="version", version=f"spotnav {__version__}")
    command_help = "one of these; spotnav COMMAND --help describes its options"
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", help=command_help)
    _scene_command(commands)
    _render_command(commands)
    _localize_command(commands)
    _track_command(commands)
    _evaluate_and_show_commands(commands)
    _bench_command(commands)
    _calibrate_command(commands)
    _experiment_commands(commands)
    for command in commands.choices.values():
        command.formatter_class = _PlainFormatter
        command.allow_abbrev = False  # an option is spelt out: the start reads --out from the words themselves
    return parser
