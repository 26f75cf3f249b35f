"""The simulator's compiled physics (:mod:`sim_bridge.plants.compiled_physics`) against the plant's
own Python steps: the same states bit for bit, the same fallbacks, the same divergence; and the
simulator process's flight the same with it as without (the FC's log byte for byte)."""

from __future__ import annotations

import math
import random
import subprocess
import sys

import pytest
from bits_helpers import needs_jit

from sim_bridge.build import plant_for
from sim_bridge.plants import compiled_physics as cp
from sim_bridge.plants.rigid_body import RigidBodyPlant
from smcpilot.errors import DivergenceError
from smcpilot.faults import FaultSpec
from smcpilot.scenario import EnvironmentSpec, Scenario
from tests.sitl_helpers import fly_sitl

DT_US = 1000
DT_S = 1.0 / 1000.0


def _fields(p: RigidBodyPlant) -> tuple:
    """What a step leaves in the plant: state, acceleration, heading, step input, time."""
    return (p._s, p._accel, p._psi, p._input, p._t_s)


def _python_steps(plants, cmds, armed, t_us0, n):  # type: ignore[no-untyped-def]
    """The simulator's Python loop (:meth:`sim_bridge.app.SimBridgeApp._integrate`)."""
    for k in range(n):
        t_s = (t_us0 + k * DT_US) * 1e-6
        for p, c, a in zip(plants, cmds, armed):
            p.step(t_s, DT_S, c, a)


def _pair(scenario: Scenario) -> tuple[RigidBodyPlant, RigidBodyPlant, cp.CompiledPhysics]:
    a, b = plant_for(scenario), plant_for(scenario)
    assert isinstance(a, RigidBodyPlant) and isinstance(b, RigidBodyPlant)
    phys, why = cp.load([b], compile_new=True)
    assert phys is not None, why
    return a, b, phys


def _commands(rng: random.Random, tick: int) -> tuple[float, float, float, float]:
    """Take off, spin (the heading through +-pi several times), then cut to idle, fall and land."""
    if tick < 300:
        return (0.7, 0.7, 0.7, 0.7)
    if tick < 1500:
        base = 0.5 + 0.02 * math.sin(tick * 0.01)
        return (base + 0.2, base - 0.2 + rng.uniform(-0.01, 0.01), base + 0.2, base - 0.2)  # a strong yaw torque
    return (0.05, 0.05, 0.05, float("nan"))  # NaN: a motor the plant treats as stopped


@needs_jit
@pytest.mark.parametrize(
    "scenario",
    [
        Scenario(),
        Scenario(environment=EnvironmentSpec(wind_force_ned_n=(0.4, -0.3, 0.1), paper_disturbance=True)),
        Scenario(faults=(FaultSpec("motor", start_s=0.0, motor=2, efficiency=0.8), FaultSpec("force", start_s=0.0, force_ned_n=(0.5, 0.0, -0.2)),
                         FaultSpec("torque", start_s=0.0, torque_frd_n_m=(0.0, 0.01, 0.02)))),  # fmt: skip
    ],
    ids=["clean", "wind-paper", "constant-faults"],
)
def test_the_compiled_span_steps_as_python_bit_for_bit(scenario: Scenario) -> None:
    a, b, phys = _pair(scenario)
    rng = random.Random(7)
    t_us = 0
    turns = set()
    for tick in range(3000):  # 6 s: take-off, spinning through the turns, a fall onto the ground
        cmd = _commands(rng, tick)
        armed = tick < 2900
        _python_steps([a], [cmd], [armed], t_us, 2)
        if phys.fly([b], [cmd], [armed], t_us, DT_US, DT_S, 2) is not None:  # (the faults start at 0: their first span)
            _python_steps([b], [cmd], [armed], t_us, 2)
        t_us += 2 * DT_US
        assert _fields(a) == _fields(b), tick
        turns.add(a.heading_turns)
    assert phys.steps >= 5998
    assert len(turns) >= 2, turns  # the heading crossed +-pi and its whole turns were counted
    assert b.on_ground and b.truth().position_m == a.truth().position_m


@needs_jit
def test_spans_with_gusts_or_a_timed_fault_due_are_left_to_python() -> None:
    gusty = Scenario(environment=EnvironmentSpec(gust_std_n=0.3))
    _a, b, phys = _pair(gusty)
    before = _fields(b)
    assert phys.fly([b], [(0.6,) * 4], [True], 0, DT_US, DT_S, 2) == "gusts are drawn in Python"
    assert _fields(b) == before  # nothing changed
    timed = Scenario(faults=(FaultSpec("motor", start_s=0.011, stop_s=0.02, motor=1, efficiency=0.5),))
    a, b, phys = _pair(timed)
    cmd = (0.7, 0.7, 0.7, 0.7)
    t_us = 0
    flown = []
    for _ in range(20):  # 40 ms: the fault starts and stops within
        _python_steps([a], [cmd], [True], t_us, 2)
        why = phys.fly([b], [cmd], [True], t_us, DT_US, DT_S, 2)
        if why is not None:
            assert why == "a fault acts on the physics in this span"
            _python_steps([b], [cmd], [True], t_us, 2)
        flown.append(why is None)
        t_us += 2 * DT_US
        assert _fields(a) == _fields(b)
    # compiled while no start or stop is due within the span (its end counts: the test is on the safe
    # side), in Python around the start at 11 ms and the stop at 20 ms, compiled after
    assert flown == [True] * 5 + [False] + [True] * 3 + [False, False] + [True] * 9, flown
    assert a.faults is not None and a.faults.started == b.faults.started == 1 and b.faults.stopped == 1  # type: ignore[union-attr]


@needs_jit
def test_a_diverging_swarm_fails_at_the_same_step_vehicle_and_time() -> None:
    calm = Scenario()
    blown = Scenario(environment=EnvironmentSpec(wind_force_ned_n=(1e308, 1e308, 0.0)))
    py = [plant_for(calm), plant_for(blown), plant_for(calm)]
    co = [plant_for(calm), plant_for(blown), plant_for(calm)]
    phys, why = cp.load(co, compile_new=True)
    assert phys is not None, why
    cmds = [(0.7,) * 4, (0.7,) * 4, (0.6,) * 4]
    with pytest.raises(DivergenceError) as e_py:
        _python_steps(py, cmds, [True] * 3, 4000, 3)
    with pytest.raises(DivergenceError) as e_co:
        phys.fly(co, cmds, [True] * 3, 4000, DT_US, DT_S, 3)
    assert str(e_co.value) == str(e_py.value) and e_co.value.time_s == e_py.value.time_s
    assert e_co.value.steps_done == 0 and e_co.value.vehicle == 1  # type: ignore[attr-defined]
    # the first vehicle flew the failing step, the third did not; the second stays where it failed
    for p, q in zip(py, co):
        assert _fields(p) == _fields(q)
    assert co[0]._t_s == 0.005 and co[2]._t_s == 0.0


@needs_jit
def test_a_swarm_steps_as_python_and_a_subset_leaves_the_others_alone() -> None:
    scs = [Scenario(seed=s, environment=EnvironmentSpec(wind_force_ned_n=(0.1 * s, 0.0, 0.0))) for s in range(4)]
    py = [plant_for(s) for s in scs]
    co = [plant_for(s) for s in scs]
    phys, _ = cp.load(co, compile_new=True)
    assert phys is not None
    rng = random.Random(3)
    t_us = 0
    for tick in range(500):
        cmds = [tuple(0.6 + rng.uniform(-0.05, 0.05) for _ in range(4)) for _ in scs]
        live = [0, 1, 3] if tick >= 250 else [0, 1, 2, 3]  # vehicle 3 (index 2) removed half-way
        _python_steps([py[i] for i in live], [cmds[i] for i in live], [True] * len(live), t_us, 2)
        assert phys.fly([co[i] for i in live], [cmds[i] for i in live], [True] * len(live), t_us, DT_US, DT_S, 2) is None
        t_us += 2 * DT_US
        assert [_fields(p) for p in py] == [_fields(q) for q in co], tick


def test_off_switch_and_help(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SMCPILOT_JIT", "0")
    phys, why = cp.load([RigidBodyPlant(Scenario().vehicle)], compile_new=True)
    assert phys is None and why == "SMCPILOT_JIT=0"
    r = subprocess.run([sys.executable, "-m", "sim_bridge.plants.compiled_physics", "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "Compile (and cache on disk) the simulator's physics" in r.stdout


@needs_jit
@pytest.mark.slow
def test_the_simulator_process_flies_the_same_compiled_and_in_python(tmp_path) -> None:  # type: ignore[no-untyped-def]
    cp.load([RigidBodyPlant(Scenario().vehicle)], compile_new=True)  # compiled and cached for the processes
    plan = ({"t_s": 0.0, "action": "takeoff", "alt_m": 2.0}, {"t_s": 3.0, "action": "goto", "north_m": 1.0, "east_m": 1.0, "alt_m": 2.0, "yaw_deg": 170.0},
            {"t_s": 7.0, "action": "land"})  # fmt: skip
    faults = (FaultSpec("motor", start_s=4.0, stop_s=5.0, motor=1, efficiency=0.8),)  # a span left to Python each way
    logs = {}
    for jit in ("wait", "off"):
        sitl, _ = fly_sitl(tmp_path, jit, 11.0, plan=plan, scenario=Scenario(faults=faults), sim_args=("--jit", jit), fc_args=("--jit", "off"))
        phys = sitl.sim_summary["physics"]  # type: ignore[index]
        if jit == "wait":
            assert phys["compiled"] and phys["compiled_steps"] > 9000 and 0 < phys["python_steps"] < 100, phys
            assert phys["states_encoded_compiled"] > 5000, phys  # (sim_bridge.state_encoder: the same log from its states too)
        else:
            assert not phys["compiled"] and phys["why_not"] == "--jit off" and phys["states_encoded_compiled"] == 0, phys
        logs[jit] = (tmp_path / jit / f"{jit}.tlog").read_bytes()
    assert len(logs["off"]) > 100_000 and logs["wait"] == logs["off"]


@needs_jit
def test_a_live_change_between_spans_reaches_the_compiled_rows() -> None:
    """A SIM_* parameter set between two states (a force, a motor's efficiency, the paper's
    disturbances) acts from the next span on, compiled as in Python; so does a reset."""
    a, b, phys = _pair(Scenario())
    cmd = (0.65, 0.65, 0.65, 0.65)
    t_us = 0
    changes = {50: ("SIM_DIST_FN", 0.8), 120: ("SIM_ENGINE_FAIL", 2.0), 121: ("SIM_ENGINE_MUL", 0.7), 200: ("SIM_PAPER_DIST", 1.0),
               260: ("SIM_DIST_FN", 0.0)}  # fmt: skip
    for tick in range(400):
        if tick in changes:
            for p in (a, b):
                p.faults.set_param(*changes[tick], t_us * 1e-6)  # type: ignore[union-attr]
        if tick == 300:
            for p in (a, b):
                p.reset(position_m=(1.0, 2.0, 3.0), yaw_rad=0.5, t_s=t_us * 1e-6)
        _python_steps([a], [cmd], [True], t_us, 2)
        assert phys.fly([b], [cmd], [True], t_us, DT_US, DT_S, 2) is None, tick
        t_us += 2 * DT_US
        assert _fields(a) == _fields(b), tick
    assert phys.steps == 800
