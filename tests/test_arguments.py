"""The command line's help is the reference: it agrees with the README's synopsis, describes every argument and its
default, and reads as plain text wrapped between words."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from spotnav import arguments
from spotnav.app import igtl
from spotnav.arguments import DESCRIPTION, build_parser
from spotnav.experiments import EXPERIMENTS
from spotnav.pose.conefit.parameters import PARAMETER_GROUPS
from spotnav.pose.localize import DEFAULT_METHOD, METHODS

README = Path(__file__).parents[1] / "README.md"
_OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    (commands,) = (action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
    return dict(commands.choices)


def _arguments(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [action for action in parser._actions if not isinstance(action, argparse._HelpAction)]


def _readme_synopsis(text: str) -> dict[str, str]:
    """Each subcommand's synopsis in the README's "Every command and its options" block: its lines joined, comments
    left out."""
    block = text.split("Every command and its options:", 1)[1].split("```sh\n", 1)[1].split("```", 1)[0]
    synopsis: dict[str, str] = {}
    command = None
    for line in block.splitlines():
        words = re.split(r"\s#", line, maxsplit=1)[0]
        if line.startswith("spotnav "):
            command = words.split()[1]
            synopsis[command] = synopsis.get(command, "") + " " + words
        elif line[:1].isspace() and command is not None:
            synopsis[command] += " " + words
        else:
            command = None  # another tool's line (make)
    return synopsis


def _options(parser: argparse.ArgumentParser) -> set[str]:
    return {name for action in _arguments(parser) for name in action.option_strings if name.startswith("--")}


def _differences(synopsis: str, parser: argparse.ArgumentParser) -> dict[str, list[str]]:
    """Where a subcommand's README synopsis and its --help differ: options on one side only, and positionals whose
    name (or one of whose choices) the synopsis lacks. Empty when they agree."""
    in_help, in_readme = _options(parser), set(_OPTION.findall(synopsis))
    positionals = []
    for action in _arguments(parser):
        if not action.option_strings:  # a positional: its metavar (or one of its choices) in the synopsis
            names = [str(action.metavar or action.dest), *map(str, action.choices or ())]
            if not any(word.lower() in synopsis.lower() for word in names):
                positionals.append(names[0])
    differences = {"help only": sorted(in_help - in_readme) + positionals, "README only": sorted(in_readme - in_help)}
    return {side: names for side, names in differences.items() if names}


def test_the_readme_synopsis_has_every_subcommand() -> None:
    # Issue 61: README and --help agree on every option of every subcommand, sweep-report's among them.
    assert sorted(_readme_synopsis(README.read_text(encoding="utf-8"))) == sorted(_subcommands())
    assert {"sweep-report", "sweep", "design", "track", "localize"} <= set(_subcommands())


@pytest.mark.parametrize("command", sorted(_subcommands()))
def test_every_option_in_help_is_in_the_readme_synopsis_and_the_other_way_round(command: str) -> None:
    synopsis = _readme_synopsis(README.read_text(encoding="utf-8"))
    assert _differences(synopsis.get(command, ""), _subcommands()[command]) == {}


def test_the_synopsis_reader_sees_a_missing_option() -> None:
    # The comparison above can fail: a synopsis without one of bench's options differs from bench's help.
    text = README.read_text(encoding="utf-8").replace(" [--memory-mb 4096]", "", 1)
    assert "--memory-mb" not in _readme_synopsis(text)["bench"]
    assert _differences(_readme_synopsis(text)["bench"], _subcommands()["bench"]) == {"help only": ["--memory-mb"]}


def test_an_option_that_help_gains_is_missed_by_the_readme() -> None:
    # Issue 61: `sweep-report --out` was said to be in --help but not in the README. An option added to
    # sweep-report's parser without the README, or a positional renamed, is a difference.
    synopsis = _readme_synopsis(README.read_text(encoding="utf-8"))["sweep-report"]
    parser = _subcommands()["sweep-report"]
    parser.add_argument("--out", help="another folder")
    assert _differences(synopsis, parser) == {"help only": ["--out"]}
    renamed = argparse.ArgumentParser()
    renamed.add_argument("folder", metavar="RESULTS")
    assert _differences(synopsis, renamed) == {"help only": ["RESULTS"]}
    assert _differences(synopsis + " [--quiet]", _subcommands()["sweep-report"]) == {"README only": ["--quiet"]}


def _help_text(action: argparse.Action) -> str:
    text = action.help or ""
    return text % {"default": action.default} if "%(" in text else text


def _shown(value: object) -> list[str]:
    """How a default may be written in a help text: 100.0 as 100, a list as its items."""
    if isinstance(value, list):
        return [" ".join(map(str, value))]
    if isinstance(value, float):
        return [f"{value:g}", str(value)]
    return [str(value)]


def test_every_argument_has_a_description_and_states_its_default() -> None:
    missing = []
    for name, parser in {"spotnav": build_parser(), **_subcommands()}.items():
        for action in _arguments(parser):
            label = f"{name} {'/'.join(action.option_strings) or action.dest}"
            text = _help_text(action)
            if not text.strip():
                missing.append(f"{label}: no description")
            default = action.default
            if default is None or default is False or default is argparse.SUPPRESS:
                continue
            if "default" not in text or not any(shown in text for shown in _shown(default)):
                missing.append(f"{label}: default {default!r} not stated")
    assert missing == []


@pytest.mark.parametrize("columns", [50, 80, 120])
def test_help_is_plain_text_wrapped_between_words(columns: int, monkeypatch: pytest.MonkeyPatch) -> None:
    # Every description reads whole in --help at any terminal width: no word or hyphenated option split across
    # lines, no reStructuredText markup.
    monkeypatch.setenv("COLUMNS", str(columns))
    parser = build_parser()
    pages = {"spotnav": (parser.format_help(), [DESCRIPTION])}
    for name, sub in _subcommands().items():
        pages[name] = (sub.format_help(), [_help_text(action) for action in _arguments(sub)])
    for name, (page, texts) in pages.items():
        flowing = " ".join(page.split())
        for text in texts:
            assert " ".join(text.split()) in flowing, (name, text)
        assert not re.search(r"``|:(func|mod|class|data):", page), name
    assert "(default 100)" in " ".join(_subcommands()["render"].format_help().split())


def test_evaluate_help_names_both_truth_files() -> None:
    page = " ".join(_subcommands()["evaluate"].format_help().split())
    assert "truth.csv" in page and "frame.json" in page


def test_the_parser_offers_the_names_the_library_defines() -> None:
    # The parser imports the standard library only, so it writes the names out: they must be the library's.
    assert arguments.METHODS == tuple(METHODS) and arguments.DEFAULT_METHOD == DEFAULT_METHOD
    assert arguments.PARAMETER_GROUPS == tuple(PARAMETER_GROUPS)
    assert arguments.EXPERIMENTS == tuple(EXPERIMENTS)
    assert (arguments.DEFAULT_PORT, arguments.DEFAULT_HOST, arguments.DEFAULT_DEVICE) == (
        igtl.DEFAULT_PORT,
        igtl.DEFAULT_HOST,
        igtl.DEFAULT_DEVICE,
    )
    assert arguments.DEFAULT_STALE_S == igtl.DEFAULT_STALE_S


def test_the_parser_takes_those_names(capsys: pytest.CaptureFixture[str]) -> None:
    parser = arguments.build_parser()
    calibrate = ["calibrate", "--scene", "s.toml", "--poses", "k.csv", "--out", "c.toml"]
    assert parser.parse_args([*calibrate, "--fit", "focal-length"]).fit == ["focal-length"]
    assert parser.parse_args(["reproduce", "--only", "mismatch"]).only == ["mismatch"]
    assert parser.parse_args(["track", "--scene", "s", "v.mkv", "--out", "p", "--igtl"]).igtl == igtl.DEFAULT_PORT
    with pytest.raises(SystemExit):
        parser.parse_args(["localize", "--scene", "s", "--method", "nope", "f.png", "--out", "p"])
    assert "invalid choice" in capsys.readouterr().err


def test_options_are_spelt_out(capsys: pytest.CaptureFixture[str]) -> None:
    # Review: `--ou x.csv` was --out to argparse, but not to the start, which reads --out from the words to leave a
    # header on an interrupt.
    with pytest.raises(SystemExit):
        build_parser().parse_args(["localize", "--scene", "s.toml", "a.png", "--ou", "p.csv"])
    error = capsys.readouterr().err
    assert "required: --out" in error or "unrecognized arguments: --ou" in error, error
