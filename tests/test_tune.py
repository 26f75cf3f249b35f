"""``smcpilot tune``: a tiny study finds a better value of a deliberately detuned gain, its outputs
load where they are meant to, ``--resume`` continues the journal (a trial a crash left RUNNING
counts as failed), and bad tuning files are one-line errors."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from fc.config import FcConfig
from fc.params import ParamStore
from lab.cli import main
from smcpilot.scenario import Scenario

# hover at 1 m in a 1.1 N wind; the position loop's gain detuned to 0.2 (default 3): the wind pushes it away
TUNE = """
name = "detuned"
seed = 0
seeds = 1
trials = 8
parallel = 1
duration_s = 4.0
score_from_s = 1.5
controllers = ["adaptive_pid_smc"]

[objective]
metric = "iae_pos_m_s"
failure_penalty = 100.0

[[gain]]
name = "PSC_POS_KP"
low = 0.2
high = 6.0
log = true

[scenario]
[scenario.environment]
wind_force_ned_n = [-1.0, 0.5, 0.0]
[scenario.fc.params]
PSC_POS_KP = 0.2

[[scenario.step]]
t_s = 0.0
action = "takeoff"
alt_m = 1.0
"""


def _trials(out: Path) -> list[dict[str, str]]:
    with (out / "trials.csv").open(encoding="utf-8", newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_a_tiny_study_improves_a_detuned_gain_and_resumes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    tune = tmp_path / "tune.toml"
    tune.write_text(TUNE, encoding="utf-8")
    out = tmp_path / "study"
    assert main(["tune", str(tune), "--out", str(out), "--workers", "2", "--quiet"]) == 0
    best = json.loads((out / "best.json").read_text(encoding="utf-8"))
    trials = _trials(out)
    assert len(trials) == 8 and all(t["state"] == "COMPLETE" for t in trials)
    assert float(trials[0]["PSC_POS_KP"]) == 0.2  # trial 0: the scenario's own (detuned) gain
    assert best["baseline_objective"] == pytest.approx(float(trials[0]["objective"]))
    assert best["objective"] < 0.7 * best["baseline_objective"], best  # the study found a clearly better gain
    kp = best["gains"]["PSC_POS_KP"]
    assert 0.2 < kp <= 6.0
    # every flight is in results.csv with its trial and gain
    with (out / "results.csv").open(encoding="utf-8", newline="") as f:
        flights = list(csv.DictReader(f))
    assert len(flights) == 8 and {int(r["trial"]) for r in flights} == set(range(8)) and all(r["status"] == "ok" for r in flights)
    # the .parm file loads into the FC's parameter store, the fragment into a scenario
    store = ParamStore(FcConfig(), out / "best.parm")
    assert store.load() == []
    assert store.value("PSC_POS_KP") == pytest.approx(kp)
    frag = Scenario.from_toml(out / "best.toml")
    assert dict(frag.params) == {"PSC_POS_KP": pytest.approx(kp)}
    assert (out / "history.png").stat().st_size > 10_000
    assert f"PSC_POS_KP = {kp:.4g}" in capsys.readouterr().out

    # a crash leaves a trial RUNNING in the journal; --resume marks it failed and continues the study
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    study = optuna.load_study(study_name="detuned", storage=JournalStorage(JournalFileBackend(str(out / "study.journal"))))
    study.ask()
    assert main(["tune", str(tune), "--out", str(out), "--workers", "1", "--quiet"]) == 2  # no silent overwrite
    assert main(["tune", str(tune), "--out", str(out), "--workers", "1", "--resume", "--trials", "10", "--quiet"]) == 0
    again = _trials(out)
    assert [t["state"] for t in again] == ["COMPLETE"] * 8 + ["FAIL", "COMPLETE"]
    assert again[:8] == trials  # the finished trials kept as they were
    assert json.loads((out / "best.json").read_text(encoding="utf-8"))["objective"] <= best["objective"]


@pytest.mark.parametrize(
    ("old", "new", "words"),
    [
        ('name = "PSC_POS_KP"\nlow', 'name = "PSC_POS_PK"\nlow', ["unknown FC parameter 'PSC_POS_PK'", "did you mean 'PSC_POS_KP'"]),
        ("low = 0.2\nhigh = 6.0", "low = 6.0\nhigh = 6.0", ["empty range"]),
        ("high = 6.0", "high = 60.0", ["leaves the parameter's valid range [0, 20]"]),
        ('metric = "iae_pos_m_s"', 'metric = "iae_pos"', ["unknown metric 'iae_pos'", "did you mean"]),
        ("trials = 8", "trials = 0", ["trials must be a whole number >= 1"]),
    ],
    ids=["gain-typo", "empty-range", "out-of-range", "metric-typo", "no-trials"],
)
def test_bad_tuning_files_are_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], old: str, new: str, words: list[str]) -> None:
    assert old in TUNE
    tune = tmp_path / "tune.toml"
    tune.write_text(TUNE.replace(old, new), encoding="utf-8")
    assert main(["tune", str(tune), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("smcpilot tune: error:"), err
    for w in words:
        assert w in err
    assert not (tmp_path / "out").exists()
