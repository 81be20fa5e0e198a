"""Stream poses to 3D Slicer (OpenIGTLinkIF) or any OpenIGTLink client, as PLUS does.

Each pose goes out as a TRANSFORM message named :data:`DEVICE_NAME`: the
homogeneous transform from the instrument's frame to the eye frame
(:func:`spotnav.geometry.instrument_to_eye`), translation in millimetres.
The server listens on the loopback interface; a frame without a pose sends
nothing.
"""

from __future__ import annotations

import logging
import signal
import time

import pyigtl

from spotnav.estimate import PoseEstimate
from spotnav.geometry import instrument_to_eye

__all__ = ["DEFAULT_PORT", "DEVICE_NAME", "PoseServer"]

DEFAULT_PORT = 18944
DEVICE_NAME = "SpotnavTip"
_FLUSH_TIMEOUT_S = 2.0

_log = logging.getLogger("spotnav.igtl")


class PoseServer:
    """An OpenIGTLink server that sends each ``ok`` pose as a TRANSFORM message.

    Parameters
    ----------
    port : int
        TCP port on 127.0.0.1 (OpenIGTLink's default is 18944).
    wait_s : float
        Wait up to this long for a client before returning from the constructor.

    Use it as a context manager; leaving it sends what is queued and closes the server.
    """

    def __init__(self, port: int = DEFAULT_PORT, wait_s: float = 0.0) -> None:
        if not 0 < port < 65536:
            raise ValueError(f"--igtl port must be in 1..65535, got {port}")
        handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
        self._server = pyigtl.OpenIGTLinkServer(port=port, local_server=True)
        for number, handler in handlers.items():  # pyigtl installs its own; keep the caller's
            signal.signal(number, handler)
        self.port = port
        deadline = time.monotonic() + wait_s
        while not self._server.is_connected() and time.monotonic() < deadline:
            time.sleep(0.01)

    @property
    def connected(self) -> bool:
        """Whether a client is connected."""
        return bool(self._server.is_connected())

    def send(self, estimate: PoseEstimate, frame: int) -> bool:
        """Queue the estimate's pose; returns whether it was sent (an ``ok`` pose and a client)."""
        if not estimate.ok:
            reason = f"{estimate.status}: {estimate.detail}" if estimate.detail else estimate.status
            _log.info("frame %d: no pose sent (%s)", frame, reason)
            return False
        if not self.connected:
            _log.info("frame %d: no OpenIGTLink client connected", frame)
            return False
        assert estimate.tip_in_eye is not None and estimate.axis is not None
        matrix = instrument_to_eye(estimate.tip_in_eye, estimate.axis, estimate.roll)
        message = pyigtl.TransformMessage(matrix, device_name=DEVICE_NAME, timestamp=time.time())
        return bool(self._server.send_message(message, wait=False))

    def close(self) -> None:
        """Send what is queued (up to 2 s) and stop the server."""
        deadline = time.monotonic() + _FLUSH_TIMEOUT_S
        while self.connected and time.monotonic() < deadline:
            with self._server.lock_outgoing_messages:
                if not self._server.outgoing_messages:
                    break
            time.sleep(0.005)
        self._server.stop()

    def __enter__(self) -> PoseServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
