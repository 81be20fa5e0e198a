"""What must be fast beside the frame's stages: the command's start and the OpenIGTLink server's queue.

The suite's tests assert what these do; how long they take is measured here, not asserted (issue 61).
"""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from spotnav.app.igtl import PoseServer
from spotnav.pose.estimate import PoseEstimate

SPOTNAV = Path(sys.executable).parent / "spotnav"


def test_version(benchmark: Any) -> None:
    # `spotnav --version` imports the standard library only (a tenth of a second).
    run = benchmark(subprocess.run, [str(SPOTNAV), "--version"], capture_output=True, text=True, check=True)
    assert run.stdout.startswith("spotnav ")


def test_igtl_send_beside_clients_that_read_nothing(benchmark: Any) -> None:
    # A send queues the pose and returns: a client that never reads (an idle one) costs the tracker nothing.
    estimate = PoseEstimate("ok", tip_in_eye=np.array([0.0, 0.0, 4.0]), axis=np.array([0.0, 0.0, -1.0]), spots=1)
    with PoseServer(0) as server, socket.create_connection(("127.0.0.1", server.port)):
        benchmark(server.send, estimate, 0, time.time(), "tracked")
        assert not server.error
