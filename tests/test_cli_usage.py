"""Every usage error of every ``smcpilot`` subcommand, at every depth, is one line and exit 2.

The parsers are walked as ``lab.cli.build_parser`` builds them: each one is given an option it
does not have (after the positionals and required options it needs, so the unknown option is what
it meets), and every argument with choices (a subcommand name, ``--plant``, ...) a value that is
not one of them. The line names the subcommand whose parser found the error, as
``smcpilot SUBCOMMAND: error: ...``; argparse's usage block is never printed.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from lab.cli import CliParser, build_parser, main

ROOT = Path(__file__).resolve().parents[1]


def _parsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, (*path, name))


def _is_leaf(parser: argparse.ArgumentParser) -> bool:
    return not any(isinstance(a, argparse._SubParsersAction) for a in parser._actions)


def _required(parser: argparse.ArgumentParser) -> list[str]:
    """Values for the parser's positionals and required options, so that parsing gets past them."""
    args: list[str] = []
    for a in parser._actions:
        if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        value = str(sorted(a.choices)[0]) if a.choices else "1"
        if not a.option_strings:
            if a.nargs in ("?", "*"):
                continue
            count = a.nargs if isinstance(a.nargs, int) else 1
            args += [value] * count
        elif a.required:
            args += [a.option_strings[0], value]
    return args


PARSERS = list(_parsers(build_parser()))
IDS = [" ".join(p) or "smcpilot" for p, _ in PARSERS]


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as info:
        main(argv)
    out, err = capsys.readouterr()
    assert info.value.code == 2, (argv, out, err)
    assert out == "", (argv, out)
    assert "usage:" not in err and "Traceback" not in err, (argv, err)
    lines = err.splitlines()
    assert len(lines) == 1, (argv, err)
    return lines[0]


def test_the_walk_finds_every_subcommand_at_every_depth() -> None:
    names = set(IDS)
    for expected in ("smcpilot", "run", "sitl", "demo", "gcs", "gcs param get", "gcs mission upload", "campaign run", "campaign replay",
                     "log summary", "log clean", "bench control", "mission run", "laws", "tune", "paper", "plot", "compare"):  # fmt: skip
        assert expected in names, expected
    assert all(isinstance(p, CliParser) for _, p in PARSERS)  # every subparser has the one-line error


@pytest.mark.parametrize(("path", "parser"), PARSERS, ids=IDS)
def test_an_unknown_option_is_one_line_naming_the_subcommand(path: tuple[str, ...], parser: argparse.ArgumentParser,
                                                            capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    if not _is_leaf(parser):
        # A group (gcs, campaign, log, ...): the unknown option before its subcommand is the group's.
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        first = next(iter(sub.choices))
        argv = [*path, "--no-such-option", first, *_required(sub.choices[first])]
    else:
        argv = [*path, *_required(parser), "--no-such-option"]
    line = _run(argv, capsys)
    prog = " ".join(("smcpilot", *path))
    assert line.startswith(f"{prog}: error: unrecognized arguments: --no-such-option"), line
    assert f"`{prog} --help`" in line


CHOICES = [(path, parser, a) for path, parser in PARSERS for a in parser._actions
           if a.choices and not isinstance(a, argparse._HelpAction)]  # fmt: skip


@pytest.mark.parametrize(("path", "parser", "action"), CHOICES, ids=[" ".join((*p, a.dest)) for p, _, a in CHOICES])
def test_a_bad_choice_is_one_line_naming_the_subcommand(path: tuple[str, ...], parser: argparse.ArgumentParser, action: argparse.Action,
                                                       capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    if isinstance(action, argparse._SubParsersAction):
        argv = [*path, "no-such-choice"]
    else:
        others = [a for a in parser._actions if a is not action]
        rest: list[str] = []
        for a in others:
            if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            value = str(sorted(a.choices)[0]) if a.choices else "1"
            if not a.option_strings and a.nargs not in ("?", "*"):
                rest += [value] * (a.nargs if isinstance(a.nargs, int) else 1)
            elif a.option_strings and a.required:
                rest += [a.option_strings[0], value]
        if action.option_strings:
            argv = [*path, *rest, action.option_strings[0], "no-such-choice"]
        else:
            argv = [*path, "no-such-choice", *rest]
    line = _run(argv, capsys)
    prog = " ".join(("smcpilot", *path))
    assert line.startswith(f"{prog}: error: "), line
    assert "invalid choice: 'no-such-choice'" in line, line


@pytest.mark.parametrize(
    ("argv", "start"),
    [
        (["run", "examples/scenarios/hover.toml", "--controller", "nosuch"], "smcpilot run: error: argument --controller/--law: unknown controller 'nosuch'"),
        (["sitl", "--bogus"], "smcpilot sitl: error: unrecognized arguments: --bogus"),
        (["gcs", "status", "--bogus"], "smcpilot gcs status: error: unrecognized arguments: --bogus"),
    ],
    ids=["run-bad-law", "sitl-unknown-option", "gcs-status-unknown-option"],
)
def test_as_a_user_sees_it(argv: list[str], start: str) -> None:
    """The real command in a new process: one line on stderr, nothing on stdout, exit 2."""
    r = subprocess.run([sys.executable, "-m", "lab.cli", *argv], cwd=ROOT, capture_output=True, text=True, timeout=60, check=False)
    assert r.returncode == 2 and r.stdout == "", (r.stdout, r.stderr)
    assert r.stderr.count("\n") == 1 and r.stderr.startswith(start), r.stderr
