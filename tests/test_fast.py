"""The compiled in-process flight (:mod:`lab.fast`) is the CPython flight, bit for bit.

Oracles: the CPython runner itself (:func:`lab.runner.simulate` with ``fast=False``) for whole
flights — every tick's metrics row (state, set-points, references, float32 motor commands, flags,
sigma), every event with its time, the plant's final state, the divergence time; CPython's
``random.Random`` for the kernel's random streams; the modes' own ``run`` for their ``watch``.

The randomized flights print their seed: ``SMCPILOT_FAST_SEED=<seed> pytest tests/test_fast.py -k random``
flies that one again.
"""

from __future__ import annotations

import math
import os
import random
import struct
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as M
from test_modes import Host, _item, _state

from fc.config import FcConfig
from fc.core import FlightCore
from fc.modes.auto import AutoMode, AutoPhase
from fc.modes.rtl import RtlMode, RtlPhase
from fc.params import settings_for
from lab.fast.flight import FastRecord
from lab.fast.kernel import _watch_holds
from lab.fast.mt import mt_export, mt_gauss, mt_import
from lab.metrics import MetricsRecorder
from lab.runner import simulate
from sim_bridge.build import plant_for
from smcpilot.errors import DivergenceError
from smcpilot.geo import Home
from smcpilot.protocol import Mode
from smcpilot.scenario import Scenario
from smcpilot.tlog import read_tlog

pytest.importorskip("numba")

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples" / "scenarios").glob("*.toml"))
LAWS = ("adaptive_pid_smc", "pid_smc", "cascade_pid", "sign_smc", "se3_geometric", "indi")


def _bits(row: tuple[float, ...]) -> bytes:
    return struct.pack(f"<{len(row)}d", *row)


def _fly(sc: Scenario, fast: bool, *, truth: bool = False) -> dict[str, Any]:
    """One flight of ``sc``: what it recorded, raised and left behind."""
    config, options = settings_for(sc)
    home = Home(*sc.home) if sc.home is not None else Home()
    events: list[tuple[float, int, str]] = []
    core = FlightCore(config, sc.vehicle, home=home, plan=sc.plan, estimator=options.estimator,
                      event=lambda sev, text: events.append((core.t_us * 1e-6, sev, text)))  # fmt: skip
    plant = plant_for(sc)
    rec = MetricsRecorder(core)
    diverged = None
    try:
        ticks = simulate(core, plant, sc.n_ticks, rate_hz=sc.rate_hz, physics_hz=sc.physics_hz, fast=fast,
                         record=FastRecord(rec, 1, truth),
                         on_fault_event=lambda ev: events.append((ev.t_s, ev.severity, ev.text)))  # fmt: skip
    except DivergenceError as exc:
        diverged = (str(exc), exc.time_s)
        ticks = core.ticks
    return {
        "ticks": ticks, "core_ticks": core.ticks, "t_us": core.t_us, "rows": [tuple(r) for r in rec.rows().tolist()], "events": events,
        "plant": plant._s, "turns": plant.heading_turns, "diverged": diverged, "law_fault": core.law_fault,
        "pipeline": core.flight.pipeline_state, "armed": core.flight.armed, "mode": core.mode,
    }  # fmt: skip


def _assert_same(a: dict[str, Any], b: dict[str, Any], what: str) -> None:
    for i, (ra, rb) in enumerate(zip(a["rows"], b["rows"])):
        if _bits(ra) != _bits(rb):
            cols = [j for j, (u, v) in enumerate(zip(ra, rb)) if struct.pack("<d", u) != struct.pack("<d", v)]
            pytest.fail(f"{what}: tick {i} differs in columns {cols}: {ra} vs {rb}")
    assert len(a["rows"]) == len(b["rows"]), what
    for key in ("ticks", "core_ticks", "t_us", "events", "turns", "diverged", "law_fault", "armed", "mode"):
        assert a[key] == b[key], f"{what}: {key}: {a[key]!r} vs {b[key]!r}"
    assert _bits(a["plant"]) == _bits(b["plant"]), what
    assert repr(a["pipeline"]) == repr(b["pipeline"]), what


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_every_example_scenario_flies_the_same_compiled(path: Path) -> None:
    sc = Scenario.from_toml(path)
    _assert_same(_fly(sc, False), _fly(sc, True), path.stem)


def test_the_true_state_is_recorded_the_same_compiled() -> None:
    sc = Scenario.from_toml(ROOT / "examples" / "scenarios" / "gusty-hold.toml").with_changes(duration_s=8.0)
    _assert_same(_fly(sc, False, truth=True), _fly(sc, True, truth=True), "truth rows")


def _random_scenario(seed: int, law: str | None = None) -> Scenario:
    """A short flight with a random law (or ``law``), plan, environment and faults (all fault kinds)."""
    r = random.Random(seed)
    dur = r.uniform(5.0, 10.0)
    alt = r.uniform(1.0, 4.0)
    steps: list[dict[str, Any]] = [{"t_s": 0.0, "action": "takeoff", "alt_m": alt}]
    t_goto = r.uniform(1.0, dur * 0.5)
    steps.append({"t_s": t_goto, "action": "goto", "north_m": r.uniform(-3, 3), "east_m": r.uniform(-3, 3),
                  "alt_m": r.uniform(1.0, 4.0), "yaw_deg": r.uniform(-180, 180)})  # fmt: skip
    if r.random() < 0.6:
        steps.append({"t_s": r.uniform(t_goto, dur), "action": "land"})
    faults: list[dict[str, Any]] = []
    for _ in range(r.randint(0, 3)):
        kind = r.choice(("motor", "motor", "force", "torque", "gust", "paper_disturbance", "sensor", "sensor"))
        start = r.uniform(0.5, dur)
        f: dict[str, Any] = {"kind": kind, "start_s": start}
        if r.random() < 0.5:
            f["stop_s"] = start + r.uniform(0.1, 2.0)
        if kind == "motor":
            f.update(motor=r.randint(1, 4), efficiency=r.uniform(0.6, 1.0))
        elif kind == "force":
            f["force_ned_n"] = [r.uniform(-1, 1), r.uniform(-1, 1), r.uniform(-1, 1)]
        elif kind == "torque":
            f["torque_frd_n_m"] = [r.uniform(-0.02, 0.02), r.uniform(-0.02, 0.02), r.uniform(-0.02, 0.02)]
        elif kind == "gust":
            f.update(force_std_n=r.uniform(0.0, 0.3), torque_std_n_m=r.uniform(0.0, 0.005))
        elif kind == "sensor":
            mode = r.choice(("stuck", "bias", "noise", "dropout", "delay"))
            sensor = r.choice(("gyro", "accel", "attitude", "position", "velocity"))
            f.update(sensor=sensor, mode=mode)
            if mode in ("bias", "noise"):
                f["value"] = [r.uniform(0.0, 0.02) for _ in range(3)]
            elif mode == "delay":
                f["value"] = [r.uniform(0.01, 0.1), 0.0, 0.0]
            f["stop_s"] = start + r.uniform(0.05, 0.5)
        faults.append(f)
    doc: dict[str, Any] = {
        "name": f"random-{seed}", "duration_s": dur, "seed": r.randint(0, 1000),
        "environment": {
            "noise": r.random() < 0.5, "wind_force_ned_n": [r.uniform(-0.5, 0.5), r.uniform(-0.5, 0.5), 0.0],
            "gust_std_n": r.choice((0.0, 0.1, 0.2)), "paper_disturbance": r.random() < 0.2,
        },
        "fc": {"controller": law or r.choice(LAWS), "rate_hz": r.choice((500.0, 250.0))},
        "step": steps, "fault": faults,
    }  # fmt: skip
    return Scenario.from_mapping(doc)


def _seeds(n: int) -> list[int]:
    pinned = os.environ.get("SMCPILOT_FAST_SEED")
    if pinned:
        return [int(pinned)]
    base = random.SystemRandom().randrange(1 << 30)
    return [base + i for i in range(n)]


@pytest.mark.slow
def test_random_flights_with_faults_noise_wind_and_gusts_fly_the_same_compiled() -> None:
    for seed in _seeds(14):
        print(f"random flight seed {seed} (SMCPILOT_FAST_SEED={seed} replays it)")
        sc = _random_scenario(seed)
        _assert_same(_fly(sc, False), _fly(sc, True), f"seed {seed}")


def test_random_flights_of_the_default_law_fly_the_same_compiled() -> None:
    for seed in _seeds(3):
        print(f"random flight seed {seed} (SMCPILOT_FAST_SEED={seed} replays it)")
        sc = _random_scenario(seed, "adaptive_pid_smc")
        _assert_same(_fly(sc, False), _fly(sc, True), f"seed {seed}")


def test_a_law_that_measures_acceleration_gets_the_imu_compiled() -> None:
    """INDI's altitude channel flies on the accelerometer (the IMU: specific force, float32, back to
    the paper frame): compiled, with sensor noise, an accelerometer bias and a dropout of it (NaN:
    INDI differences z' then), the same flight bit for bit, and the kernel flew it."""
    from lab.fast.flight import KERNEL_TIME

    sc = Scenario.from_mapping({
        "name": "indi-imu", "duration_s": 6.0, "seed": 5, "environment": {"noise": True, "gust_std_n": 0.1},
        "fc": {"controller": "indi"}, "step": [{"t_s": 0.0, "action": "takeoff", "alt_m": 2.0}],
        "fault": [{"kind": "sensor", "sensor": "accel", "mode": "bias", "value": [0.0, 0.0, 0.3], "start_s": 2.0, "stop_s": 3.5},
                  {"kind": "sensor", "sensor": "accel", "mode": "dropout", "start_s": 4.0, "stop_s": 4.3}],
    })  # fmt: skip
    before = KERNEL_TIME[1]
    fast = _fly(sc, True)
    assert KERNEL_TIME[1] - before > 0.8 * sc.n_ticks  # the kernel flew most of it, not CPython
    slow = _fly(sc, False)
    _assert_same(slow, fast, "indi with the IMU")


def test_a_divergence_is_the_same_compiled() -> None:
    """An absurd torque blows the physics up: the same tick, the same error and time either way."""
    doc = {
        "name": "blow-up", "duration_s": 6.0,
        "step": [{"t_s": 0.0, "action": "takeoff", "alt_m": 2.0}],
        "fault": [{"kind": "torque", "start_s": 2.0, "torque_frd_n_m": [1e150, 0.0, 0.0]}],
    }  # fmt: skip
    sc = Scenario.from_mapping(doc)
    a, b = _fly(sc, False), _fly(sc, True)
    assert a["diverged"] is not None, "the torque blows the physics up"
    _assert_same(a, b, "divergence")


# -- the random streams -----------------------------------------------------------------------------
def test_the_kernels_random_streams_are_cpythons() -> None:
    from lab.fast.mt import MT_FUNCTIONS
    from smcpilot.jit import compile_pure

    jit = compile_pure(MT_FUNCTIONS)
    for seed in (0, 7, 2**40 + 3):
        rng = random.Random(seed)
        rng.gauss(0.0, 1.0)  # a kept second value travels too
        mt, gs = mt_export(rng)
        want = [rng.gauss(0.3, 2.0) for _ in range(1500)]  # crosses two regenerations of the 624 words
        got = [jit[mt_gauss](mt, gs, 0.3, 2.0) for _ in range(1500)]
        assert got == want
        back = random.Random()
        mt_import(back, mt, gs)
        assert back.getstate() == rng.getstate()
    # and CPython runs the same pure functions too (slowly)
    mt, gs = mt_export(random.Random(3))
    want_rng = random.Random(3)
    assert [mt_gauss(mt, gs, 0.0, 1.0) for _ in range(5)] == [want_rng.gauss(0.0, 1.0) for _ in range(5)]


def test_gaussian_draws_in_batches_are_the_streams_draws_one_by_one() -> None:
    """mt_gauss_fill (the kernel's batches: a tick's sensor noise, a physics step's gusts) gives
    the numbers n calls of random.gauss give, in order, and leaves the stream where they do:
    batches of every size from 0 to 15, odd and even (a kept second value), across regenerations."""
    from lab.fast.mt import MT_FUNCTIONS, mt_gauss_fill
    from smcpilot.jit import compile_pure

    jit = compile_pure(MT_FUNCTIONS)
    out = np.zeros(16)
    for fill in (jit[mt_gauss_fill], mt_gauss_fill):
        rng = random.Random(11)
        mt, gs = mt_export(rng)
        sizes = [0, 1, 15, 2, 3, 6, 5, 4] * (60 if fill is not mt_gauss_fill else 2)  # compiled: ~2,500 draws, four regenerations
        for n in sizes:
            want = [0.0 + rng.gauss(0.0, 1.0) * 0.25 for _ in range(n)]
            fill(mt, gs, out, n)
            assert [0.0 + z * 0.25 for z in out[:n]] == want
        back = random.Random()
        mt_import(back, mt, gs)
        assert back.getstate() == rng.getstate()


# -- the modes' watch ---------------------------------------------------------------------------------
def _snapshot(h: Host, auto: AutoMode | None, rtl: RtlMode) -> tuple:
    f = h.flight
    a = (auto.phase, auto._seq, auto.complete, h.mission.current) if auto is not None else ()
    return (*a, rtl.phase, f.target, f.landing, f.speed_xy_mps, tuple(h.reached), tuple(h.events))


def _fly_modes(mode: Any, h: Host, rtl: RtlMode, auto: AutoMode | None, r: random.Random, ticks: int) -> int:
    """Fly ``mode`` on a toy vehicle that moves towards its target with noise; every tick on which
    ``run`` changed anything, its watch (taken before) must have held. Returns the ticks on which
    the watch held."""
    f = h.flight
    x, y, z = 0.0, 0.0, 0.0
    held = 0
    t = 0.0
    for _ in range(ticks):
        tx, ty, tz = f.target
        x += 0.05 * (tx - x) + r.gauss(0.0, 0.01)
        y += 0.05 * (ty - y) + r.gauss(0.0, 0.01)
        z += 0.05 * ((tz - 1.0 if f.landing else tz) - z) + r.gauss(0.0, 0.01)
        st = _state(x, y, z)
        w = mode.watch()
        before = _snapshot(h, auto, rtl)
        mode.run(st, t, 0.002)
        holds = _watch_holds(w.kind, w.a, w.b, w.c, w.r, x, y, z, t) or w.kind == 1
        held += holds
        if _snapshot(h, auto, rtl) != before:
            assert holds, f"run acted at t = {t:.3f} ({x:.3f}, {y:.3f}, {z:.3f}) but its watch {w} did not hold"
        t += 0.002
    return held


def test_rtl_acts_only_when_its_watch_holds() -> None:
    r = random.Random(11)
    h = Host(FcConfig(rtl_alt_m=3.0))
    h.flight.arm(_state())
    rtl = RtlMode(h)
    rtl.enter(Mode.GUIDED, _state())
    held = _fly_modes(rtl, h, rtl, None, r, 6000)
    assert rtl.phase is RtlPhase.LAND and 0 < held < 100  # it went through every phase, watching


def test_auto_acts_only_when_its_watch_holds() -> None:
    items = [
        _item(0, M.MAV_CMD_NAV_WAYPOINT, alt=0.0),
        _item(1, M.MAV_CMD_NAV_TAKEOFF, alt=2.0),
        _item(2, M.MAV_CMD_DO_CHANGE_SPEED, frame=M.MAV_FRAME_MISSION, p2=1.5),
        _item(3, M.MAV_CMD_NAV_WAYPOINT, n=3.0, alt=2.0, p1=1.0),
        _item(4, M.MAV_CMD_NAV_LOITER_TIME, n=1.0, e=1.0, alt=2.5, p1=0.5),
        _item(5, M.MAV_CMD_NAV_WAYPOINT, n=-1.0, alt=2.0, p2=0.5),
        _item(6, M.MAV_CMD_NAV_RETURN_TO_LAUNCH, frame=M.MAV_FRAME_MISSION),
    ]
    r = random.Random(5)
    h = Host(FcConfig(rtl_alt_m=3.0), items)
    h.flight.arm(_state())
    rtl = RtlMode(h)
    auto = AutoMode(h, rtl)
    auto.enter(Mode.GUIDED, _state())
    held = _fly_modes(auto, h, rtl, auto, r, 12000)
    assert auto.phase is AutoPhase.RTL and rtl.phase is RtlPhase.LAND, (auto.phase, rtl.phase, h.reached)
    assert h.reached == [1, 2, 3, 4, 5] and held < 1000


# -- switches and imports -----------------------------------------------------------------------------
def _python(code: str, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300,
                          env={**os.environ, **env})  # fmt: skip


def test_smcpilot_jit_0_flies_in_cpython_and_says_so_once() -> None:
    code = (
        "from smcpilot.scenario import Scenario\n"
        "from lab.run import fly_in_process\n"
        "import tempfile, pathlib, sys\n"
        "sc = Scenario.from_toml('examples/scenarios/hover.toml').with_changes(duration_s=2.0)\n"
        "from fc.core import FlightCore\n"
        "from fc.params import config_for\n"
        "from lab.runner import simulate\n"
        "from sim_bridge.build import plant_for\n"
        "for _ in range(2):\n"
        "    core = FlightCore(config_for(sc), sc.vehicle, plan=sc.plan)\n"
        "    simulate(core, plant_for(sc), sc.n_ticks, rate_hz=sc.rate_hz)\n"
        "print('numba' in sys.modules)\n"
    )
    p = _python(code, SMCPILOT_JIT="0")
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "False"
    assert p.stderr.count("compiled flight path off (SMCPILOT_JIT=0)") == 1, p.stderr


@pytest.mark.parametrize("argv", [["--help"], ["gcs", "--help"], ["log", "--help"], ["laws"]])
def test_commands_that_do_not_fly_never_import_numba(argv: list[str]) -> None:
    code = f"import sys\nfrom lab.cli import main\ntry:\n    main({argv!r})\nexcept SystemExit:\n    pass\nprint('numba' in sys.modules, file=sys.stderr)\n"
    p = _python(code)
    assert p.stderr.strip().splitlines()[-1] == "False", p.stderr[-2000:]



# -- the log ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["gusty-hold", "motor-loss"])
def test_the_tlog_of_a_compiled_flight_is_the_same_file(name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``smcpilot run``'s in-process log: every record (state messages, motor commands, the SMC
    record, the events, the simulator's fault announcements) the same, byte for byte."""
    from lab.run import fly_in_process

    sc = Scenario.from_toml(ROOT / "examples" / "scenarios" / f"{name}.toml").with_changes(duration_s=14.0)
    compiled = fly_in_process(sc, tmp_path / "compiled.tlog")
    monkeypatch.setenv("SMCPILOT_JIT", "0")
    cpython = fly_in_process(sc, tmp_path / "cpython.tlog")
    assert (compiled.status, compiled.ticks, compiled.events) == (cpython.status, cpython.ticks, cpython.events)
    assert compiled.events, "the flight had events (take-off, the fault or the landing)"
    assert (tmp_path / "compiled.tlog").read_bytes() == (tmp_path / "cpython.tlog").read_bytes()
    kinds = [m.get_type() for _, m in read_tlog(tmp_path / "compiled.tlog")]
    assert kinds.count("HIGHRES_IMU") == kinds.count("ODOMETRY") == kinds.count("ATTITUDE") == compiled.ticks  # the IMU and the truth


@pytest.mark.parametrize("sensor", ["accel", "gyro"])
def test_a_compiled_flight_with_an_imu_dropout_writes_the_cpython_file(sensor: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """NaN in the IMU (a dropout) and noise: the compiled and the CPython flight write the same bytes."""
    from lab.run import fly_in_process

    sc = Scenario.from_mapping({
        "name": f"{sensor}-dropout", "duration_s": 4.0, "seed": 5, "environment": {"noise": True, "gust_std_n": 0.1},
        "step": [{"t_s": 0.0, "action": "takeoff", "alt_m": 2.0}],
        "fault": [{"kind": "sensor", "sensor": sensor, "mode": "dropout", "start_s": 1.5, "stop_s": 2.0}],
    })  # fmt: skip
    compiled = fly_in_process(sc, tmp_path / "compiled.tlog")
    monkeypatch.setenv("SMCPILOT_JIT", "0")
    cpython = fly_in_process(sc, tmp_path / "cpython.tlog")
    assert compiled.status == cpython.status == "ok"
    data = (tmp_path / "compiled.tlog").read_bytes()
    assert data == (tmp_path / "cpython.tlog").read_bytes()
    imu = [m for _, m in read_tlog(tmp_path / "compiled.tlog") if m.get_type() == "HIGHRES_IMU"]
    gap = [m for m in imu if 1_500_000 <= m.time_usec < 2_000_000]
    field = "xacc" if sensor == "accel" else "xgyro"
    assert gap and all(math.isnan(getattr(m, field)) for m in gap) and not math.isnan(getattr(imu[-1], field))


@pytest.mark.parametrize("case", ["gusts", "gyro-bias", "pos-dropout", "motor30-step", "paper-dist"])
def test_the_robustness_study_cases_fly_the_same_compiled(case: str) -> None:
    """The study's cases (lab.compare): fault gusts, a gyro bias, a position dropout (dead reckoning),
    a motor loss mid-step, the paper's disturbances — and with them the kernel's sensor-fault program."""
    from lab.compare import study_cases

    (c,) = [c for c in study_cases(duration_s=9.0, t_event_s=4.0) if c.name == case]
    sc = c.scenario.with_changes(seed=3)
    _assert_same(_fly(sc, False), _fly(sc, True), case)
    _assert_same(_fly(sc, False, truth=True), _fly(sc, True, truth=True), case + " (truth)")


def _pd_law_copy(tmp_path: Path, stem: str, change: tuple[str, str] | None = None) -> tuple[str, str]:
    """A copy of the example PD law as a new law (new sources, so nothing is compiled for it; its
    own name and parameter prefix, beside the example's and other copies in this process), with
    one line of its source changed: (its name, its ``file.py:NAME`` reference)."""
    tag = random.SystemRandom().randrange(1 << 30)
    name = f"{stem}_{tag}"
    prefix = "F" + "".join(chr(65 + int(d)) for d in str(tag)[:7])
    src = (ROOT / "examples" / "law-plugin" / "smcpilot_pd_law" / "pd_law.py").read_text()
    head = 'name="pd_feedback", stage="attitude", prefix="PDL"'
    assert head in src
    src = src.replace(head, f'name="{name}", stage="attitude", prefix="{prefix}"')
    if change is not None:
        assert change[0] in src
        src = src.replace(*change)
    law_file = tmp_path / f"{name}.py"
    law_file.write_text(src + f"\n# {tag}: a new law\n")
    return name, f"{law_file}:PD_LAW"


@pytest.mark.slow  # compiles a kernel for a law nobody compiled before (20-50 s)
def test_a_plug_in_law_flies_in_cpython_until_it_is_compiled_and_then_the_same(tmp_path: Path) -> None:
    """A single flight of a plug-in law whose kernel is not compiled flies in CPython (said once);
    ``fast=True`` (what campaigns pass) compiles it, and the flight is the same."""
    _name, ref = _pd_law_copy(tmp_path, "pd_copy")
    sc = Scenario.from_toml(ROOT / "examples" / "scenarios" / "hover.toml").with_changes(duration_s=4.0, controller=ref)
    code = (
        "import sys\n"
        "from smcpilot.scenario import Scenario\n"
        "from fc.core import FlightCore\n"
        "from fc.params import config_for\n"
        "from lab.runner import simulate\n"
        "from sim_bridge.build import plant_for\n"
        f"sc = Scenario.from_toml({str(ROOT / 'examples' / 'scenarios' / 'hover.toml')!r}).with_changes(duration_s=4.0, controller={sc.controller!r})\n"
        "core = FlightCore(config_for(sc), sc.vehicle, plan=sc.plan)\n"
        "simulate(core, plant_for(sc), sc.n_ticks, rate_hz=sc.rate_hz)\n"
        "simulate(FlightCore(config_for(sc), sc.vehicle, plan=sc.plan), plant_for(sc), sc.n_ticks, rate_hz=sc.rate_hz)\n"
    )
    p = _python(code)
    assert p.returncode == 0, p.stderr
    assert p.stderr.count("no compiled kernel yet") == 1, p.stderr  # two flights, said once
    assert "compiling the flight kernel" not in p.stderr and "compiled the flight kernel" not in p.stderr, p.stderr
    a = _fly(sc, False)
    b = _fly(sc, True)  # compiles the kernel for this law
    _assert_same(a, b, "plug-in law")


def test_a_law_numba_cannot_compile_flies_in_cpython_and_says_why(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """In the pure style, but its state changes shape between branches (numba cannot type it): the
    flight falls back to CPython before anything changed, says so once, and is the CPython flight."""
    name, ref = _pd_law_copy(tmp_path, "pd_shape", ("    return u, (iz,), (zero, zero, zero, zero)",
                                                    "    return u, ((iz,) if iz < 1e9 else (iz, 0.0)), (zero, zero, zero, zero)"))  # fmt: skip
    sc = Scenario.from_toml(ROOT / "examples" / "scenarios" / "hover.toml").with_changes(duration_s=3.0, controller=ref)
    a = _fly(sc, False)
    capfd.readouterr()
    b = _fly(sc, True)
    err = capfd.readouterr().err
    assert f"the control law {name} could not be compiled" in err, err
    _assert_same(a, b, "a law numba cannot compile")
    assert a["armed"] and a["rows"][-1][3] > 0.5, "it flew (took off)"
