"""``smcpilot run`` owns its output directory: a second run into the same ``--out`` leaves only its
own files there (the first run's figures, log, scenario and results are gone), and never touches a
file it did not write. In-process flights of a few simulated seconds."""

from __future__ import annotations

from pathlib import Path

import pytest

from lab.cli import main
from lab.run import RUN_FILES

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "examples" / "scenarios"


def _files(d: Path) -> set[str]:
    return {p.name for p in d.iterdir() if p.is_file()}


def test_a_second_run_into_the_same_out_leaves_only_its_own_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n", encoding="utf-8")  # the user's: never ours to delete
    assert main(["run", str(SCENARIOS / "motor-loss.toml"), "--out", str(out), "--duration", "2", "--json", str(out / "first.json"), "--quiet"]) == 0
    first = _files(out)
    assert {"motor-loss.tlog", "motor-loss.scenario.toml", "controller.png", "first.json", RUN_FILES} <= first, first

    assert main(["run", str(SCENARIOS / "step-yaw.toml"), "--out", str(out), "--duration", "2", "--controller", "cascade_pid"]) == 0
    second = _files(out)
    assert "deleted the previous run's" in capsys.readouterr().out
    ours = second - {"notes.txt", RUN_FILES}
    assert ours == {"step-yaw.tlog", "step-yaw.scenario.toml", "position.png", "attitude.png", "motors.png", "track.png"}, second
    assert "controller.png" not in second  # the cascade has no sigma or chi_hat: the adaptive run's figure must not pass for its own
    assert (out / "notes.txt").read_text(encoding="utf-8") == "mine\n"
    assert sorted((out / RUN_FILES).read_text(encoding="utf-8").split()) == sorted(ours)


def test_the_list_never_reaches_outside_the_directory(tmp_path: Path) -> None:
    from lab.run import clear_previous_run

    out = tmp_path / "out"
    out.mkdir()
    outside = tmp_path / "precious.txt"
    outside.write_text("x", encoding="utf-8")
    (out / "a.png").write_text("x", encoding="utf-8")
    (out / RUN_FILES).write_text("a.png\n../precious.txt\n/etc/hostname\nmissing.tlog\n", encoding="utf-8")
    assert [p.name for p in clear_previous_run(out)] == ["a.png"]
    assert outside.exists() and not (out / RUN_FILES).exists()
    assert clear_previous_run(out) == []  # nothing listed: nothing deleted
