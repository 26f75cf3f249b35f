"""``smcpilot campaign``: a small campaign on a local Dask cluster, the same results with 1 and 2
workers, resume after a real Ctrl-C, a hang recorded as timed out, a worker that dies, a campaign on
a scheduler and worker started here, replay, and the one-line errors."""

from __future__ import annotations

import contextlib
import csv
import json
import logging
import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lab.campaign.engine import ClusterOptions, Engine
from lab.campaign.results import read_rows
from lab.campaign.spec import load_campaign
from lab.campaign.units import Unit, expand, scenario_seed
from lab.cli import main
from smcpilot.scenario import Scenario

ROOT = Path(__file__).resolve().parents[1]

SMALL = """
name = "small"
seed = 3
seeds = 3
duration_s = 1.5
score_from_s = 0.5
controllers = ["adaptive_pid_smc", "cascade_pid"]

[scenario]
[scenario.environment]
noise = true

[[scenario.step]]
t_s = 0.0
action = "takeoff"
alt_m = 1.0

[[vary]]
field = "plant.mass_kg"
dist = "uniform"
low = 1.0
high = 1.2
relative = true

[[vary]]
field = "environment.wind_force_ned_n[0]"
dist = "normal"
mean = 0.0
std = 0.3

[[vary]]
field = "environment.gust_std_n"
grid = [0.0, 0.4]
"""


def _write(tmp_path: Path, text: str, name: str = "c.toml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def _rows(out: Path) -> list[dict[str, str]]:
    """The complete rows of results.csv as text (a last line an interrupt cut short is not one)."""
    with (out / "results.csv").open(encoding="utf-8", newline="") as f:
        return [r for r in csv.DictReader(f) if None not in r.values() and None not in r]


def _strip(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    return sorted(({k: v for k, v in r.items() if k != "wall_s"} for r in rows), key=lambda r: int(r["unit"]))


@pytest.mark.slow
def test_small_campaign_on_a_local_cluster_is_the_same_with_one_and_two_workers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    camp = _write(tmp_path, SMALL)
    assert main(["campaign", "run", str(camp), "--out", str(tmp_path / "one"), "--workers", "1", "--quiet", "--no-plots"]) == 0
    assert main(["campaign", "run", str(camp), "--out", str(tmp_path / "two"), "--workers", "2", "--quiet", "--worst", "3"]) == 0
    one, two = _rows(tmp_path / "one"), _rows(tmp_path / "two")
    assert len(one) == len(two) == 12  # 2 groups × 2 controllers × 3 seeds
    assert _strip(one) == _strip(two)  # every sampled value, seed, metric and status, whatever the workers
    by_unit = {int(r["unit"]): r for r in one}
    assert sorted(by_unit) == list(range(12))
    for r in one:
        assert r["status"] == "ok" and r["crashed"] == "False" and float(r["sim_s"]) == pytest.approx(1.5)
        assert 1.0 * 0.5 <= float(r["plant.mass_kg"]) and float(r["environment.gust_std_n"]) in (0.0, 0.4)
    # seed index s: the same draws for every controller and group (paired), different across s
    for s in range(3):
        same = [r for r in one if r["seed_index"] == str(s)]
        assert len({(r["seed"], r["plant.mass_kg"], r["environment.wind_force_ned_n[0]"]) for r in same}) == 1
        assert same[0]["seed"] == str(scenario_seed(3, s))
    assert len({r["seed"] for r in one}) == 3 and len({r["plant.mass_kg"] for r in one}) == 3
    # the controllers differ in flight, not only in name
    assert by_unit[0]["iae_pos_m_s"] != by_unit[3]["iae_pos_m_s"]
    summary = json.loads((tmp_path / "two" / "summary.json").read_text(encoding="utf-8"))
    groups = {(g["group"], g["controller"]): g for g in summary["groups"]}
    assert set(groups) == {(f"environment.gust_std_n={g}", c) for g in ("0", "0.4") for c in ("adaptive_pid_smc", "cascade_pid")}
    assert all(g["flights"] == 3 and g["crash_rate"] == g["error_rate"] == 0.0 for g in groups.values())
    worst = (tmp_path / "two" / "worst.md").read_text(encoding="utf-8")
    assert worst.count("smcpilot campaign replay") == 3
    figs = sorted(p.name for p in (tmp_path / "two" / "figures").iterdir())
    assert "worst_runs.png" in figs and "ecdf_max_pos_err_m.png" in figs and "box_iae_pos_m_s.png" in figs
    out = capsys.readouterr().out
    assert "| environment.gust_std_n=0.4 | cascade_pid | 0/3 |" in out and f"smcpilot campaign replay {tmp_path / 'two'} " in out

    # replay: the unit flown again in this process gives its row exactly, and writes its tlog
    unit = json.loads(json.dumps(int(one[7]["unit"])))
    assert main(["campaign", "replay", str(tmp_path / "one"), str(unit), "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "gives the unit's results.csv row exactly" in out
    tlog = tmp_path / "one" / "replay" / f"unit-{unit}" / f"unit-{unit}.tlog"
    assert tlog.stat().st_size > 10_000
    from ground.logs import load_log

    log = load_log(tlog)
    assert log.has_smc and float(log.alt_m[-1]) > 0.3  # the take-off was flown and logged


def test_sampled_values_follow_their_distributions(tmp_path: Path) -> None:
    camp = _write(tmp_path, SMALL.replace("seeds = 3", "seeds = 400").replace("grid = [0.0, 0.4]", "grid = [0.0]")
                  .replace('controllers = ["adaptive_pid_smc", "cascade_pid"]', 'controllers = ["cascade_pid"]'))  # fmt: skip
    spec = load_campaign(camp)
    units = expand(spec)
    mass = np.array([dict(u.values)["plant.mass_kg"] for u in units]) / spec.base.vehicle.mass_kg
    wind = np.array([u.scenario.environment.wind_force_ned_n[0] for u in units])
    assert 1.0 <= mass.min() and mass.max() <= 1.2 and abs(mass.mean() - 1.1) < 0.01
    assert abs(wind.mean()) < 0.05 and abs(wind.std() - 0.3) < 0.03
    assert all(u.scenario.vehicle == spec.base.vehicle for u in units)  # plant.*: the FC keeps its model
    assert all(u.plant_vehicle is not None and u.plant_vehicle.mass_kg == pytest.approx(m * spec.base.vehicle.mass_kg) for u, m in zip(units, mass))


@pytest.mark.slow
def test_resume_after_ctrl_c_flies_only_the_missing_units(tmp_path: Path) -> None:
    camp = _write(tmp_path, SMALL.replace("seeds = 3", "seeds = 8").replace("duration_s = 1.5", "duration_s = 3.0"))
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "lab.cli", "campaign", "run", str(camp), "--out", str(out), "--workers", "1", "--quiet",
                             "--no-plots"], cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(read_rows(out / "results.csv")) < 3:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C: the whole foreground group, workers too
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, err.decode()
    before = _rows(out)
    assert 3 <= len(before) < 32, "the interrupt came too late to test anything"
    assert main(["campaign", "run", str(camp), "--out", str(out), "--workers", "1", "--quiet", "--no-plots"]) == 2  # no silent overwrite
    assert main(["campaign", "run", str(camp), "--out", str(out), "--workers", "2", "--resume", "--quiet", "--no-plots"]) == 0
    after = _rows(out)
    assert after[: len(before)] == before  # nothing finished was lost or flown twice
    assert sorted(int(r["unit"]) for r in after) == list(range(32))
    # the resumed half equals a run in one go
    assert main(["campaign", "run", str(camp), "--out", str(tmp_path / "whole"), "--workers", "2", "--quiet", "--no-plots"]) == 0
    assert _strip(after) == _strip(_rows(tmp_path / "whole"))


@pytest.mark.slow
def test_a_flight_over_its_time_limit_is_recorded_as_timed_out(tmp_path: Path) -> None:
    text = "timeout_s = 3.0\n" + SMALL.replace("seeds = 3", "seeds = 1").replace("grid = [0.0, 0.4]", "grid = [0.0]")
    # a flight far over its 3 s limit however fast the compiled flight gets (5,000 s once was)
    camp = _write(tmp_path, text + '\n[[vary]]\nfield = "duration_s"\ngrid = [1.0, 500000.0]\n')
    t0 = time.monotonic()
    assert main(["campaign", "run", str(camp), "--out", str(tmp_path / "out"), "--workers", "2", "--quiet", "--no-plots"]) == 0
    assert time.monotonic() - t0 < 60
    rows = {(r["duration_s"], r["controller"]): r for r in _rows(tmp_path / "out")}
    assert len(rows) == 4
    for ctrl in ("adaptive_pid_smc", "cascade_pid"):
        assert rows[("1.0", ctrl)]["status"] == "ok"
        hung = rows[("500000.0", ctrl)]
        assert hung["status"] == "timed out" and "3 s limit" in hung["message"] and 0 < float(hung["sim_s"]) < 500000


def _hang(unit):  # a task that never returns (not even cooperatively): the engine's backstop
    if unit.index == 0:
        time.sleep(3600)
    return {"unit": unit.index, "status": "ok", "message": ""}


def _die(unit):  # a task that kills its worker process
    if unit.index == 0:
        os._exit(3)
    return {"unit": unit.index, "status": "ok", "message": ""}


@pytest.mark.slow
@pytest.mark.parametrize(
    ("task", "status", "words"),
    [(_hang, "timed out", "a hang"), (_die, "error", "worker died")],
    ids=["hang", "killed-worker"],
)
def test_a_hung_task_or_a_dead_worker_fails_its_unit_not_the_campaign(tmp_path: Path, task, status: str, words: str) -> None:
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers need not import this test module
    from dataclasses import replace

    spec = load_campaign(_write(tmp_path, SMALL.replace("seeds = 3", "seeds = 2").replace("grid = [0.0, 0.4]", "grid = [0.0]")))
    units = [replace(u, timeout_s=1.0) for u in expand(spec)[:3]]
    rows: dict[int, dict] = {}
    t0 = time.monotonic()
    with dask_logs() as logged:  # the scheduler's and nanny's expected complaints: kept here, not in the test report
        with Engine(ClusterOptions(workers=1), task=task, grace_s=1.0) as engine:
            engine.run(units, lambda u, r: rows.__setitem__(u.index, r))
    assert time.monotonic() - t0 < 90
    if task is _die:
        assert any("exited with status 3" in m or "died" in m for m in logged), logged  # the noise is what was expected
    assert rows[0]["status"] == status and words in rows[0]["message"]
    assert rows[1]["status"] == rows[2]["status"] == "ok"  # the others flew on the restarted worker


def _die_if(killers: frozenset[int], unit):  # a task that kills its worker for the units named
    if unit.index in killers:
        os._exit(3)
    return {"unit": unit.index, "status": "ok", "message": ""}


@pytest.mark.slow
def test_only_the_units_that_kill_their_worker_are_errors() -> None:
    """Randomized (the seed is printed): units that kill their worker at random among many short
    ones, two workers. A unit Dask counted against a dying worker without having flown it is flown
    once more: exactly the killers are errors, every other unit is ok (it ran to its end)."""
    import functools

    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    seed = random.randrange(1 << 30)
    print(f"\nseed {seed}")
    rng = random.Random(seed)
    n = 12
    killers = frozenset(rng.sample(range(n), 2))
    units = [Unit(i, "g", "adaptive_pid_smc", 0, Scenario(name="x"), timeout_s=5.0) for i in range(n)]
    rows: dict[int, dict] = {}
    with dask_logs():
        with Engine(ClusterOptions(workers=2), task=functools.partial(_die_if, killers), grace_s=5.0) as engine:
            engine.run(units, lambda u, r: rows.__setitem__(u.index, r))
    assert sorted(rows) == list(range(n))
    errors = {i for i, r in rows.items() if r["status"] != "ok"}
    assert errors == set(killers), (seed, {i: rows[i]["message"] for i in errors})
    assert all("worker died" in rows[i]["message"] for i in killers)


@contextlib.contextmanager
def dask_logs() -> Iterator[list[str]]:
    """Capture the ``distributed`` loggers' records (a killed worker makes the scheduler log
    errors such as "marked as failed because 2 workers died" and "Couldn't gather keys"): into
    the list yielded, not to the root logger, whose records pytest prints in an XPASS report."""
    logger = logging.getLogger("distributed")
    messages: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            messages.append(record.getMessage())

    handler = Keep(logging.DEBUG)
    saved = logger.propagate
    logger.addHandler(handler)
    logger.propagate = False
    try:
        yield messages
    finally:
        logger.removeHandler(handler)
        logger.propagate = saved


@pytest.fixture
def dask_cluster(tmp_path: Path):
    """A Dask scheduler and one worker on 127.0.0.1, as separate processes (own process groups)."""
    sched_file = tmp_path / "scheduler.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    common = {"cwd": tmp_path, "env": env, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "start_new_session": True}
    procs = [subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(sched_file)], **common)]  # type: ignore[call-overload]  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while not sched_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(sched_file.read_text(encoding="utf-8"))["address"]
        procs.append(subprocess.Popen([sys.executable, "-m", "dask", "worker", address, "--nthreads", "1", "--nworkers", "1", "--no-dashboard",
                                       "--host", "127.0.0.1"], **common))  # type: ignore[call-overload]  # fmt: skip
        yield address, sched_file
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


@pytest.mark.slow
def test_the_same_campaign_on_a_running_scheduler(tmp_path: Path, dask_cluster, capsys: pytest.CaptureFixture[str]) -> None:
    address, sched_file = dask_cluster
    assert address.startswith("tcp://127.0.0.1:")
    camp = _write(tmp_path, SMALL.replace("seeds = 3", "seeds = 2"))
    assert main(["campaign", "run", str(camp), "--out", str(tmp_path / "remote"), "--cluster", address, "--no-plots"]) == 0
    assert f"Dask scheduler {address}, 1 workers" in capsys.readouterr().err
    assert main(["campaign", "run", str(camp), "--out", str(tmp_path / "local"), "--workers", "1", "--quiet", "--no-plots"]) == 0
    remote = _rows(tmp_path / "remote")
    assert len(remote) == 8 and _strip(remote) == _strip(_rows(tmp_path / "local"))
    assert main(["campaign", "run", str(camp), "--out", str(tmp_path / "by-file"), "--scheduler-file", str(sched_file), "--quiet", "--no-plots"]) == 0
    assert _strip(_rows(tmp_path / "by-file")) == _strip(remote)


@pytest.mark.parametrize(
    ("text", "argv", "words"),
    [
        (SMALL.replace('field = "plant.mass_kg"', 'field = "plant.mas_kg"'), [], ["unknown field 'plant.mas_kg'", "did you mean 'mass_kg'"]),
        (SMALL.replace('field = "plant.mass_kg"', 'field = "vehicel.mass_kg"'), [], ["unknown field 'vehicel.mass_kg'", "did you mean 'vehicle'"]),
        (SMALL.replace("dist = \"uniform\"\nlow = 1.0\nhigh = 1.2", "dist = \"uniform\"\nlow = 1.2\nhigh = 1.2"), [], ["empty range", "low (1.2) must be below high (1.2)"]),
        (SMALL.replace("std = 0.3", "std = -0.3"), [], ["normal needs std > 0"]),
        (SMALL.replace('dist = "normal"', 'dist = "gaussian"'), [], ["dist must be one of"]),
        (SMALL.replace("grid = [0.0, 0.4]", "grid = []"), [], ["grid must be a non-empty list"]),
        (SMALL.replace("grid = [0.0, 0.4]", "grid = [-1.0]"), [], ["unit 0", "gust_std_n must be >= 0"]),
        (SMALL + '\n[[vary]]\nfield = "fc.params.SMC_R_KPP"\ngrid = [1.0]\n', [], ["unknown FC parameter 'SMC_R_KPP'", "did you mean 'SMC_R_KP'"]),
        (SMALL + '\n[[vary]]\nfield = "fault[1].start_s"\ngrid = [1.0]\n', [], ["has 0 fault table(s)"]),
        (SMALL, ["--cluster", "tcp://127.0.0.1:9"], ["cannot reach the Dask scheduler at tcp://127.0.0.1:9"]),
        (SMALL, ["--sitl"], ["plant.* fields", "in-process only"]),
    ],
    ids=["field-typo", "section-typo", "empty-range", "normal-std", "unknown-dist", "empty-grid", "refused-value", "param-typo",
         "no-such-fault", "unreachable-scheduler", "plant-with-sitl"],
)  # fmt: skip
def test_bad_input_is_one_line_exit_2_and_nothing_started(tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, argv: list[str],
                                                        words: list[str]) -> None:  # fmt: skip
    camp = _write(tmp_path, text)
    out = tmp_path / "out"
    assert main(["campaign", "run", str(camp), "--out", str(out), "--quiet", "--connect-timeout", "1", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("smcpilot campaign: error:"), err
    for w in words:
        assert w in err
    assert not out.exists()  # nothing started, nothing written


@pytest.mark.slow
def test_sitl_units_fly_as_two_processes_and_a_hung_one_is_killed(tmp_path: Path) -> None:
    """--sitl: each unit is the real FC and simulator over UDP; one over its limit is stopped (its
    process group), recorded as timed out, and leaves no process behind."""
    import psutil

    text = "timeout_s = 8.0\n" + SMALL.replace("seeds = 3", "seeds = 1").replace("grid = [0.0, 0.4]", "grid = [0.0]").replace(
        'controllers = ["adaptive_pid_smc", "cascade_pid"]', 'controllers = ["adaptive_pid_smc"]')
    text = text[: text.index("[[vary]]\nfield = \"plant.mass_kg\"")] + text[text.index("[[vary]]\nfield = \"environment.wind"):]
    camp = _write(tmp_path, text + '\n[[vary]]\nfield = "duration_s"\ngrid = [1.0, 5000.0]\n')  # SITL: 5,000 s is far over 8 s
    out = tmp_path / "out"
    assert main(["campaign", "run", str(camp), "--out", str(out), "--workers", "1", "--sitl", "--quiet", "--no-plots"]) == 0
    rows = {r["duration_s"]: r for r in _rows(out)}
    assert rows["1.0"]["status"] == "ok" and float(rows["1.0"]["sim_s"]) > 0.9 and rows["1.0"]["iae_pos_m_s"] != ""
    assert rows["5000.0"]["status"] == "timed out" and "8 s limit" in rows["5000.0"]["message"]
    left = [p for p in psutil.process_iter(["cmdline"]) if any("smcpilot-unit-" in a for a in (p.info["cmdline"] or []))]
    assert not left, left


@pytest.mark.parametrize("path", sorted((ROOT / "examples" / "campaigns").glob("*.toml")), ids=lambda p: p.name)
def test_example_campaign_and_tuning_files_load_and_expand(path: Path) -> None:
    import tomllib

    if "gain" in tomllib.loads(path.read_text(encoding="utf-8")):
        from lab.tuning.study import load_tune

        spec = load_tune(path).campaign
    else:
        spec = load_campaign(path)
    units = expand(spec)
    assert len(units) == spec.n_units > 0 and [u.index for u in units] == list(range(len(units)))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), low=st.floats(-5, 5), width=st.floats(1e-3, 10), seeds=st.integers(1, 6))
def test_draws_are_in_range_deterministic_and_independent_of_other_variations(seed: int, low: float, width: float, seeds: int) -> None:
    from lab.campaign.spec import parse_campaign

    def doc(extra: list[dict]) -> dict:
        return {"seed": seed, "seeds": seeds, "scenario": {"duration_s": 1.0},
                "vary": [{"field": "environment.wind_force_ned_n[1]", "dist": "uniform", "low": low, "high": low + width}, *extra]}  # fmt: skip

    one = expand(parse_campaign(doc([])))
    again = expand(parse_campaign(doc([])))
    more = expand(parse_campaign(doc([{"field": "environment.noise_scale", "dist": "log-uniform", "low": 0.5, "high": 2.0}])))
    east = [u.scenario.environment.wind_force_ned_n[1] for u in one]
    assert all(low <= e <= low + width for e in east)
    assert east == [u.scenario.environment.wind_force_ned_n[1] for u in again]  # the same file, the same units
    assert east == [u.scenario.environment.wind_force_ned_n[1] for u in more]  # another variation leaves this one's draws
    assert [u.seed for u in one] == [u.seed for u in more] == [scenario_seed(seed, s) for s in range(seeds)]
    assert all(0.5 <= u.scenario.environment.noise_scale <= 2.0 for u in more)


# -- batches: several units per task ------------------------------------------------------------------
def _same_rows(a: dict, b: dict) -> bool:
    """Two rows of one unit are the same but for the wall time, bit for bit (NaN equal to NaN)."""
    keys = (set(a) | set(b)) - {"wall_s"}
    return all(a.get(k) == b.get(k) or (isinstance(a.get(k), float) and isinstance(b.get(k), float) and a[k] != a[k] and b[k] != b[k])
               for k in keys)  # fmt: skip


def test_a_batch_flies_each_unit_as_it_flies_alone() -> None:
    """fly_batch (what a worker runs for a batch) gives every unit the row it gets flown alone, bit
    for bit: different seeds, controllers (a whole-stack law too), a motor fault, a sensor fault,
    gusts, a plant the FC does not know, flown in one order as a batch and alone in the other."""
    from dataclasses import replace

    from lab.campaign.engine import fly_batch
    from lab.campaign.flight import fly_row
    from lab.compare import VARIANTS, study_cases, study_unit

    cases = {c.name: c for c in study_cases(duration_s=3.0, t_event_s=1.5)}
    picks = [("motor30-hover", 0, 0), ("gusts", 3, 1), ("gyro-bias", 5, 2), ("mass+30", 6, 0), ("pos-dropout", 1, 3)]
    units = [replace(study_unit(cases[c], VARIANTS[v], seed, i), score_from_s=0.5) for i, (c, v, seed) in enumerate(picks)]
    batch = fly_batch(fly_row, units)
    alone = [fly_row(u) for u in reversed(units)][::-1]
    assert [r["unit"] for r in batch] == [u.index for u in units]
    for b, a in zip(batch, alone):
        assert b["status"] == "ok" and b["sim_s"] == pytest.approx(3.0)
        assert _same_rows(b, a), {k: (b.get(k), a.get(k)) for k in set(a) | set(b) if k != "wall_s" and b.get(k) != a.get(k)}
    assert len({r["iae_pos_m_s"] for r in batch}) == len(batch)  # five different flights


def test_units_are_cut_into_batches_in_order() -> None:
    from dataclasses import replace

    from lab.campaign.engine import batches

    sc = Scenario(name="x", duration_s=20.0)  # 10,000 ticks at 500 Hz
    units = [Unit(i, "g", "adaptive_pid_smc", 0, sc) for i in range(100)]
    cut = batches(units, 2)
    assert [u.index for b in cut for u in b] == list(range(100))  # every unit once, in order
    assert [len(b) for b in cut] == [13] * 7 + [9]  # about four batches per worker
    assert [len(b) for b in batches(units, 1, max_ticks=5 * sc.n_ticks)] == [5] * 20  # at most max_ticks a batch
    assert [len(b) for b in batches(units[:3], 2)] == [1, 1, 1]  # too few units: one each
    swarm = Scenario.from_mapping({"name": "s", "duration_s": 20.0, "swarm": {"count": 4}})
    assert swarm.count == 4
    assert [len(b) for b in batches([replace(u, scenario=swarm) for u in units[:20]], 1)] == [4] * 5  # 200,000 ticks: 4 swarms of 4
    mixed = [replace(u, sitl=u.index % 4 == 0) for u in units[:12]]
    cut = batches(mixed, 1)
    assert [u.index for b in cut for u in b] == list(range(12))
    assert all(len(b) == 1 for b in cut if b[0].sitl)  # a SITL unit always alone
    assert [[u.index for u in b] for b in cut if not b[0].sitl] == [[1, 2, 3], [5, 6, 7], [9, 10, 11]]


def _hang_or_die(bad: frozenset[int], how: str, unit):  # a task that hangs or kills its worker for the units named
    if unit.index in bad:
        if how == "hang":
            time.sleep(3600)
        os._exit(3)
    return {"unit": unit.index, "status": "ok", "message": ""}


@pytest.mark.slow
@pytest.mark.parametrize(("how", "status", "words"), [("hang", "timed out", "a hang"), ("die", "error", "worker died")])
def test_a_batch_that_hangs_or_kills_its_worker_is_flown_again_one_unit_per_task(how: str, status: str, words: str) -> None:
    """A batch that does not come back is not a result: its units are flown again alone, so only
    the unit that hangs (or kills its worker) fails, every other unit of its batch is ok."""
    import functools

    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    units = [Unit(i, "g", "adaptive_pid_smc", 0, Scenario(name="x", duration_s=1.0), timeout_s=1.0) for i in range(8)]
    rows: dict[int, dict] = {}
    with dask_logs():
        with Engine(ClusterOptions(workers=1), task=functools.partial(_hang_or_die, frozenset({5}), how), grace_s=1.0) as engine:
            assert [len(b) for b in engine.batches(units)] == [2, 2, 2, 2]
            engine.run(units, lambda u, r: rows.__setitem__(u.index, r))
    assert sorted(rows) == list(range(8))
    assert rows[5]["status"] == status and words in rows[5]["message"], rows[5]
    assert all(rows[i]["status"] == "ok" for i in range(8) if i != 5)


SWARM_CAMPAIGN = """
name = "pair"
seed = 5
seeds = 2
duration_s = 2.0
controllers = ["adaptive_pid_smc"]

[scenario]
[scenario.environment]
noise = true
[[scenario.step]]
t_s = 0.0
action = "takeoff"
alt_m = 1.0
[scenario.swarm]
count = 2
spacing_m = 3.0

[[vary]]
field = "environment.wind_force_ned_n[0]"
dist = "normal"
mean = 0.0
std = 0.3
"""


@pytest.mark.slow
def test_a_swarm_unit_is_one_row_with_every_vehicle_and_the_separation(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    camp = _write(tmp_path, SWARM_CAMPAIGN)
    assert main(["campaign", "run", str(camp), "--out", str(tmp_path / "one"), "--workers", "1", "--quiet", "--no-plots"]) == 0
    assert main(["campaign", "run", str(camp), "--out", str(tmp_path / "two"), "--workers", "2", "--quiet", "--no-plots"]) == 0
    one, two = _rows(tmp_path / "one"), _rows(tmp_path / "two")
    assert len(one) == 2 and _strip(one) == _strip(two)
    for r in one:
        assert r["status"] == "ok" and r["vehicles"] == "2" and r["crashed_vehicles"] == "0" and r["contacts"] == "0"
        assert float(r["min_separation_m"]) == pytest.approx(3.0, abs=0.3)
        assert r["worst_vehicle"] in ("1", "2")
        worst = r["worst_vehicle"]
        assert r["iae_pos_m_s"] == r[f"v{worst}_iae_pos_m_s"]  # the unit's columns are its worst vehicle's
        assert max(float(r["v1_iae_pos_m_s"]), float(r["v2_iae_pos_m_s"])) == float(r["iae_pos_m_s"])
    assert one[0]["v1_iae_pos_m_s"] != one[1]["v1_iae_pos_m_s"]  # the seeds differ
    # replay: the swarm unit again, exactly, with each vehicle's log
    capsys.readouterr()
    assert main(["campaign", "replay", str(tmp_path / "one"), "1", "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "gives the unit's results.csv row exactly" in out and "unit-1-v1.tlog, " in out and "unit-1-v2.tlog" in out
    # a plant.* variation cannot apply to a swarm: the rows say so
    bad = _write(tmp_path, SWARM_CAMPAIGN + '[[vary]]\nfield = "plant.mass_kg"\ndist = "uniform"\nlow = 1.0\nhigh = 1.1\nrelative = true\n', "bad.toml")
    main(["campaign", "run", str(bad), "--out", str(tmp_path / "bad"), "--workers", "1", "--quiet", "--no-plots"])
    rows = _rows(tmp_path / "bad")
    assert rows and all(r["status"] == "error" and "no plant.* variation" in r["message"] for r in rows)
