"""What every command does before its work: SIGTERM as Ctrl-C, an interrupted output's header, the kernels once.

Standard library only (with :mod:`spotnav.files.columns`): the command line imports this module before it knows
its command, so that ``spotnav --version`` starts at once and an interrupt in the first instant, while NumPy, Numba
and the rest are still importing, ends as cleanly as one later on.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence

from spotnav.files.columns import POSES_COLUMNS, TRACK_COLUMNS, write_header

TYPE_CHECKING = False  # the standard library's lightest: no typing module at run time
if TYPE_CHECKING:
    import argparse
    from types import FrameType

__all__ = [
    "KERNEL_COMMANDS",
    "OUTPUT_COLUMNS",
    "compile_kernels_once",
    "end_stdout_if_left",
    "header_on_interrupt",
    "poses_out",
    "terminate_as_interrupt",
]

OUTPUT_COLUMNS: dict[str, Sequence[str]] = {"localize": POSES_COLUMNS, "track": TRACK_COLUMNS}
"""The commands whose ``--out`` is a ``poses.csv``, and its columns."""

KERNEL_COMMANDS = frozenset(
    {"render", "localize", "show", "track", "calibrate", "bench", "analyze", "reproduce", "sweep", "design"}
)
"""The commands that run compiled kernels (``--example`` aside, which only prints)."""


def _interrupt(_number: int, _frame: FrameType | None) -> None:
    raise KeyboardInterrupt


@contextlib.contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM interrupts as Ctrl-C does (``KeyboardInterrupt``) instead of killing at once.

    A run that handles its own stops (:class:`spotnav.app.session.StopSignals`) replaces this while it runs. Outside
    the main thread (where signals cannot be caught) the block runs unchanged.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _file_state(path: str) -> tuple[int, int, int] | None:
    try:
        stat = os.stat(path)
    except OSError:
        return None
    return stat.st_ino, stat.st_mtime_ns, stat.st_size


def poses_out(words: Sequence[str]) -> tuple[str, Sequence[str]] | None:
    """The ``--out poses.csv`` that the command line's ``words`` ask for, and its columns; None for a command
    without one. Read from the words themselves, so that it is known before the parser is even imported."""
    command = next((word for word in words if not word.startswith("-")), None)
    if command not in OUTPUT_COLUMNS:
        return None
    for index, word in enumerate(words[:-1]):
        if word == "--out":
            return words[index + 1], OUTPUT_COLUMNS[command]
    out = next((word.removeprefix("--out=") for word in words if word.startswith("--out=")), None)
    return None if out is None else (out, OUTPUT_COLUMNS[command])


@contextlib.contextmanager
def header_on_interrupt(words: Sequence[str]) -> Iterator[None]:
    """On an interrupt before the command began writing the ``--out poses.csv`` that ``words`` ask for, leave the
    header there: a valid, empty table.

    An interrupt once the command has written its header and rows leaves them as they are. Nothing is done for a
    command without a ``poses.csv`` (:func:`poses_out`).
    """
    asked = poses_out(words)
    before = None if asked is None else _file_state(asked[0])
    try:
        yield
    except KeyboardInterrupt:
        if asked is not None and _file_state(asked[0]) in (before, None):  # absent, or an earlier run's
            with contextlib.suppress(OSError):
                write_header(*asked)
        raise


def _missing_input(args: argparse.Namespace) -> bool:
    """Whether a setup, known-poses or sweep file the command names is not there (it says so before any work)."""
    named = [getattr(args, "scene", None), getattr(args, "file", None)]
    named += [args.poses] if isinstance(getattr(args, "poses", None), str) else []  # reproduce's --poses is a count
    return any(isinstance(path, str) and not os.path.isfile(path) for path in named)


def compile_kernels_once(args: argparse.Namespace, report: Callable[[str], None]) -> None:
    """Before a command that runs compiled kernels: compile all of them at once when Numba's cache lacks them.

    The first such command after an install or a change to the sources says so in one line
    (:func:`spotnav.app.kernels.warm_kernels`), and in one more when they are done, with the time it took; every
    later one loads them from the cache.
    """
    if args.command not in KERNEL_COMMANDS or getattr(args, "example", None) or _missing_input(args):
        return  # nothing to compile for, or a missing file the command names at once
    from spotnav.app.kernels import kernels_compiled, warm_kernels  # Numba only where it is needed

    if not kernels_compiled():
        took = warm_kernels(report=report)
        report(f"spotnav: kernels compiled in {took['total']:.0f} s; later commands load them")


def end_stdout_if_left() -> bool:
    """Whether standard output is a pipe whose reader has left (``spotnav ... | head -1``); if so, point it at
    ``/dev/null`` so that nothing more fails on it (Python's recipe, the signal module's "Note on SIGPIPE").

    A broken pipe elsewhere (an ``--out`` FIFO whose reader died) is not this: it stays an error.
    """
    try:
        descriptor = sys.stdout.fileno()
    except (OSError, AttributeError):  # replaced by a stream without a descriptor (a test's capture)
        return False
    poller = select.poll()
    poller.register(descriptor, select.POLLOUT)
    if not any(events & select.POLLERR for _, events in poller.poll(0)):
        return False
    os.dup2(os.open(os.devnull, os.O_WRONLY), descriptor)
    return True
