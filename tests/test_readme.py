"""The README's path at the microscope runs as written (issue 62): a nominal setup from ``scene --example``, frames
with the tip at known points, ``calibrate``, then ``localize`` and ``track``, on frames from a microscope that is
not its nominal values. The README's first try is run by ``tests/test_cli.py``."""

from __future__ import annotations

import csv
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from spotnav.files.setup_files import CLAIMS_EXACT_GEOMETRY

README = Path(__file__).parents[1] / "README.md"

# The microscope as it is, which its setup does not know: the beam 0.5 deg wider, the camera 0.5 mm higher (the
# world of issue 62's newcomer, whose exact setup answered 20/20 frames ok at 0.22 mm, none within 3 sigma).
BEAM = "s/beam_half_angle_deg = 9.0 /beam_half_angle_deg = 9.5 /"
CAMERA = "s/distance_mm = 110.0 /distance_mm = 110.5 /"

# What the user does between the block's first line and its second: writes the microscope's values into the setup
# (here 512 px) and records frames with the tip at known points, frames to localize and a session to track.
AT_THE_MICROSCOPE = [
    "sed -i 's/_px = 5000/_px = 512/' setup.toml",
    f"sed -e '{BEAM}' -e '{CAMERA}' setup.toml > world.toml",
    "spotnav render --scene world.toml --path square --frames 8 --out known && mv known/truth.csv known/known.csv",
    "spotnav render --scene world.toml --path helix --frames 12 --out frames",
    "spotnav render --scene world.toml --path helix --frames 40 --tremor --out surgery.mkv",
]

# After the block: the nominal setup's answers, and both runs against the truth.
CHECKS = [
    "spotnav localize --scene setup.toml frames/*.png --out nominal.csv",
    "spotnav evaluate poses.csv frames/truth.csv",
    "spotnav evaluate track.csv surgery.truth.csv",
]


def lab_block() -> list[str]:
    """The README's block "At the microscope", a command a line."""
    text = README.read_text(encoding="utf-8")
    block = text.split("At the microscope, the same path", 1)[1].split("```sh\n", 1)[1].split("```", 1)[0]
    return block.strip().splitlines()


def _evaluations(stdout: str) -> list[tuple[int, int, float, float, float]]:
    """Each evaluation's frames, ok frames, mean and max tip error (mm) and share within 3 sigma (%)."""
    counts = re.findall(r"^frames: (\d+) \((\d+) ok", stdout, re.MULTILINE)
    errors = re.findall(r"^tip error over .*: mean ([\d.]+), .* max ([\d.]+)$", stdout, re.MULTILINE)
    within = re.findall(r"^within 3 sigma: (\d+) %", stdout, re.MULTILINE)
    assert len(counts) == len(errors) == len(within) == 2, stdout
    return [
        (int(n), int(ok), float(mean), float(top), float(share))
        for (n, ok), (mean, top), share in zip(counts, errors, within, strict=True)
    ]


@pytest.mark.slow  # 60 rendered frames, a calibration, 12 localized and 40 tracked at 512 px: about a minute
def test_the_readme_path_at_the_microscope_runs_as_written(tmp_path: Path) -> None:
    first, *rest = lab_block()
    assert first.startswith("spotnav scene --example > setup.toml"), first
    assert any(line.startswith("spotnav calibrate --scene setup.toml") for line in rest), rest
    script = "\n".join([first, *AT_THE_MICROSCOPE, *rest, *CHECKS])
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    result = subprocess.run(
        ["bash", "-e", "-c", script], cwd=tmp_path, capture_output=True, text=True, check=False, env=env
    )
    assert result.returncode == 0, result.stdout[-1500:] + result.stderr[-3000:]
    world = (tmp_path / "world.toml").read_text()
    assert "beam_half_angle_deg = 9.5 " in world and "distance_mm = 110.5 " in world  # the world is off the setup
    # Before calibration the nominal setup refuses every frame, as a microscope's must; after it, every frame and
    # every tracked frame is answered, within 3 sigma (issue 62's targets: mean <= 0.010 mm, max <= 0.030 mm).
    with (tmp_path / "nominal.csv").open() as handle:
        assert {row["status"] for row in csv.DictReader(handle)} == {"uncalibrated"}
    (frames, frames_ok, mean, top, within), (tracked, tracked_ok, _, _, tracked_within) = _evaluations(result.stdout)
    assert frames == frames_ok == 12 and mean <= 0.010 and top <= 0.030 and within >= 90, result.stdout
    assert tracked == tracked_ok == 40 and tracked_within >= 90, result.stdout
    assert CLAIMS_EXACT_GEOMETRY not in result.stderr and "Traceback" not in result.stderr, result.stderr
