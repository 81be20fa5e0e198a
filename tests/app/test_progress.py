from __future__ import annotations

import io

import pytest

from spotnav.app import progress as progress_module
from spotnav.app.progress import PlainProgress, progress


def test_a_log_gets_plain_lines_and_a_last_one(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(progress_module, "LINE_EVERY_S", 0.0)
    stream = io.StringIO()
    bar = PlainProgress(range(4), desc="track", unit="frame", stream=stream)
    assert list(bar) == [0, 1, 2, 3]
    bar.set_postfix_str("500 Hz")
    bar.close()
    lines = stream.getvalue().splitlines()
    assert len(lines) == 5 and "\r" not in stream.getvalue()
    assert lines[0].startswith("track: 1/4 frames (25 %)") and lines[-1].startswith("track: 4/4 frames (100 %)")
    assert lines[-1].endswith(", 500 Hz")


def test_a_short_run_writes_nothing() -> None:
    stream = io.StringIO()
    bar = PlainProgress(total=3, desc="sweep", unit="chunk", initial=1, stream=stream)
    bar.update(2)
    bar.close()
    assert stream.getvalue() == "" and bar.n == 3


def test_not_a_terminal_means_plain_lines(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("sys.stderr", io.StringIO())
    assert isinstance(progress(range(2), desc="x", unit="it"), PlainProgress)
