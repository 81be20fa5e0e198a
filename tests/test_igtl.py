from __future__ import annotations

import csv
import socket
import threading
from pathlib import Path

import numpy as np
import pyigtl
from test_cli import write_scene

from spotnav.cli import main
from spotnav.geometry import instrument_to_eye
from spotnav.igtl import DEVICE_NAME


class RecordingMessages(dict):
    """pyigtl's client keeps only each device's latest message; this keeps every one, in order."""

    def __init__(self) -> None:
        super().__init__()
        self.received: list[pyigtl.MessageBase] = []
        self.lock = threading.Lock()

    def __setitem__(self, key: str, message: pyigtl.MessageBase) -> None:
        with self.lock:
            self.received.append(message)
        super().__setitem__(key, message)


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def test_a_pyigtl_client_receives_the_poses_that_poses_csv_holds(tmp_path: Path) -> None:
    scene = write_scene(tmp_path / "setup.toml", size_px=1024, blend=0.15)
    frames = tmp_path / "frames"
    assert main(["render", "--scene", str(scene), "--path", "helix", "--frames", "60", "--out", str(frames)]) == 0
    for broken in sorted(frames.glob("frame_*.png"))[-3:]:  # no pose, so nothing may be sent for them
        broken.write_bytes(b"")
    port = free_port()
    client = pyigtl.OpenIGTLinkClient("127.0.0.1", port)
    messages = RecordingMessages()
    client.incoming_messages = messages
    try:
        track = ["track", "--scene", str(scene), str(frames), "--out", str(tmp_path / "poses.csv")]
        code = main([*track, "--igtl", str(port), "--igtl-wait", "10"])
    finally:
        client.stop()
    assert code == 0
    with (tmp_path / "poses.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    ok = [r for r in rows if r["status"] == "ok"]
    assert len(rows) == 60 and len(ok) == 57
    assert [m.device_name for m in messages.received] == [DEVICE_NAME] * len(ok)
    for row, message in zip(ok, messages.received, strict=True):
        tip = np.array([float(row[k]) for k in ("x_mm", "y_mm", "z_mm")])
        axis = np.array([float(row[k]) for k in ("dir_x", "dir_y", "dir_z")])
        assert message.message_type == "TRANSFORM"
        np.testing.assert_allclose(message.matrix[:3, 3], tip, atol=1e-5)
        np.testing.assert_allclose(message.matrix[:3, 2], axis, atol=1e-5)


def test_instrument_frame_is_right_handed_with_z_along_the_axis() -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        transform = instrument_to_eye(rng.normal(size=3), axis, rng.uniform(-np.pi, np.pi))
        rotation = transform[:3, :3]
        np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)
        assert np.isclose(np.linalg.det(rotation), 1.0)
        np.testing.assert_allclose(rotation[:, 2], axis, atol=1e-12)
