"""Run independent tasks on Dask (a local cluster or a scheduler's) or in this process, each result as it arrives.

The studies that fan out over many setups (``sweep``, ``design``) hand :func:`task_runner`'s runner a function and
its tasks;
the local cluster's workers are single-threaded processes whose numeric libraries and OpenCV use one thread each,
so that ``workers`` processes keep ``workers`` cores busy and no more.

A scheduler's address is checked before Dask is handed it (:func:`connect_scheduler`): a scheme other than
``tcp://``/``tls://``, a port where nothing listens, an endpoint that answers HTTP (the dashboard's port) or no
Dask handshake at all, and a scheduler without workers after the stated wait are each a :class:`ClusterError`
of one line, within that wait. During a run, a worker that leaves is said in one line (Dask runs its tasks again
on the others); no worker left for the wait, a lost scheduler, or a task that killed its workers in turn are
errors.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import socket
import struct
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

from spotnav.errors import InputError

__all__ = [
    "SCHEDULER_TIMEOUT_S",
    "ClusterError",
    "TaskRunner",
    "Workers",
    "check_cluster_options",
    "connect_scheduler",
    "scheduler_endpoint",
    "seed_of",
    "task_runner",
]

Task = TypeVar("Task")
Result = TypeVar("Result")

SCHEDULER_TIMEOUT_S = 20.0
"""How long a scheduler may take to answer, to have a worker, and to get one back when all have left, s."""

# The local cluster's workers: one thread each, and none for the numeric libraries. Dask's default
# also sets MALLOC_TRIM_THRESHOLD_, which turns off glibc's adaptive mmap threshold: every frame-sized
# array is then mapped and faulted in afresh, and rendering ran 3x slower on each worker.
_WORKER_ENVIRONMENT = {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1}
_SCHEMES = ("tcp", "tls")  # Dask's schemes that a scheduler started by `dask scheduler` listens on
_HANDSHAKE_BYTES = 1 << 20  # a Dask handshake's first 8 bytes: its length, a few hundred bytes (at most this)
_HTTP_AFTER_S = 3.0  # a Dask scheduler speaks first; silent this long (or half the wait), the endpoint is asked HTTP
_POLL_S = 1.0  # how often a run looks for lost workers, s
_CHECK = "give the scheduler's tcp://HOST:PORT as `dask scheduler` prints it (port 8786 by default)"


class ClusterError(InputError):
    """Cluster options that cannot be used together, or a cluster that cannot be used (said in one line)."""


def scheduler_endpoint(address: str) -> tuple[str, str, int]:
    """A scheduler's address as ``(scheme, host, port)``; ``HOST:PORT`` alone is ``tcp``.

    Raises
    ------
    ClusterError
        For a scheme Dask's schedulers do not listen on (``http://``: the dashboard's), or no port.
    """
    scheme, separator, rest = address.partition("://")
    if not separator:
        scheme, rest = "tcp", address
    if scheme in ("http", "https"):
        raise ClusterError(
            f"--scheduler {address}: {scheme}:// is the Dask dashboard's (port 8787 by default), not the scheduler's: "
            + _CHECK
        )
    if scheme not in _SCHEMES:
        raise ClusterError(f"--scheduler {address}: unknown scheme {scheme}:// ({', '.join(_SCHEMES)} only): " + _CHECK)
    host, colon, port = rest.rstrip("/").rpartition(":")
    if not colon or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ClusterError(f"--scheduler {address}: no port: " + _CHECK)
    return scheme, host.strip("[]"), int(port)


def check_cluster_options(
    scheduler: str | None, workers: int | None, dashboard: str | None, timeout_s: float | None = None
) -> None:
    """Refuse ``workers`` below 0, ``workers`` with a ``scheduler``, a ``dashboard`` without a local cluster, a
    scheduler's address Dask cannot use, and a ``timeout_s`` that is not positive or has no ``scheduler``.

    Raises
    ------
    ClusterError
        Naming the option (``--workers``, ``--dashboard``, ``--scheduler``, ``--scheduler-timeout``).
    """
    if workers is not None and workers < 0:
        raise ClusterError(f"--workers must be >= 0, got {workers}")
    if scheduler is not None and workers is not None:
        raise ClusterError("--workers sizes the local cluster; it cannot be used with --scheduler")
    if dashboard is not None and (scheduler is not None or workers == 0):
        raise ClusterError("--dashboard serves the local Dask cluster's: not with --scheduler or --workers 0")
    if timeout_s is not None and scheduler is None:
        raise ClusterError("--scheduler-timeout is how long to wait for a --scheduler: not without one")
    if timeout_s is not None and not timeout_s > 0:
        raise ClusterError(f"--scheduler-timeout must be > 0 s, got {timeout_s:g}")
    if scheduler is not None:
        scheduler_endpoint(scheduler)


def _first_bytes(sock: socket.socket, deadline: float) -> bytes | None:
    """Up to 8 bytes the peer sends before ``deadline`` (``time.monotonic``); b"" if it closed, None if silent."""
    data = b""
    while len(data) < 8:
        left = deadline - time.monotonic()
        if left <= 0:
            return data or None
        sock.settimeout(left)
        try:
            more = sock.recv(8 - len(data))
        except TimeoutError:
            return data or None
        if not more:
            return data
        data += more
    return data


def _probe_scheduler(address: str, host: str, port: int, timeout_s: float) -> None:
    """Check that a Dask scheduler listens at ``host:port``: it speaks first, a Dask handshake (tcp only).

    Raises
    ------
    ClusterError
        Nothing listens there, nothing answers, the endpoint speaks HTTP, or something else than Dask answers.
    """
    where = f"--scheduler {address}"
    deadline = time.monotonic() + timeout_s
    try:
        sock = socket.create_connection((host, port), timeout=timeout_s)
    except socket.gaierror:
        raise ClusterError(f"{where}: no host {host} is known here: check its name") from None
    except ConnectionRefusedError:
        raise ClusterError(
            f"{where}: nothing listens on port {port} of {host}: is the scheduler running? " + _CHECK
        ) from None
    except TimeoutError:
        raise ClusterError(
            f"{where}: no connection within {timeout_s:g} s (--scheduler-timeout): check the host, port and firewall"
        ) from None
    except OSError as error:
        raise ClusterError(f"{where}: cannot connect ({error.strerror or error}): check the host and port") from None
    with sock:
        first = _first_bytes(sock, time.monotonic() + min(_HTTP_AFTER_S, timeout_s / 2))
        if first is None:  # silent: a web server waits for a request
            with contextlib.suppress(OSError):
                sock.sendall(f"GET / HTTP/1.0\r\nHost: {host}\r\n\r\n".encode())
            first = _first_bytes(sock, deadline)
    if first is None:
        raise ClusterError(
            f"{where}: it accepted a connection but sent no Dask handshake within {timeout_s:g} s "
            "(--scheduler-timeout): is it a Dask scheduler's port? " + _CHECK
        )
    if first.startswith(b"HTTP"):
        raise ClusterError(
            f"{where}: it answers HTTP, not Dask: a web server or the Dask dashboard (port 8787 by default); " + _CHECK
        )
    if len(first) < 8 or struct.unpack("<Q", first)[0] > _HANDSHAKE_BYTES:
        raise ClusterError(f"{where}: what answers there is not a Dask scheduler (it sent {first!r}): " + _CHECK)


def connect_scheduler(address: str, timeout_s: float = SCHEDULER_TIMEOUT_S) -> Any:
    """A ``distributed.Client`` of the scheduler at ``address`` once it has a worker; every step within ``timeout_s``.

    Raises
    ------
    ClusterError
        In one line, naming what to check: the address (:func:`scheduler_endpoint`), nothing or something else than
        Dask at it, or no worker after ``timeout_s``.
    """
    from distributed import Client

    scheme, host, port = scheduler_endpoint(address)
    if scheme == "tcp":
        _probe_scheduler(address, host, port, timeout_s)
    try:
        client = Client(address, timeout=timeout_s)
    except OSError as error:  # TimeoutError among them
        message = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ClusterError(f"--scheduler {address}: {message}: " + _CHECK) from None
    try:
        client.wait_for_workers(1, timeout=timeout_s)
    except TimeoutError:
        client.close()
        raise ClusterError(
            f"--scheduler {address}: no Dask worker joined it within {timeout_s:g} s (--scheduler-timeout): "
            f"start some (dask worker {address} --nthreads 1)"
        ) from None
    return client


def seed_of(*parts: object) -> int:
    """A noise seed from a plan's place (the run's seed, the design or point, the frame): 32 bits of a digest."""
    key = "/".join(map(str, parts)).encode()
    return int.from_bytes(hashlib.blake2b(key, digest_size=4).digest(), "little")


@dataclass(frozen=True)
class Workers:
    """Where tasks ran: Dask worker processes (0: in this process) and their threads in all."""

    processes: int
    threads: int

    def where(self) -> str:
        """``in this process``, ``on 1 Dask worker (2 threads)``, ``on 2 Dask workers (2 threads)``."""
        if self.processes == 0:
            return "in this process"
        plural = ("s" if self.processes != 1 else "", "s" if self.threads != 1 else "")
        return f"on {self.processes} Dask worker{plural[0]} ({self.threads} thread{plural[1]})"


class TaskRunner(Protocol):
    """Runs ``function`` on every task, handing each task and its result to ``done`` as it arrives."""

    def __call__(
        self, function: Callable[[Task], Result], tasks: Sequence[Task], done: Callable[[Task, Result], None], name: str
    ) -> None: ...


def _in_process(
    function: Callable[[Task], Result], tasks: Sequence[Task], done: Callable[[Task, Result], None], name: str
) -> None:
    for task in tasks:
        done(task, function(task))


class _WorkerWatch:
    """Says each worker that leaves a run (once), and refuses a cluster left without workers for ``timeout_s``."""

    def __init__(self, client: Any, where: str, timeout_s: float, log: Callable[[str], None]) -> None:
        self.client, self.where, self.timeout_s, self.log = client, where, timeout_s, log
        self.known = set(self._workers())
        self.checked = self.last_seen = time.monotonic()

    def _workers(self) -> dict[str, int]:
        try:
            workers: dict[str, int] = self.client.nthreads()
        except OSError:  # CommClosedError among them
            raise ClusterError(f"{self.where}: lost the Dask scheduler mid-run: check it, then run again") from None
        return workers

    def check(self) -> None:
        now = time.monotonic()
        if now - self.checked < _POLL_S:
            return
        self.checked = now
        workers = set(self._workers())
        for lost in sorted(self.known - workers):
            self.log(f"Dask worker {lost} left mid-run: its tasks run again on the {len(workers)} left")
        self.known = workers
        if workers:
            self.last_seen = now
        elif now - self.last_seen > self.timeout_s:
            raise ClusterError(
                f"{self.where}: every Dask worker left mid-run and none came back within {self.timeout_s:g} s: "
                "check the workers' logs (memory?), start some, and run again"
            )


def _result(future: Any, where: str) -> Any:
    """A finished task's result; a cluster's failure as a :class:`ClusterError` (a task's own error as raised)."""
    from concurrent.futures import CancelledError

    from distributed.scheduler import KilledWorker

    try:
        return future.result()
    except KilledWorker as error:
        raise ClusterError(
            f"{where}: a task's workers died in turn ({error.args[0] if error.args else 'a task'}): "
            "check the workers' logs (memory?)"
        ) from None
    except CancelledError:
        raise ClusterError(f"{where}: the Dask scheduler dropped the run (lost mid-run?): check it") from None


@contextlib.contextmanager
def task_runner(
    scheduler: str | None = None,
    workers: int | None = None,
    dashboard: str | None = None,
    log: Callable[[str], None] = print,
    timeout_s: float | None = None,
) -> Iterator[tuple[TaskRunner, Workers]]:
    """A runner of independent tasks, and where it runs them (no workers: in this process), for the ``with`` block.

    The runner takes a function (picklable on Dask: a module's function or a ``functools.partial`` of one), its
    tasks, a ``done(task, result)`` called in this process as each result arrives (in plan order without Dask),
    and a name for the tasks' keys on the cluster.

    Parameters
    ----------
    scheduler : str, optional
        A Dask scheduler's address (``tcp://HOST:PORT``); by default a ``distributed.LocalCluster`` of
        ``workers`` single-threaded processes, closed at the block's end.
    workers : int, optional
        The local cluster's workers (default: one per core); 0 runs the tasks in this process, without Dask.
    dashboard : str, optional
        Serve the local cluster's dashboard at this address (``:0`` picks a free port); its link goes to ``log``.
        With ``scheduler``, the scheduler's own dashboard link is logged.
    log : callable
        Also gets a line for each worker that leaves a run.
    timeout_s : float, optional
        How long the scheduler may take to answer, to have a worker, and to get one back when all have left
        (default :data:`SCHEDULER_TIMEOUT_S`).

    Raises
    ------
    ClusterError
        A scheduler that cannot be used, or a cluster that fails mid-run (:func:`connect_scheduler`).
    """
    if workers == 0 and scheduler is None:
        yield _in_process, Workers(0, 0)
        return
    import dask.config
    from distributed import Client, LocalCluster, WorkerPlugin, wait

    class OneThreadPerWorker(WorkerPlugin):
        """OpenCV's own thread pool off: each worker is one thread, on its own core."""

        def setup(self, worker: Any) -> None:
            import cv2

            cv2.setNumThreads(1)

    timeout_s = SCHEDULER_TIMEOUT_S if timeout_s is None else timeout_s
    where = f"--scheduler {scheduler}" if scheduler is not None else "the local Dask cluster"
    if scheduler is not None:
        client, cluster = connect_scheduler(scheduler, timeout_s), None
    else:
        count = workers or os.cpu_count() or 1
        with dask.config.set({"distributed.nanny.pre-spawn-environ": _WORKER_ENVIRONMENT}):
            cluster = LocalCluster(n_workers=count, threads_per_worker=1, processes=True, dashboard_address=dashboard)
        client = Client(cluster)

    def on_dask(
        function: Callable[[Task], Result], tasks: Sequence[Task], done: Callable[[Task, Result], None], name: str
    ) -> None:
        token = hashlib.blake2b(repr((function, list(tasks))).encode(), digest_size=8).hexdigest()
        keys = [f"spotnav-{name}-{token}-{index}" for index in range(len(tasks))]
        futures = {client.submit(function, task, key=key): task for key, task in zip(keys, tasks, strict=True)}
        watch = _WorkerWatch(client, where, timeout_s, log)
        pending = set(futures)
        while pending:
            try:
                finished, pending = wait(pending, timeout=_POLL_S, return_when="FIRST_COMPLETED")
            except TimeoutError:
                finished = set()
            for future in finished:
                done(futures[future], _result(future, where))
                future.release()
            watch.check()

    try:
        if dashboard is not None or scheduler is not None:
            link = client.dashboard_link
            log(f"Dask dashboard: {link}" if link else "Dask dashboard: not served (is bokeh installed?)")
        client.register_plugin(OneThreadPerWorker())
        threads = client.nthreads()
        yield on_dask, Workers(len(threads), sum(threads.values()))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
