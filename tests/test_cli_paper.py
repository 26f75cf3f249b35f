"""The real ``smcpilot`` entry point (``python -m lab.cli``) in subprocesses.

All commands are started together by one module fixture (they are independent processes) so the
slow ones overlap; each test then checks its own command's result.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import jsonschema
import pytest

from lab.paper.metrics import METRICS_SCHEMA
from smcpilot.model import CHANNELS

#: end-to-end: the quick tier (`pytest -m "not slow"`) leaves this module to the full suite.
pytestmark = pytest.mark.slow

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
FIGURES = ("states.png", "errors.png", "sliding.png", "inputs.png", "chi_hat.png", "rotor_speeds.png", "chattering.png")
PAPER_OPTIONS = (
    "--controller",
    "--rate-hz",
    "--sigma",
    "--chi-hat0",
    "--literal",
    "--no-disturbance",
    "--duration",
    "--vehicle",
    "--out",
    "--no-figures",
    "--json",
)
HELP_CASES = {
    "top": ((), ("paper", "bench", "--version", "--help")),
    "paper": (("paper",), PAPER_OPTIONS),
    "bench": (("bench",), ("control",)),
    "bench_control": (("bench", "control"), ("--repeat", "--duration")),
}


@dataclass
class Result:
    returncode: int
    stdout: str
    stderr: str


@dataclass
class Cmd:
    args: tuple[str, ...]
    proc: subprocess.Popen | None = None
    result: Result | None = None


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    (d / "unknown-key.toml").write_text("[vehicle]\nmass_kg = 0.5\npropeller_count = 4\n", encoding="utf-8")
    (d / "negative-mass.toml").write_text("[vehicle]\nmass_kg = -1\n", encoding="utf-8")
    return d


@pytest.fixture(scope="module")
def runs(work):
    cmds: dict[str, Cmd] = {
        "main": Cmd(("paper", "--duration", "2", "--json", str(work / "m" / "metrics.json"), "--out", str(work / "figs"))),
        "b3": Cmd(
            (
                "paper",
                "--literal",
                "b3",
                "--controller",
                "adaptive_pid_smc",
                "--duration",
                "0.5",
                "--json",
                str(work / "b3.json"),
                "--out",
                str(work / "b3figs"),
            )
        ),
        "bad_rate": Cmd(("paper", "--rate-hz", "333", "--duration", "0.1", "--no-figures")),
        "bad_literal": Cmd(("paper", "--literal", "nope", "--duration", "0.1", "--no-figures")),
        "bad_duration": Cmd(("paper", "--duration", "-1", "--no-figures")),
        "bad_chi": Cmd(("paper", "--chi-hat0", "-1", "--duration", "0.1", "--no-figures")),
        "bad_vehicle_key": Cmd(("paper", "--vehicle", str(work / "unknown-key.toml"), "--duration", "0.1", "--no-figures")),
        "bad_vehicle_mass": Cmd(("paper", "--vehicle", str(work / "negative-mass.toml"), "--duration", "0.1", "--no-figures")),
        "bad_vehicle_missing": Cmd(("paper", "--vehicle", str(work / "nope.toml"), "--duration", "0.1", "--no-figures")),
        "json_is_dir": Cmd(("paper", "--duration", "0.05", "--controller", "pid_smc", "--no-figures", "--json", str(work))),
        "out_is_file": Cmd(
            ("paper", "--duration", "0.05", "--controller", "pid_smc", "--out", str(work / "negative-mass.toml"))
        ),
    }
    for key, (args, _opts) in HELP_CASES.items():
        cmds[f"help_{key}"] = Cmd(args + ("--help",))
    # run this tree's code even from another cwd, installed or not
    root = str(Path(__file__).resolve().parents[1])
    env = dict(os.environ, MPLBACKEND="Agg")
    env["PYTHONPATH"] = os.pathsep.join([root] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    for c in cmds.values():
        c.proc = subprocess.Popen(
            [sys.executable, "-m", "lab.cli", *c.args],
            cwd=work,  # nothing lands in the repository (default --out is relative)
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
    try:
        for c in cmds.values():
            out, err = c.proc.communicate(timeout=120)
            c.result = Result(c.proc.returncode, out, err)
    finally:
        for c in cmds.values():
            if c.proc.poll() is None:
                c.proc.kill()
                c.proc.communicate()
    return {k: c.result for k, c in cmds.items()}


# -- the main run --------------------------------------------------------------------------------


def test_paper_run_exits_zero(runs):
    r = runs["main"]
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    # the table lists every controller and channel
    for name in ("pid_smc", "adaptive_pid_smc", "sign_smc", "cascade_pid"):
        assert name in r.stdout
    assert "DIVERGED" not in r.stdout
    assert "ideal (unlimited) actuators" in r.stdout  # spec §5: say so


def test_paper_json_validates(runs, work):
    assert runs["main"].returncode == 0, runs["main"].stderr
    path = work / "m" / "metrics.json"  # parent directory created by the command
    doc = json.loads(path.read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator(METRICS_SCHEMA).validate(doc)
    assert set(doc["controllers"]) == {"pid_smc", "adaptive_pid_smc", "sign_smc", "cascade_pid"}
    for entry in doc["controllers"].values():
        assert entry["diverged"] is False
        assert set(entry["channels"]) == set(CHANNELS)
    assert doc["config"]["duration_s"] == 2.0


@pytest.mark.parametrize("name", FIGURES)
def test_paper_figures_are_pngs(runs, work, name):
    assert runs["main"].returncode == 0, runs["main"].stderr
    p = work / "figs" / name
    assert p.is_file()
    data = p.read_bytes()
    assert len(data) > 1000
    assert data.startswith(PNG_MAGIC)
    assert f"{len(FIGURES)} PNG files" in runs["main"].stdout


def test_no_stray_output_in_cwd(runs, work):
    assert runs["main"].returncode == 0
    assert not (work / "out").exists()  # --out was honoured, no default directory created


# -- help ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("key", list(HELP_CASES))
def test_help_exits_zero_and_lists_options(runs, key):
    r = runs[f"help_{key}"]
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""
    assert r.stdout.startswith("usage: ")
    for opt in HELP_CASES[key][1]:
        assert re.search(rf"(?<![\w-]){re.escape(opt)}(?![\w-])", r.stdout), f"{opt} missing from {key} --help"


# -- bad input: exit 2, one line, no traceback -------------------------------------------------


BAD = {
    "bad_rate": "333",
    "bad_literal": "nope",
    "bad_duration": "duration",
    "bad_chi": "chi_hat",
    "bad_vehicle_key": "propeller_count",
    "bad_vehicle_mass": "mass_kg",
    "bad_vehicle_missing": "nope.toml",
}


@pytest.mark.parametrize("key", list(BAD))
def test_bad_input_exits_2_with_one_line(runs, key):
    r = runs[key]
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("smcpilot paper: error: ")
    assert BAD[key] in lines[0]


@pytest.mark.parametrize("key", ["json_is_dir", "out_is_file"])
def test_unwritable_output_path_exits_2_with_one_line(runs, key):
    r = runs[key]
    assert "Traceback" not in r.stderr
    assert r.returncode == 2
    assert r.stderr.strip().splitlines()[-1].startswith("smcpilot paper: error: ")


# -- a diverging run is a result ------------------------------------------------------------------


def test_literal_b3_reports_divergence(runs, work):
    r = runs["b3"]
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    m = re.search(r"DIVERGED at t = ([0-9.]+) s", r.stdout)
    assert m, r.stdout
    t_div = float(m.group(1))
    assert 0.0 < t_div < 0.05
    doc = json.loads((work / "b3.json").read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator(METRICS_SCHEMA).validate(doc)
    entry = doc["controllers"]["adaptive_pid_smc"]
    assert entry["diverged"] is True
    assert entry["diverged_at_s"] == pytest.approx(t_div, abs=1e-3)
    assert list(doc["controllers"]) == ["adaptive_pid_smc"]
    assert doc["config"]["literal_typos"] == ["b3"]
    # figures are still written for a diverged run
    for name in FIGURES:
        assert (work / "b3figs" / name).read_bytes().startswith(PNG_MAGIC)
