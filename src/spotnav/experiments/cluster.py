"""Run independent tasks on Dask (a local cluster or a scheduler's) or in this process, each result as it arrives.

The studies that fan out over many setups (``sweep``, ``design``) hand :func:`task_runner`'s runner a function and
its tasks;
the local cluster's workers are single-threaded processes whose numeric libraries and OpenCV use one thread each,
so that ``workers`` processes keep ``workers`` cores busy and no more.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Protocol, TypeVar

from spotnav.errors import InputError

__all__ = ["ClusterError", "TaskRunner", "check_cluster_options", "seed_of", "task_runner"]

Task = TypeVar("Task")
Result = TypeVar("Result")

# The local cluster's workers: one thread each, and none for the numeric libraries. Dask's default
# also sets MALLOC_TRIM_THRESHOLD_, which turns off glibc's adaptive mmap threshold: every frame-sized
# array is then mapped and faulted in afresh, and rendering ran 3x slower on each worker.
_WORKER_ENVIRONMENT = {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1}


class ClusterError(InputError):
    """Cluster options that cannot be used together."""


def check_cluster_options(scheduler: str | None, workers: int | None, dashboard: str | None) -> None:
    """Refuse ``workers`` below 0, ``workers`` with a ``scheduler``, and a ``dashboard`` without a local cluster.

    Raises
    ------
    ClusterError
        Naming the option (``--workers``, ``--dashboard``).
    """
    if workers is not None and workers < 0:
        raise ClusterError(f"--workers must be >= 0, got {workers}")
    if scheduler is not None and workers is not None:
        raise ClusterError("--workers sizes the local cluster; it cannot be used with --scheduler")
    if dashboard is not None and (scheduler is not None or workers == 0):
        raise ClusterError("--dashboard serves the local Dask cluster's: not with --scheduler or --workers 0")


def seed_of(*parts: object) -> int:
    """A noise seed from a plan's place (the run's seed, the design or point, the frame): 32 bits of a digest."""
    key = "/".join(map(str, parts)).encode()
    return int.from_bytes(hashlib.blake2b(key, digest_size=4).digest(), "little")


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


@contextlib.contextmanager
def task_runner(
    scheduler: str | None = None,
    workers: int | None = None,
    dashboard: str | None = None,
    log: Callable[[str], None] = print,
) -> Iterator[tuple[TaskRunner, int]]:
    """A runner of independent tasks, and its worker count (0 in this process), for the ``with`` block.

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
    """
    if workers == 0 and scheduler is None:
        yield _in_process, 0
        return
    import dask.config
    from distributed import Client, LocalCluster, WorkerPlugin, as_completed

    class OneThreadPerWorker(WorkerPlugin):
        """OpenCV's own thread pool off: each worker is one thread, on its own core."""

        def setup(self, worker: Any) -> None:
            import cv2

            cv2.setNumThreads(1)

    if scheduler is not None:
        client, cluster = Client(scheduler), None
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
        for future in as_completed(futures):
            done(futures[future], future.result())
            future.release()

    try:
        if dashboard is not None or scheduler is not None:
            link = client.dashboard_link
            log(f"Dask dashboard: {link}" if link else "Dask dashboard: not served (is bokeh installed?)")
        client.register_plugin(OneThreadPerWorker())
        yield on_dask, len(client.scheduler_info()["workers"])
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
