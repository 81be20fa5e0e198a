from __future__ import annotations

import contextlib
import csv
import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pyigtl
import pytest
from test_cli import write_scene

from spotnav.app.igtl import DEFAULT_DEVICE, SETTLE_S, IgtlError, PoseServer
from spotnav.cli import main
from spotnav.pose.estimate import PoseEstimate
from spotnav.setup.geometry import instrument_to_eye


class RecordingMessages(dict):
    """pyigtl's client keeps only each device's latest message; this keeps every one, in order."""

    def __init__(self) -> None:
        super().__init__()
        self.received: list[pyigtl.MessageBase] = []
        self.arrived: list[float] = []  # time.monotonic() when each arrived
        self.lock = threading.Lock()

    def __setitem__(self, key: str, message: pyigtl.MessageBase) -> None:
        with self.lock:
            self.received.append(message)
            self.arrived.append(time.monotonic())
        super().__setitem__(key, message)

    def of(self, device: str) -> list[pyigtl.MessageBase]:
        with self.lock:
            return [m for m in self.received if m.device_name == device]

    def timed(self, device: str) -> list[tuple[float, pyigtl.MessageBase]]:
        """``device``'s messages with when each arrived."""
        with self.lock:
            return [(t, m) for t, m in zip(self.arrived, self.received, strict=True) if m.device_name == device]


@contextlib.contextmanager
def recording_client(port: int) -> Iterator[RecordingMessages]:
    client = pyigtl.OpenIGTLinkClient("127.0.0.1", port)
    messages = RecordingMessages()
    client.incoming_messages = messages
    try:
        yield messages
    finally:
        client.stop()


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def wait_for(condition: object, timeout_s: float = 600.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():  # type: ignore[operator]
            return True
        time.sleep(0.01)
    return False


def finishes(call: Callable[[], object], within_s: float = 600.0) -> bool:
    """Whether ``call`` returns within ``within_s`` s: a hang's guard, with a margin no busy machine reaches."""
    thread = threading.Thread(target=call, daemon=True)
    thread.start()
    thread.join(within_s)
    return not thread.is_alive()


def pose(frame: int) -> PoseEstimate:
    tip = np.array([0.01 * frame, 0.0, 4.0])
    return PoseEstimate("ok", tip_in_eye=tip, axis=np.array([0.0, 0.0, -1.0]), spots=1, sigma_mm=0.002)


def test_a_pyigtl_client_receives_every_frame_as_poses_csv_holds_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = write_scene(tmp_path / "setup.toml", size_px=512, blend=0.15)
    frames = tmp_path / "frames"
    assert main(["render", "--scene", str(scene), "--path", "helix", "--frames", "40", "--out", str(frames)]) == 0
    for broken in sorted(frames.glob("frame_*.png"))[-3:]:  # no pose: sent as INVALID
        broken.write_bytes(b"")
    port = free_port()
    with recording_client(port) as messages:
        track = ["track", "--scene", str(scene), str(frames), "--out", str(tmp_path / "poses.csv")]
        assert main([*track, "--igtl", str(port), "--igtl-wait", "10"]) == 0
        assert wait_for(lambda: len(messages.of(DEFAULT_DEVICE + "Status")) == 40)
    with (tmp_path / "poses.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    transforms, statuses = messages.of(DEFAULT_DEVICE), messages.of(DEFAULT_DEVICE + "Status")
    assert len(rows) == len(transforms) == len(statuses) == 40
    for row, transform, text in zip(rows, transforms, statuses, strict=True):
        assert transform.message_type == "TRANSFORM" and text.message_type == "STRING"
        status = json.loads(text.string)
        assert status["frame"] == int(row["frame"]) and status["status"] == row["status"]
        assert transform.metadata["TransformStatus"] == ("OK" if row["status"] == "ok" else "INVALID")
        assert transform.timestamp == pytest.approx(float(row["timestamp_s"]), abs=2e-6)  # the capture time
        if row["status"] == "ok":
            tip = np.array([float(row[k]) for k in ("x_mm", "y_mm", "z_mm")])
            axis = np.array([float(row[k]) for k in ("dir_x", "dir_y", "dir_z")])
            np.testing.assert_allclose(transform.matrix[:3, 3], tip, atol=1e-5)
            np.testing.assert_allclose(transform.matrix[:3, 2], axis, atol=1e-5)
            assert status["sigma_mm"] == pytest.approx(float(row["sigma_mm"]), abs=1e-6)
    assert [r["status"] for r in rows[-3:]] == ["unreadable"] * 3
    np.testing.assert_array_equal(transforms[-1].matrix, transforms[-4].matrix)  # the last pose, marked invalid
    err = capsys.readouterr().err
    assert "TipToEye (TRANSFORM) and TipToEyeStatus (STRING) on 127.0.0.1" in err and "1 clients served" in err


def test_a_mismatch_frame_s_status_says_what_of_the_setup_does_not_fit() -> None:
    verdict = "the instrument's axes over 10 frames pass 0.52 mm from the setup's insertion point"
    with PoseServer(0) as server, recording_client(server.port) as messages:
        assert wait_for(lambda: server.connected)
        server.send(pose(0), 0, time.time(), "tracked")
        server.send(PoseEstimate("mismatch", spots=1, detail=verdict), 1, time.time(), "tracked")
        assert wait_for(lambda: len(messages.of(DEFAULT_DEVICE + "Status")) == 2)
    ok, flagged = (json.loads(m.string) for m in messages.of(DEFAULT_DEVICE + "Status"))
    assert "detail" not in ok and flagged["status"] == "mismatch" and flagged["detail"] == verdict
    assert messages.of(DEFAULT_DEVICE)[1].metadata["TransformStatus"] == "INVALID"


def test_bad_clients_neither_stop_nor_starve_tracking(capsys: pytest.CaptureFixture[str]) -> None:
    # Issue 20: garbage, a half header and a clean close, a header claiming a 2^62-byte body, an idle
    # client that holds its connection, 200 connects and closes: the good client gets every message.
    server = PoseServer(0)
    port = server.port
    with recording_client(port) as messages:
        assert wait_for(lambda: server.connected)
        idle = socket.create_connection(("127.0.0.1", port))
        garbage = socket.create_connection(("127.0.0.1", port))
        garbage.sendall(np.random.default_rng(0).bytes(5000))
        half = socket.create_connection(("127.0.0.1", port))
        half.sendall(b"\x00\x01TRANSFORM\x00\x00\x00TipTo")  # 20 header bytes, then a clean close
        half.close()
        huge = socket.create_connection(("127.0.0.1", port))
        header = b"\x00\x01" + b"STRING".ljust(12, b"\0") + b"x".ljust(20, b"\0") + bytes(8)
        huge.sendall(header + (1 << 62).to_bytes(8))
        for _ in range(200):
            socket.create_connection(("127.0.0.1", port)).close()
        for frame in range(600):  # queued at once: benchmarks/test_speed.py times a send beside such clients
            server.send(pose(frame), frame, time.time(), "tracked")
        assert wait_for(lambda: len(messages.of(DEFAULT_DEVICE)) == 600)
        assert finishes(server.close)  # no client holds the server open
        for sock in (idle, garbage, huge):
            sock.close()
    tips = [m.matrix[0, 3] for m in messages.of(DEFAULT_DEVICE)]
    np.testing.assert_allclose(tips, 0.01 * np.arange(600), atol=1e-6)
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err + captured.out


def test_a_client_that_connects_late_leaves_and_comes_back_gets_the_frames_while_connected() -> None:
    with PoseServer(0) as server:
        port = server.port
        server.send(pose(0), 0, time.time())  # nobody listening: dropped, nothing breaks
        assert wait_for(lambda: server.pending_frames == 0)
        with recording_client(port) as first:
            assert wait_for(lambda: server.connected)
            for frame in range(1, 11):
                server.send(pose(frame), frame, time.time())
            assert wait_for(lambda: len(first.of(DEFAULT_DEVICE)) == 10)
        assert wait_for(lambda: not server.connected)
        with recording_client(port) as second:
            assert wait_for(lambda: server.connected)
            for frame in range(11, 21):
                server.send(pose(frame), frame, time.time())
            assert wait_for(lambda: len(second.of(DEFAULT_DEVICE)) == 10)
    assert [json.loads(m.string)["frame"] for m in first.of(DEFAULT_DEVICE + "Status")] == list(range(1, 11))
    assert [json.loads(m.string)["frame"] for m in second.of(DEFAULT_DEVICE + "Status")] == list(range(11, 21))
    assert server.clients_served == 2


def test_a_client_that_stops_reading_is_dropped_and_one_that_reads_gets_everything() -> None:
    frames = 30_000  # some 9 MB: more than the kernel's buffers and the server's 1 MiB
    received = bytearray()

    def read_all(sock: socket.socket) -> None:
        while chunk := sock.recv(1 << 16):
            received.extend(chunk)

    with PoseServer(0) as server:
        stalled = socket.socket()
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stalled.connect(("127.0.0.1", server.port))
        reader = socket.create_connection(("127.0.0.1", server.port))
        reading = threading.Thread(target=read_all, args=(reader,))
        reading.start()
        assert wait_for(lambda: server.clients_served == 2)
        for frame in range(frames):  # at a pace the server thread keeps up with (its queue drops the oldest)
            server.send(pose(frame), frame, time.time())
            if frame % 1000 == 999:
                assert wait_for(lambda: server.pending_frames == 0)
        assert wait_for(lambda: server.clients_dropped == 1)
    reading.join(10.0)
    for sock in (stalled, reader):
        sock.close()
    kinds, offset = [], 0
    while offset + 58 <= len(received):  # OpenIGTLink: a 58-byte header, its body's size at bytes 42-50
        kinds.append(bytes(received[offset + 2 : offset + 14]).rstrip(b"\0"))
        offset += 58 + int.from_bytes(received[offset + 42 : offset + 50], "big")
    assert offset == len(received) and kinds.count(b"TRANSFORM") == kinds.count(b"STRING") == frames


def test_server_errors_name_the_address_and_the_device() -> None:
    with PoseServer(0) as server, pytest.raises(IgtlError, match=f"cannot listen on 127.0.0.1:{server.port}"):
        PoseServer(server.port)
    with pytest.raises(IgtlError, match="--igtl-device"):
        PoseServer(free_port(), device="ThisNameIsFarTooLong")


def test_serving_beyond_loopback_warns_that_there_is_no_authentication(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = write_scene(tmp_path / "setup.toml", size_px=256)
    frame = tmp_path / "frames" / "frame_00000.png"
    assert main(["render", "--scene", str(scene), "--tip", "0", "0", "4", "--out", str(frame)]) == 0
    track = ["track", "--scene", str(scene), str(frame.parent), "--out", str(tmp_path / "poses.csv")]
    assert main([*track, "--igtl", str(free_port()), "--igtl-host", "0.0.0.0", "--igtl-device", "NeedleToEye"]) == 0
    err = capsys.readouterr().err
    assert "no authentication" in err and "NeedleToEye (TRANSFORM)" in err


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


def test_a_pose_that_stops_updating_turns_invalid_as_stale_and_the_next_pose_clears_it() -> None:
    with PoseServer(0, stale_s=0.5) as server, recording_client(server.port) as messages:
        assert wait_for(lambda: server.connected)
        server.send(pose(0), 0, time.time(), "tracked")
        server.send(pose(1), 1, time.time(), "tracked")
        sent = time.monotonic()
        assert wait_for(lambda: len(messages.of(DEFAULT_DEVICE)) == 3)  # the two poses, then the stale one
        time.sleep(0.3)
        server.send(pose(2), 2, time.time(), "tracked")
        assert wait_for(lambda: len(messages.of(DEFAULT_DEVICE)) == 4)
        time.sleep(0.2)  # under 0.5 s since the last pose: nothing more
    transforms = messages.timed(DEFAULT_DEVICE)
    statuses = [json.loads(m.string) for m in messages.of(DEFAULT_DEVICE + "Status")]
    assert [m.metadata["TransformStatus"] for _, m in transforms] == ["OK", "OK", "INVALID", "OK"]
    stale_at, stale = transforms[2]
    assert 0.45 <= stale_at - sent < 0.6 and stale.metadata["Status"] == "stale"
    np.testing.assert_array_equal(stale.matrix, transforms[1][1].matrix)  # the last pose, marked invalid
    assert statuses[2]["status"] == "stale" and statuses[2]["frame"] == 1 and statuses[2]["mode"] == "tracked"
    assert 0.5 <= statuses[2]["seconds_since_frame"] < 0.6 and statuses[2]["detail"].startswith("no frame for 0.5")
    assert [s["frame"] for s in statuses] == [0, 1, 1, 2] and statuses[3]["status"] == "ok"


def test_a_client_that_sends_garbage_is_dropped_and_reported_once_with_its_address() -> None:
    said: list[str] = []
    with PoseServer(0, report=said.append) as server, recording_client(server.port) as messages:
        assert wait_for(lambda: server.connected)
        garbage = socket.create_connection(("127.0.0.1", server.port))
        host, port = garbage.getsockname()[:2]
        address = f"{host}:{port}"
        garbage.sendall(b"GET / HTTP/1.1\r\nHost: localhost\r\n\r\n")
        assert wait_for(lambda: server.clients_garbage == 1)
        with contextlib.suppress(OSError):  # the server has closed it: more garbage is not read, nor reported
            garbage.sendall(np.random.default_rng(0).bytes(5000))
        command = pyigtl.StringMessage("hello", device_name="Command")  # a well-formed message: skipped, kept
        polite = socket.create_connection(("127.0.0.1", server.port))
        polite.sendall(command.pack() * 3)
        server.send(pose(0), 0, time.time(), "tracked")
        assert wait_for(lambda: len(messages.of(DEFAULT_DEVICE)) == 1)
        time.sleep(0.2)
        assert server.connected and server.clients_garbage == 1
        garbage.close()
        polite.close()
    assert said == [f"spotnav: warning: OpenIGTLink: {address} sent what is not OpenIGTLink: dropped"]


def test_waiting_for_a_client_ignores_one_that_connects_and_closes_at_once() -> None:
    with PoseServer(0) as server:
        start = time.monotonic()
        for _ in range(5):
            socket.create_connection(("127.0.0.1", server.port)).close()
        assert not server.wait_for_client(1.0)
        assert time.monotonic() - start >= 1.0 and server.clients_served == 5
        with recording_client(server.port):
            start = time.monotonic()
            assert server.wait_for_client(10.0)
            assert time.monotonic() - start >= SETTLE_S  # a client counts once it stayed
