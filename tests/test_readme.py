"""README.md tells the truth: its commands exist with the flags it shows, CI runs its test command,
and its pytest example passes."""

from __future__ import annotations

import functools
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest_plugins = ("pytester",)

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def _code_blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README, flags=re.S)


def test_readme_opens_with_install_and_run_and_install_and_test() -> None:
    blocks = _code_blocks("bash")
    assert len(blocks) >= 2
    run, test = (b.strip().splitlines()[-1] for b in blocks[:2])
    assert "pip install -e ." in run and "smcpilot demo" in run
    assert "pip install -e '.[test]'" in test and "pytest" in test


def test_ci_runs_exactly_the_readme_install_and_test_commands() -> None:
    test = _code_blocks("bash")[1].strip().splitlines()[-1]
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    for part in (p.strip() for p in test.split("&&")):
        assert part in ci, f"{part!r} from README is not in .ci/run"


def _smcpilot_invocations() -> list[list[str]]:
    """Every `smcpilot ...` command line in README's code blocks and tables."""
    out = []
    for line in README.splitlines():
        for m in re.finditer(r"(?:\.venv/bin/)?smcpilot ((?:[a-z][a-z-]* ?)+(?:[^`|#&]*))", line):
            words = m.group(1).split("#")[0].replace("…", "").split()
            out.append([w.strip("'\"`,.") if not w.startswith("-") else w.rstrip(",.") for w in words])
    return out


def _help(path: list[str]) -> str:
    return _help_of(tuple(path))


@functools.cache
def _help_of(path: tuple[str, ...]) -> str:
    """``smcpilot PATH --help`` as a user runs it (once per path: README repeats its commands)."""
    r = subprocess.run([sys.executable, "-m", "lab.cli", *path, "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, (path, r.stderr)
    return r.stdout


def test_every_command_and_flag_in_readme_exists() -> None:
    top = _help([])
    checked = 0
    for words in _smcpilot_invocations():
        if not words or words[0] not in top:
            continue
        # The subcommand path: leading words that are subcommands of the previous level.
        path: list[str] = []
        text = top
        for w in words:
            if w.startswith("-") or not re.search(rf"^\s+{re.escape(w)}\b", text, flags=re.M):
                break
            path.append(w)
            text = _help(path)
        for w in words[len(path):]:
            if w.startswith("--"):
                flag = w.split("=", 1)[0]
                assert flag in text, f"README uses `smcpilot {' '.join(path)} {flag}`, which --help does not list"
                checked += 1
    assert checked >= 5, "the README's commands were not found"


def test_option_tables_match_each_commands_help() -> None:
    """Under a ``### `smcpilot X` `` heading, every `--flag` of the table is in `smcpilot X --help`."""
    sections = re.split(r"^### ", README, flags=re.M)[1:]
    checked = 0
    for sec in sections:
        m = re.match(r"`smcpilot ([a-z ]+)`", sec)
        if not m:
            continue
        text = _help(m.group(1).split())
        for flag in re.findall(r"^\| `(--[a-z0-9-]+)", sec, flags=re.M):
            assert flag in text, f"README's table for `smcpilot {m.group(1)}` lists {flag}, which --help does not"
            checked += 1
    assert checked >= 15


@pytest.mark.slow
def test_readme_pytest_example_passes(pytester: pytest.Pytester) -> None:
    examples = [b for b in _code_blocks("python") if "def test_" in b and "(sitl)" in b]
    assert examples, "README has no pytest example"
    pytester.makepyfile(test_readme_example=examples[0])
    result = pytester.runpytest_subprocess(timeout=300)
    result.assert_outcomes(passed=1)


@pytest.mark.slow
def test_readme_client_example_flies(tmp_path: Path) -> None:
    """The README's `Vehicle` example, run against a real lockstep SITL (on a free port)."""
    import socket

    from ground.sitl import Sitl, SitlOptions

    example = next(b for b in _code_blocks("python") if "from ground.client import Vehicle" in b)
    assert "udpin:127.0.0.1:14550" in example
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    opts = SitlOptions.of(lockstep=True, speed=5.0, duration_s=300.0, gcs=f"udp:127.0.0.1:{port}",
                       tlog=tmp_path / "readme.tlog", param_file=tmp_path / "readme.parm")  # fmt: skip
    with Sitl(opts):
        exec(compile(example.replace("udpin:127.0.0.1:14550", f"udpin:127.0.0.1:{port}"), "README.md", "exec"), {})
