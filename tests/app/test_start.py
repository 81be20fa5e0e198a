from __future__ import annotations

import argparse
import os
import signal
from pathlib import Path

import pytest

from spotnav.app import start
from spotnav.files.columns import POSES_COLUMNS, TRACK_COLUMNS


def _header(columns: tuple[str, ...]) -> str:
    return ",".join(columns) + "\n"


def test_the_output_is_read_from_the_words_themselves() -> None:
    assert start.poses_out(["track", "--scene", "s.toml", "v.mkv", "--out", "p.csv"]) == ("p.csv", TRACK_COLUMNS)
    assert start.poses_out(["localize", "--out=d/p.csv", "--scene", "s", "a.png"]) == ("d/p.csv", POSES_COLUMNS)
    assert start.poses_out(["render", "--scene", "s", "--tip", "1", "1", "5", "--out", "f.png"]) is None
    assert start.poses_out(["track", "--out"]) is None and start.poses_out([]) is None


def test_an_interrupt_before_the_output_leaves_its_header(tmp_path: Path) -> None:
    fresh, earlier = tmp_path / "new" / "poses.csv", tmp_path / "earlier.csv"
    earlier.write_text("an earlier run's rows\n")
    for path in (fresh, earlier):
        with pytest.raises(KeyboardInterrupt), start.header_on_interrupt(["track", "v.mkv", "--out", str(path)]):
            raise KeyboardInterrupt
        assert path.read_text() == _header(TRACK_COLUMNS)


def test_an_interrupt_after_the_output_began_leaves_it(tmp_path: Path) -> None:
    path = tmp_path / "poses.csv"
    rows = _header(POSES_COLUMNS) + "a.png,ok,1,2,3,0,0,-1" + "," * 9 + "\n"
    with pytest.raises(KeyboardInterrupt), start.header_on_interrupt(["localize", "a.png", "--out", str(path)]):
        path.write_text(rows)
        raise KeyboardInterrupt
    assert path.read_text() == rows
    other = tmp_path / "other.csv"
    with pytest.raises(RuntimeError), start.header_on_interrupt(["localize", "a.png", "--out", str(other)]):
        raise RuntimeError  # only an interrupt leaves a header
    with pytest.raises(KeyboardInterrupt), start.header_on_interrupt(["render", "--out", str(other)]):
        raise KeyboardInterrupt  # no poses.csv asked for
    assert not other.exists()


def test_sigterm_interrupts_within_the_block_only() -> None:
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), start.terminate_as_interrupt():
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(1000):  # the handler runs between bytecodes: at once
            pass
    assert signal.getsignal(signal.SIGTERM) == before


def test_only_the_commands_with_kernels_compile_them(monkeypatch: pytest.MonkeyPatch) -> None:
    warmed: list[str] = []
    monkeypatch.setattr("spotnav.app.kernels.kernels_compiled", lambda: False)
    monkeypatch.setattr("spotnav.app.kernels.warm_kernels", lambda report: warmed.append("warm") or {"total": 1.0})
    for command, example in [("scene", "thesis"), ("evaluate", None), ("sweep", True), ("sweep-report", None)]:
        start.compile_kernels_once(argparse.Namespace(command=command, example=example), report=print)
    assert warmed == []
    start.compile_kernels_once(argparse.Namespace(command="localize"), report=print)
    assert warmed == ["warm"]


def test_only_a_stdout_whose_reader_left_ends_quietly(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Review: every BrokenPipeError ended with exit 0, also one from an --out FIFO whose reader died (rows lost).
    read_end, write_end = os.pipe()
    with open(write_end, "w", encoding="utf-8") as piped:
        monkeypatch.setattr("sys.stdout", piped)
        assert not start.end_stdout_if_left()  # its reader is still there
        os.close(read_end)
        assert start.end_stdout_if_left()  # gone: stdout now writes to /dev/null
        piped.write("more\n")
        piped.flush()  # no BrokenPipeError
    with (tmp_path / "out.txt").open("w", encoding="utf-8") as file:
        monkeypatch.setattr("sys.stdout", file)
        assert not start.end_stdout_if_left()


def test_a_missing_input_is_said_before_any_compiling(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Review: `spotnav localize --scene typo.toml ...` compiled for a minute before saying the file was missing.
    warmed: list[str] = []
    monkeypatch.setattr("spotnav.app.kernels.kernels_compiled", lambda: False)
    monkeypatch.setattr("spotnav.app.kernels.warm_kernels", lambda report: warmed.append("warm") or {"total": 1.0})
    setup = tmp_path / "setup.toml"
    setup.write_text("")
    missing = str(tmp_path / "typo.toml")
    for named in [{"scene": missing}, {"scene": str(setup), "poses": missing}, {"file": missing}]:
        start.compile_kernels_once(argparse.Namespace(command="calibrate", **named), report=print)
    assert warmed == []
    start.compile_kernels_once(argparse.Namespace(command="reproduce", poses=25), report=print)  # a count
    start.compile_kernels_once(argparse.Namespace(command="localize", scene=str(setup)), report=print)
    assert warmed == ["warm", "warm"]
