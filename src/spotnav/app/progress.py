"""Progress of long runs on stderr: a tqdm bar on a terminal, plain lines in a log.

On a terminal, :func:`progress` is tqdm's bar. Elsewhere (a log file, CI, a
pipe) a bar's carriage returns make one unreadable line, so it writes a plain
line instead, at most every :data:`LINE_EVERY_S` seconds, and a last one when
the run ends; a run shorter than that writes nothing.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator, Sized
from typing import Any, TextIO

from tqdm import tqdm

__all__ = ["LINE_EVERY_S", "PlainProgress", "progress"]

LINE_EVERY_S = 10.0


class PlainProgress:
    """A progress report in plain lines, with the part of tqdm's interface spotnav uses.

    Parameters
    ----------
    iterable : iterable, optional
    desc, unit : str
    total : int, optional
        Default: ``len(iterable)`` when it has one.
    initial : int
        Steps done before.
    stream : file
        Where the lines go (stderr).
    """

    def __init__(
        self,
        iterable: Iterable[Any] | None = None,
        *,
        desc: str = "",
        unit: str = "it",
        total: int | None = None,
        initial: int = 0,
        stream: TextIO | None = None,
    ) -> None:
        self.iterable = iterable
        self.desc, self.unit = desc, unit
        self.total = total if total is not None else (len(iterable) if isinstance(iterable, Sized) else None)
        self.n = initial
        self._initial = initial
        self._postfix = ""
        self._stream = stream or sys.stderr
        self._start = self._last = time.monotonic()
        self._lines = 0

    def __iter__(self) -> Iterator[Any]:
        if self.iterable is None:
            return
        for item in self.iterable:
            yield item
            self.update()

    def update(self, n: int = 1) -> None:
        """Count ``n`` more steps; write a line if the last one is old enough."""
        self.n += n
        now = time.monotonic()
        if now - self._last >= LINE_EVERY_S:
            self._write(now)

    def set_postfix_str(self, text: str) -> None:
        """Text to put after the counts."""
        self._postfix = text

    def close(self) -> None:
        """Write the last line, if any line was written."""
        if self._lines:
            self._write(time.monotonic())

    def _write(self, now: float) -> None:
        elapsed = now - self._start
        done = f"{self.n}/{self.total}" if self.total else str(self.n)
        share = f" ({100 * self.n / self.total:.0f} %)" if self.total else ""
        rate = (self.n - self._initial) / elapsed if elapsed > 0 else 0.0
        tail = f", {self._postfix}" if self._postfix else ""
        print(f"{self.desc}: {done} {self.unit}s{share}, {rate:.1f} {self.unit}/s, {elapsed:.0f} s{tail}",
              file=self._stream, flush=True)  # fmt: skip
        self._last = now
        self._lines += 1


def progress(
    iterable: Iterable[Any] | None = None,
    *,
    desc: str,
    unit: str,
    total: int | None = None,
    initial: int = 0,
    leave: bool = True,
) -> tqdm[Any] | PlainProgress:
    """A progress bar on a terminal (stderr), plain lines otherwise (see the module's docstring)."""
    if sys.stderr.isatty():
        return tqdm(iterable, desc=desc, unit=unit, total=total, initial=initial, leave=leave)
    return PlainProgress(iterable, desc=desc, unit=unit, total=total, initial=initial)
