"""``smcpilot compare``: the study's files, its independence from the number of workers, its errors."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from lab.cli import main
from lab.compare import _ci95, markdown_table, study_cases, summarize_study


def _run(out: Path, jobs: int) -> list[dict[str, str]]:
    rc = main(["compare", "--cases", "motor30-hover", "--controllers", "adaptive,cascade", "--seeds", "2", "--duration", "13",
               "--jobs", str(jobs), "--out", str(out), "--no-plots", "--quiet"])  # fmt: skip
    assert rc == 0
    with (out / "results.csv").open(encoding="utf-8") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_study_files_and_results_do_not_depend_on_the_workers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    one = _run(tmp_path / "one", 1)
    two = _run(tmp_path / "two", 2)
    drop = {"wall_s"}
    assert [{k: v for k, v in r.items() if k not in drop} for r in one] == [{k: v for k, v in r.items() if k not in drop} for r in two]
    assert [(r["case"], r["controller"], r["seed"]) for r in one] == [
        ("motor30-hover", "adaptive", "0"), ("motor30-hover", "adaptive", "1"),
        ("motor30-hover", "cascade", "0"), ("motor30-hover", "cascade", "1"),
    ]  # fmt: skip
    for r in one:  # the fault at 10 s is flown and scored: nobody crashes, recovery is timed from it
        assert r["status"] == "ok" and r["crashed"] == "False" and float(r["fault_start_s"]) == 10.0
    summary = json.loads((tmp_path / "one" / "summary.json").read_text(encoding="utf-8"))
    groups = {(g["case"], g["controller"]): g for g in summary["groups"]}
    assert set(groups) == {("motor30-hover", "adaptive"), ("motor30-hover", "cascade")}
    assert all(g["flights"] == 2 and g["crash_rate"] == 0.0 for g in groups.values())
    table = (tmp_path / "one" / "table.md").read_text(encoding="utf-8")
    assert table.count("| motor30-hover |") == 2
    assert (tmp_path / "one" / "scenarios" / "motor30-hover.toml").is_file()
    assert "| motor30-hover | adaptive | 0/2 |" in capsys.readouterr().out


def test_ci95_is_the_student_t_interval() -> None:
    mean, lo, hi = _ci95([1.0, 2.0, 3.0, None, float("nan")])  # type: ignore[misc]
    # mean 2, s = 1, n = 3: half-width t(0.975, 2) / sqrt(3) = 4.302653 / 1.732051
    assert mean == pytest.approx(2.0)
    assert hi - mean == pytest.approx(4.302653 / 3**0.5, rel=1e-6) and mean - lo == pytest.approx(hi - mean)
    assert _ci95([5.0]) == (5.0, 5.0, 5.0)
    assert _ci95([None, True]) is None


def test_summary_counts_crashes() -> None:
    rows = [{"case": "c", "controller": "x", "crashed": c, "max_tilt_deg": t} for c, t in ((False, 5.0), (True, 120.0))]
    (entry,) = summarize_study(rows)
    assert entry["crash_rate"] == 0.5 and entry["flights"] == 2
    assert entry["max_tilt_deg"]["mean"] == pytest.approx(62.5)
    assert "| c | x | 1/2 |" in markdown_table([entry], [])


def test_every_study_case_is_a_valid_scenario_with_its_event_at_10_s() -> None:
    cases = study_cases()
    assert len({c.name for c in cases}) == len(cases) == 10
    for c in cases:
        assert c.scenario.duration_s == 20.0 and c.scenario.environment.noise
        assert all(t >= 10.0 for t in c.fault_starts_s)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--cases", "nope"], "unknown case 'nope'"),
        (["--controllers", "pid"], "unknown controller 'pid'"),
        (["--seeds", "0"], "--seeds and --jobs must be >= 1"),
        (["--duration", "5"], "--duration must be"),
    ],
)
def test_user_errors_are_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str) -> None:
    assert main(["compare", *argv, "--out", str(tmp_path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
