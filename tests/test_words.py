"""Words and units a new user reads (issue 23): one name per quantity with its window where two
windows exist, units on every table column, "crashed" for the vehicle and "error" for the software,
no "nan" for a value that does not exist yet, small samples flagged, connection hints that are true
for the port given."""

from __future__ import annotations

import io
import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from lab.campaign.figures import until_crash, write_worst_figure
from lab.campaign.flight import Trace
from lab.campaign.run import Progress
from lab.campaign.summary import markdown_table, summarize


# -- crashed (the vehicle) and error (the software) ------------------------------------------------
def _rows(statuses: list[str], group: str = "g", ctrl: str = "c", value: float = 1.0) -> list[dict]:
    return [{"group": group, "controller": ctrl, "status": s, "crashed": s in ("crashed", "diverged"), "max_tilt_deg": value + i}
            for i, s in enumerate(statuses)]  # fmt: skip


def test_the_tables_say_crashed_and_count_errors_apart() -> None:
    table = markdown_table(summarize(_rows(["ok", "crashed", "diverged", "error", "timed out", "ok"])))
    head, _, row = table.splitlines()[:3]
    assert "| crashed | errors |" in head and "failed" not in table
    assert row.startswith("| g | c | 2/6 | 2/6 |"), row
    quiet = markdown_table(summarize(_rows(["ok"] * 6)))
    assert "| crashed |" in quiet.splitlines()[0] and "errors" not in quiet  # the column only when there are errors


def test_the_progress_line_says_crashed_and_errors_never_failed() -> None:
    p = Progress(4, quiet=True)
    for status in ("ok", "crashed", "error", "diverged"):
        p.update({"status": status, "crashed": status in ("crashed", "diverged")})
    line = p.line(p.t0 + 1.0)
    assert "2 crashed, 1 error," in line and "failed" not in line, line


def test_summary_json_counts_crashes_and_errors() -> None:
    (entry,) = summarize(_rows(["ok", "crashed", "error", "ok"]))
    assert (entry["crashes"], entry["errors"], entry["crash_rate"], entry["error_rate"]) == (1, 1, 0.25, 0.25)
    assert "failures" not in entry and "failure_rate" not in entry


# -- small samples ----------------------------------------------------------------------------------
def test_a_table_of_two_seeds_says_its_intervals_are_rough_and_marks_the_wide_ones() -> None:
    rows = [{"group": "g", "controller": "c", "status": "ok", "recover_s": v} for v in (10.0, 300.0)]
    table = markdown_table(summarize(rows), metrics=(("recover_s", "recover s"),))
    assert "† |" in table.splitlines()[2]  # 155 ± 1842: wider than the mean
    notes = [ln for ln in table.splitlines() if ln.startswith("Note:")]
    assert any("Only 2 flights per row" in n for n in notes) and any("1 cell: the interval is wider than the mean" in n for n in notes), table
    many = [{"group": "g", "controller": "c", "status": "ok", "recover_s": 10.0 + 0.1 * i} for i in range(8)]
    assert "Note:" not in markdown_table(summarize(many), metrics=(("recover_s", "recover s"),))


# -- one label, one meaning -------------------------------------------------------------------------
def test_the_summary_names_the_window_of_each_max_position_error() -> None:
    from ground.logs.summary import print_summary

    summary = {
        "log": "x.tlog", "records": 1, "lockstep": True, "duration_s": 10.0, "armed_time_s": 9.0, "settle_s": 8.0,
        "settled_time_s": 3.0, "position_error_final_m": 0.003, "position_error_rms_m": 0.002, "position_error_max_m": 0.00501,
        "yaw_error_final_deg": 0.1, "yaw_error_rms_deg": 0.05,
        "metrics": {"flight_time_s": 9.0, "armed_time_s": 9.0, "iae_pos_m_s": 1.0, "ise_pos_m2_s": 1.0, "itae_pos_m_s2": 1.0,
                    "max_pos_err_m": 5.1, "crashed": False},
    }  # fmt: skip
    buf = io.StringIO()
    print_summary(summary, buf)
    text = buf.getvalue()
    assert "settled max 0.00501 m" in text and "in-flight max 5.1 m" in text, text
    assert not re.search(r"[ ,]max \d", text.replace("settled max", "").replace("in-flight max", "")), text


def test_the_paper_table_has_a_unit_on_every_column() -> None:
    from lab.paper.report import print_table

    ch = {"t_sigma_below_0p01_s": 0.34, "t_err_below_0p01_s": 3.59, "err_final": -2.53e-3, "overshoot": 0.037, "max_abs_u": 0.08,
          "total_variation_u": 0.30, "chi_hat_final": 0.61}  # fmt: skip
    metrics = {"controllers": {"adaptive_pid_smc": {"channels": {c: dict(ch) for c in ("phi", "theta", "psi", "z")}, "diverged": False,
                                                    "min_omega_sq_over_hover": 0.5}}}  # fmt: skip
    buf = io.StringIO()
    print_table(metrics, {"adaptive_pid_smc": 1.0}, 15.0, buf)
    lines = buf.getvalue().splitlines()
    assert "t|σ|<.01 s" in lines[0] and "t|e|<.01 s" in lines[0]
    phi, _, psi, z = lines[2:6]
    assert "-2.53e-03 rad" in phi and "0.08 N" in phi and "0.610 rad/s²" in phi
    assert "0.08 N·m" in psi and "-2.53e-03 m" in z and "0.610 m/s²" in z


# -- where to connect ------------------------------------------------------------------------------
@pytest.mark.parametrize(("gcs", "says"), [("udp:127.0.0.1:14550", "QGroundControl listens there by default"),
                                           ("udp:127.0.0.1:14560", "QGroundControl listens on 14550 by default: add a UDP comm link on port 14560")])  # fmt: skip
def test_the_qgroundcontrol_hint_is_true_for_the_port_given(gcs: str, says: str) -> None:
    from ground.sitl import print_connect_help

    opts = SimpleNamespace(lockstep=False, speed=None, gcs=gcs, signing_key=None, scenario=SimpleNamespace(controller="adaptive_pid_smc", plant="rigid-body"))
    buf = io.StringIO()
    print_connect_help(SimpleNamespace(options=opts, tlog=Path("x.tlog"), gcs_address=None, fcs=[None], tlogs=[Path("x.tlog")], sysids=[1], router=None), buf)  # type: ignore[arg-type]
    text = buf.getvalue()
    assert says in text, text
    if not gcs.endswith("14550"):
        assert "listens there by default" not in text


def test_the_top_level_help_names_every_log_subcommand(capsys: pytest.CaptureFixture[str]) -> None:
    from lab.cli import main

    with pytest.raises(SystemExit):
        main(["--help"])
    log_line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith("log "))
    assert all(w in log_line for w in ("summary", "compress", "clean")), log_line


def test_no_example_speaks_of_an_issue_number() -> None:
    root = Path(__file__).resolve().parents[1] / "examples"
    hits = [f"{p.relative_to(root)}: {ln.strip()}" for p in root.rglob("*") if p.is_file() and p.suffix in (".toml", ".py", ".md")
            for ln in p.read_text(encoding="utf-8").splitlines() if re.search(r"\bissue[- ]?\d", ln, flags=re.I)]  # fmt: skip
    assert not hits, hits


# -- the worst runs' figure ---------------------------------------------------------------------------
def test_a_crashed_run_is_drawn_up_to_its_crash(tmp_path: Path) -> None:
    t = [0.01 * k for k in range(1000)]
    trace = Trace(t, [0.1 if x < 5.0 else 10.0 * x for x in t], [5.0 if x < 5.0 else 170.0 for x in t])
    row = {"unit": 3, "controller": "c", "group": "g", "seed_index": 0, "status": "crashed", "crashed": True, "crash_t_s": 5.0}
    tt, err, tilt, t_crash = until_crash(row, trace)
    assert t_crash == 5.0 and tt[-1] == pytest.approx(5.0) and len(tt) == len(err) == len(tilt) == 501
    assert until_crash({**row, "crashed": False, "status": "ok"}, trace)[0] == t  # not crashed: the whole flight
    ok = {**row, "unit": 4, "status": "ok", "crashed": False}
    path = write_worst_figure([(row, trace), (ok, Trace(t, [0.1] * len(t), [5.0] * len(t)))], tmp_path / "worst_runs.png")
    assert path.stat().st_size > 10_000
