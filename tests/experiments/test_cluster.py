"""Tasks on Dask or in this process: a scheduler's address checked, a wrong or empty cluster said in one line, lost
workers said, and the workers and threads counted (local schedulers only: loopback, a web server, a closed port)."""

from __future__ import annotations

import http.server
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from distributed import LocalCluster

from spotnav.cli import main
from spotnav.experiments.cluster import (
    ClusterError,
    Workers,
    check_cluster_options,
    connect_scheduler,
    scheduler_endpoint,
    task_runner,
)

# No test asserts how long an error took (issue 61): each waits a small stated timeout, and says so.
WAIT_S = 2.0
_TCP = {"protocol": "tcp://", "host": "127.0.0.1"}  # an in-process cluster's scheduler on loopback, not inproc://


def _closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
    return port


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: object) -> None:
        pass


class _QuietServer(http.server.ThreadingHTTPServer):
    def handle_error(self, request: object, client_address: object) -> None:
        pass  # a client that hung up before reading the answer: the probe may


@contextmanager
def _web_server() -> Iterator[int]:
    """A web server on a free loopback port (an endpoint that answers HTTP, not Dask)."""
    server = _QuietServer(("127.0.0.1", 0), _Quiet)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server.server_address[1]
    finally:
        server.shutdown()
        server.server_close()


@contextmanager
def _silent_listener() -> Iterator[int]:
    """A loopback port that accepts connections and never says a word."""
    with socket.create_server(("127.0.0.1", 0)) as listener:
        accepted: list[socket.socket] = []
        thread = threading.Thread(target=lambda: accepted.append(listener.accept()[0]), daemon=True)
        thread.start()
        try:
            yield listener.getsockname()[1]
        finally:
            for sock in accepted:
                sock.close()


@pytest.mark.parametrize(
    ("address", "endpoint"),
    [
        ("tcp://127.0.0.1:8786", ("tcp", "127.0.0.1", 8786)),
        ("scheduler.lan:8786", ("tcp", "scheduler.lan", 8786)),
        ("tls://[::1]:9000/", ("tls", "::1", 9000)),
    ],
)
def test_an_address_reads_as_dask_reads_it(address: str, endpoint: tuple[str, str, int]) -> None:
    assert scheduler_endpoint(address) == endpoint


@pytest.mark.parametrize(
    ("address", "message"),
    [
        ("http://host:8786", "http:// is the Dask dashboard's"),
        ("https://host:8787/status", "https:// is the Dask dashboard's"),
        ("udp://host:8786", "unknown scheme udp://"),
        ("tcp://host", "no port"),
        ("tcp://host:port", "no port"),
        ("tcp://host:70000", "no port"),
    ],
)
def test_a_bad_address_is_refused_naming_what_to_give(address: str, message: str) -> None:
    with pytest.raises(ClusterError, match=message) as caught:
        check_cluster_options(address, None, None)
    assert "tcp://HOST:PORT" in str(caught.value) and "\n" not in str(caught.value)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ((None, None, None, 5.0), "--scheduler-timeout is how long to wait for a --scheduler"),
        (("tcp://h:1", None, None, 0.0), "--scheduler-timeout must be > 0"),
    ],
)
def test_a_timeout_needs_a_scheduler_and_a_length(options: tuple[str | None, None, None, float], message: str) -> None:
    with pytest.raises(ClusterError, match=message):
        check_cluster_options(*options)


def test_nothing_listening_is_said() -> None:
    port = _closed_port()
    with pytest.raises(ClusterError, match=f"nothing listens on port {port} of 127.0.0.1: is the scheduler running"):
        connect_scheduler(f"tcp://127.0.0.1:{port}", WAIT_S)


def test_a_web_server_is_said_to_answer_http() -> None:
    with _web_server() as port, pytest.raises(ClusterError, match="it answers HTTP, not Dask"):
        connect_scheduler(f"tcp://127.0.0.1:{port}", WAIT_S)


def test_the_dashboards_port_is_said_to_answer_http() -> None:
    with LocalCluster(n_workers=0, processes=False, dashboard_address="127.0.0.1:0", **_TCP) as cluster:
        port = int(cluster.dashboard_link.split(":")[2].split("/")[0])
        with pytest.raises(ClusterError, match="the Dask dashboard \\(port 8787 by default\\)"):
            connect_scheduler(f"tcp://127.0.0.1:{port}", WAIT_S)


def test_a_silent_endpoint_is_said_after_the_stated_wait() -> None:
    with _silent_listener() as port, pytest.raises(ClusterError, match="sent no Dask handshake within 2 s"):
        connect_scheduler(f"tcp://127.0.0.1:{port}", WAIT_S)


def test_a_scheduler_without_workers_is_said_after_the_stated_wait() -> None:
    with LocalCluster(n_workers=0, processes=False, dashboard_address=None, **_TCP) as cluster:
        address = cluster.scheduler_address
        with pytest.raises(ClusterError, match=f"no Dask worker joined it within 2 s .*dask worker {address}"):
            connect_scheduler(address, WAIT_S)


@pytest.mark.parametrize(
    ("workers", "where"),
    [
        (Workers(0, 0), "in this process"),
        (Workers(1, 1), "on 1 Dask worker (1 thread)"),
        (Workers(1, 2), "on 1 Dask worker (2 threads)"),
        (Workers(3, 5), "on 3 Dask workers (5 threads)"),
    ],
)
def test_where_says_workers_and_threads(workers: Workers, where: str) -> None:
    assert workers.where() == where


def test_a_schedulers_workers_and_threads_are_counted() -> None:
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None, **_TCP) as cluster:
        results: dict[int, int] = {}
        with task_runner(cluster.scheduler_address, log=lambda line: None) as (run, used):
            run(abs, [-1, -2, -3], results.__setitem__, "abs")
    assert used == Workers(1, 2) and results == {-1: 1, -2: 2, -3: 3}


def test_every_worker_lost_mid_run_is_said_and_refused_after_the_stated_wait() -> None:
    lines: list[str] = []
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None, **_TCP) as cluster:
        with task_runner(cluster.scheduler_address, log=lines.append, timeout_s=WAIT_S) as (run, _):
            (worker,) = cluster.scheduler_info["workers"]

            def lose_the_worker(task: float, result: None) -> None:
                cluster.scale(0)

            with pytest.raises(ClusterError, match="every Dask worker left mid-run and none came back within 2 s"):
                run(time.sleep, [0.2] * 20, lose_the_worker, "sleep")
    assert f"Dask worker {worker} left mid-run: its tasks run again on the 0 left" in lines


@pytest.mark.parametrize(
    ("scheduler", "message"),
    [
        ("http://127.0.0.1:8786", "http:// is the Dask dashboard's"),
        ("web server", "it answers HTTP, not Dask"),
        ("closed port", "nothing listens on port"),
    ],
)
def test_cli_says_a_wrong_scheduler_in_one_line(
    scheduler: str, message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sweep = tmp_path / "sweep.toml"
    sweep.write_text("[frames]\ncount = 1\n")
    with _web_server() as web:
        address = {"web server": f"tcp://127.0.0.1:{web}", "closed port": f"tcp://127.0.0.1:{_closed_port()}"}
        argv = ["sweep", str(sweep), "--out", str(tmp_path / "out"), "--scheduler", address.get(scheduler, scheduler)]
        assert main([*argv, "--scheduler-timeout", str(WAIT_S)]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and error[0].startswith("spotnav: error: --scheduler ") and message in error[0]
