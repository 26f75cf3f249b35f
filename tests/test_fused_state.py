"""The lockstep swarm's fused call (:mod:`sim_bridge.fused_state`: a vehicle's physics span and its
state datagram in one compiled call) against what the simulator did before it: the compiled span
(:meth:`CompiledPhysics.fly`) then :meth:`sim_bridge.app.SimVehicle.make_state`. The same datagram
bytes, sequence numbers and plant afterwards (state, acceleration, time, heading, step input, the
truth's memo, the observation cache, the faults' observation bookkeeping), bit for bit; the old
path wherever the observation is not the truth (sensor noise, a sensor fault) or the encoder leaves
the state to CPython (a NaN, a value beyond float32); the same divergence."""

from __future__ import annotations

import math
import random
from collections.abc import Callable

import pytest
from bits_helpers import bits, needs_jit

from fc.control.purity import function_problems
from sim_bridge.app import SimVehicle
from sim_bridge.build import plant_for
from sim_bridge.fused_state import compiled_fused
from sim_bridge.plants import compiled_physics as cp
from sim_bridge.plants.rigid_body import RigidBodyPlant
from sim_bridge.state_encoder import compiled_encoder
from smcpilot.errors import DivergenceError
from smcpilot.faults import FaultSpec
from smcpilot.frames import euler_from_quat, wrap_pi
from smcpilot.scenario import EnvironmentSpec, Scenario

DT_US = 1000
DT_S = 1.0 / 1000.0
N = 2  # physics steps a control period


class _Side:
    """One vehicle, its compiled physics and encoder, and its clock (µs)."""

    def __init__(self, scenario: Scenario, fused: bool) -> None:
        self.plant = plant_for(scenario)
        assert isinstance(self.plant, RigidBodyPlant)
        self.t_us = 0
        self.v = SimVehicle(self.plant, fc_url="udp:127.0.0.1:9", system_id=5, clock_us=lambda: self.t_us)
        self.v.encoder = compiled_encoder(5, compile_new=True)
        phys, why = cp.load([self.plant], compile_new=True)
        assert phys is not None and self.v.encoder is not None, why
        self.phys = phys
        if fused:
            phys.fused = compiled_fused(compile_new=True)
            assert phys.fused is not None
        self.fused_states = 0

    def period(self, cmd: tuple[float, ...], armed: bool) -> None:
        """A control period as the swarm loop flies it: one call fused, else fly then make_state."""
        v, t0 = self.v, self.t_us
        v.commands, v.armed = cmd, armed
        self.t_us = t0 + N * DT_US
        if self.phys.fused is not None and v.fly_and_make(self.phys, t0, DT_US, DT_S, N):
            self.fused_states += 1
            return
        if self.phys.fly([self.plant], [cmd], [armed], t0, DT_US, DT_S, N, count=False) is not None:
            for k in range(N):
                self.plant.step((t0 + k * DT_US) * 1e-6, DT_S, cmd, armed)
        v.make_state()

    def close(self) -> None:
        self.v.link.close()


def _after(s: _Side) -> tuple:
    """What the next readers of the plant and the link see."""
    p = s.plant
    memo = p._truth_memo
    assert memo is not None and memo[0] is p._s and memo[2] is p._accel and memo[1] == p._t_s
    f = p.faults
    book = None if f is None else (f._buf_n, f._last_obs_t, f._next_s, f.sensing, f.started, f.stopped, [bits(f._buf[k % len(f._buf)]) for k in range(max(0, f._buf_n - 3), f._buf_n)])
    return (b"".join(s.v.last_state), s.v.link.peek_seq(), bits(p._s), bits(p._accel), bits(p._t_s), bits(p._psi), bits(p._input),
            bits(memo[3]), bits(p._obs_cache), p._obs_cache is memo[3], bits(s.v.position_ned_m()), book)  # fmt: skip


def _fly_both(scenario: Scenario, ticks: int, commands: Callable[[int], tuple[float, ...]], *, start: Callable[[RigidBodyPlant], None] | None = None,
              armed_until: int | None = None) -> tuple[_Side, _Side]:  # fmt: skip
    old, new = _Side(scenario, False), _Side(scenario, True)
    try:
        if start is not None:
            start(old.plant)
            start(new.plant)
        for tick in range(ticks):
            cmd = commands(tick)
            armed = armed_until is None or tick < armed_until
            old.period(cmd, armed)
            new.period(cmd, armed)
            assert _after(new) == _after(old), tick
    finally:
        old.close()
        new.close()
    return old, new


def _flight(tick: int) -> tuple[float, ...]:
    """Take off, spin (the heading through +-pi), tilt, then cut to idle with a NaN motor and fall to the ground."""
    if tick < 150:
        return (0.7, 0.7, 0.7, 0.7)
    if tick < 700:
        base = 0.5 + 0.02 * math.sin(tick * 0.01)
        return (base + 0.2, base - 0.2, base + 0.2, base - 0.2)  # a strong yaw torque
    if tick < 800:
        return (0.55, 0.62, 0.58, 0.6)  # a tilt
    return (0.05, 0.05, 0.05, float("nan"))


@needs_jit
@pytest.mark.parametrize(
    "scenario",
    [
        Scenario(),
        Scenario(environment=EnvironmentSpec(wind_force_ned_n=(0.4, -0.3, 0.1), paper_disturbance=True)),
        Scenario(
            faults=(
                FaultSpec("motor", start_s=0.0, motor=2, efficiency=0.8),
                FaultSpec("force", start_s=0.0, force_ned_n=(0.5, 0.0, -0.2)),
                FaultSpec("torque", start_s=0.0, torque_frd_n_m=(0.0, 0.01, 0.02)),
            )
        ),  # fmt: skip
    ],
    ids=["clean", "wind-paper", "constant-faults"],
)
def test_the_fused_call_makes_the_same_bytes_and_plant(scenario: Scenario) -> None:
    _old, new = _fly_both(scenario, 1500, _flight, armed_until=1450)
    assert new.fused_states >= 1490, new.fused_states  # (the constant faults start in the first span: Python flies it)
    assert new.plant.on_ground and new.plant.heading_turns != 0


@needs_jit
@pytest.mark.parametrize("seed", range(6))
def test_random_states_and_commands(seed: int) -> None:
    """Tilted, spinning, moving, near the ground or high up, with random commands (armed or not)."""
    rng = random.Random(seed)

    def start(p: RigidBodyPlant) -> None:
        r = random.Random(seed)
        p.reset(position_m=(r.uniform(-50, 50), r.uniform(-50, 50), r.choice([0.0, 0.002, r.uniform(0, 100)])),
                yaw_rad=r.uniform(-math.pi, math.pi), roll_rad=r.uniform(-1.2, 1.2), pitch_rad=r.uniform(-1.4, 1.4),
                velocity_mps=(r.uniform(-5, 5), r.uniform(-5, 5), r.uniform(-3, 0.5)), body_rates_radps=(r.uniform(-8, 8), r.uniform(-8, 8), r.uniform(-12, 12)),
                rotor_speeds_radps=tuple(r.uniform(0, 900) for _ in range(4)))  # fmt: skip

    cmds = [tuple(rng.uniform(0.0, 1.0) for _ in range(4)) for _ in range(200)]
    _old, new = _fly_both(Scenario(seed=seed), 200, lambda k: cmds[k], start=start, armed_until=150 + seed)
    assert new.fused_states == 200


@needs_jit
def test_near_the_gimbal_lock_and_the_wrap() -> None:
    """Pitched to +-90 deg (the Euler angles' special case) and yawed across +-pi."""
    for pitch, yaw in ((math.pi / 2, math.pi - 1e-12), (-math.pi / 2, -math.pi), (1.0, math.pi)):

        def start(p: RigidBodyPlant, pitch: float = pitch, yaw: float = yaw) -> None:
            p.reset(position_m=(0.0, 0.0, 10.0), pitch_rad=pitch, yaw_rad=yaw)

        _fly_both(Scenario(), 5, lambda k: (0.0, 0.0, 0.0, 0.0), start=start, armed_until=0)


@needs_jit
def test_sensor_noise_falls_back_to_the_old_path() -> None:
    noisy = Scenario(seed=3, environment=EnvironmentSpec(noise=True))
    old, new = _Side(noisy, False), _Side(noisy, True)
    try:
        new.period((0.6,) * 4, True)  # (declined: flown and made as before)
        old.period((0.6,) * 4, True)
        before = _after(new)
        assert new.phys.fly_state(new.plant, (0.6,) * 4, True, 0, DT_US, DT_S, N, new.v.encoder, 9.81, 2000, 0) == "the environment's sensors add noise"
        assert _after(new) == before  # nothing changed
        for tick in range(100):
            old.period((0.66,) * 4, True)
            new.period((0.66,) * 4, True)
            assert _after(new) == _after(old), tick
        assert new.fused_states == 0
    finally:
        old.close()
        new.close()


@needs_jit
def test_a_sensor_fault_falls_back_from_the_observation_it_starts_at() -> None:
    """A gyro bias from 0.1 s and a position dropout (NaN) from 0.15 s to 0.2 s: fused before;
    declined in the span a timed fault starts or stops in (:func:`steady`) and while one acts; fused
    again after both stop; a live delay (which reads the observations kept meanwhile) likewise."""
    faults = (FaultSpec("sensor", start_s=0.1, stop_s=0.13, sensor="gyro", mode="bias", value=(0.1, -0.2, 0.05)),
              FaultSpec("sensor", start_s=0.15, stop_s=0.2, sensor="position", mode="dropout"))  # fmt: skip
    old, new = _Side(Scenario(faults=faults), False), _Side(Scenario(faults=faults), True)
    try:
        fused_at = []
        for tick in range(150):
            if tick in (120, 135):
                for s in (old, new):
                    s.plant.faults.set_param("SIM_POS_FAULT", 5.0 if tick == 120 else 0.0, s.t_us * 1e-6)  # type: ignore[union-attr]
                    s.plant.faults.set_param("SIM_POS_FAULT_V", 0.05, s.t_us * 1e-6)  # type: ignore[union-attr]
            n0 = new.fused_states
            old.period((0.66,) * 4, True)
            new.period((0.66,) * 4, True)
            assert _after(new) == _after(old), tick
            fused_at.append(new.fused_states > n0)
        # the bias starts at the observation of 0.1 s (tick 49) and acts until 0.13 s; the dropout from 0.15 s to 0.2 s
        assert all(fused_at[:49]) and not any(fused_at[50:65]) and not any(fused_at[75:99]) and all(fused_at[100:120]), fused_at
        assert not any(fused_at[120:135]) and all(fused_at[136:]), fused_at
        assert new.plant.faults.started >= 3 and new.plant.faults.stopped >= 3  # type: ignore[union-attr]
    finally:
        old.close()
        new.close()


@needs_jit
def test_an_observation_the_faults_change_after_the_span_is_made_in_cpython() -> None:
    """Should the faults change the very observation of the span's end (a sensor fault starting
    there, which the steady span rules out for timed faults), the span stays flown fused and the
    datagram is made from that observation, in CPython."""
    old, new = _Side(Scenario(), False), _Side(Scenario(), True)
    try:
        for s in (old, new):
            faults = s.plant.faults
            assert faults is not None
            real = faults.observe

            def observe(obs, real=real):  # type: ignore[no-untyped-def]
                seen = real(obs)
                return seen._replace(position_m=(seen.position_m[0] + 1.0, *seen.position_m[1:])) if 10 <= round(obs.t_s * 500) < 13 else seen

            faults.observe = observe  # type: ignore[method-assign]
        for tick in range(20):
            old.period((0.6,) * 4, True)
            new.period((0.6,) * 4, True)
            assert _after(new) == _after(old), tick  # (the changed position on the wire at ticks 9 .. 11)
            assert (new.plant._obs_cache is new.plant._truth_memo[2 + 1]) == (not 9 <= tick < 12), tick  # type: ignore[index]
        assert new.fused_states == 20
    finally:
        old.close()
        new.close()


@needs_jit
def test_a_nan_or_a_value_beyond_float32_is_made_in_cpython() -> None:
    """A NaN gravity (specific force NaN: the encoder refuses it, CPython packs it) gives CPython's
    bytes; a position beyond float32 raises as make_state does."""
    old, new = _Side(Scenario(), False), _Side(Scenario(), True)
    try:
        for s in (old, new):
            s.v._gravity = math.nan
        for tick in range(5):
            made = new.v.encoder.made  # type: ignore[union-attr]
            old.period((0.6,) * 4, True)
            new.period((0.6,) * 4, True)
            assert _after(new) == _after(old), tick
            assert new.v.encoder.made == made and len(new.v.last_state) == 4  # type: ignore[union-attr]
        assert new.fused_states == 5  # (flown fused, the states made in CPython)
        for s in (old, new):
            s.v._gravity = 9.81
            s.plant.reset(position_m=(1e39, 0.0, 5.0))
        errors = []
        for s in (old, new):
            with pytest.raises(Exception) as e:
                s.period((0.6,) * 4, True)
            errors.append((type(e.value), str(e.value)))
        assert errors[0] == errors[1]
        assert bits(new.plant._s) == bits(old.plant._s) and new.plant._t_s == old.plant._t_s
    finally:
        old.close()
        new.close()


@needs_jit
def test_divergence_raises_as_before() -> None:
    blown = Scenario(environment=EnvironmentSpec(wind_force_ned_n=(1e308, 1e308, 0.0)))
    old, new = _Side(blown, False), _Side(blown, True)
    try:
        with pytest.raises(DivergenceError) as e_old:
            old.phys.fly([old.plant], [(0.7,) * 4], [True], 4000, DT_US, DT_S, 3, count=False)
        with pytest.raises(DivergenceError) as e_new:
            new.v.commands, new.v.armed = (0.7,) * 4, True
            new.v.fly_and_make(new.phys, 4000, DT_US, DT_S, 3)
        assert str(e_new.value) == str(e_old.value) and e_new.value.time_s == e_old.value.time_s
        assert e_new.value.steps_done == e_old.value.steps_done  # type: ignore[attr-defined]
        for a, b in ((old.plant, new.plant),):
            assert bits((a._s, a._accel, a._psi, a._input, a._t_s)) == bits((b._s, b._accel, b._psi, b._input, b._t_s))
        assert new.v.last_state == () and new.v.link.peek_seq() == old.v.link.peek_seq()
    finally:
        old.close()
        new.close()


@needs_jit
def test_not_loaded_or_not_steady_changes_nothing() -> None:
    new = _Side(Scenario(environment=EnvironmentSpec(gust_std_n=0.3)), False)
    try:
        before = _after(new) if new.plant._truth_memo is not None else None
        assert new.phys.fly_state(new.plant, (0.6,) * 4, True, 0, DT_US, DT_S, N, new.v.encoder, 9.81, 2000, 0) == "the fused physics and state is not loaded"
        new.phys.fused = compiled_fused(compile_new=True)
        assert new.phys.fly_state(new.plant, (0.6,) * 4, True, 0, DT_US, DT_S, N, new.v.encoder, 9.81, 2000, 0) == "gusts are drawn in Python"
        assert new.plant._t_s == 0.0 and new.v.last_state == () and (before is None or _after(new) == before)
    finally:
        new.close()


def test_the_truths_angles_are_pure() -> None:
    """What the fused call compiles besides the span and the encoder follows the pure style."""
    assert function_problems(euler_from_quat) == [] and function_problems(wrap_pi) == []


def test_without_the_jit_there_is_no_fused_call(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SMCPILOT_JIT", "0")
    assert compiled_fused(compile_new=True) is None


_TRIO = """
name = "trio"
duration_s = 2.0
[[step]]
t_s = 0.0
action = "takeoff"
alt_m = 2.0
[swarm]
count = 3
[[fault]]
kind = "motor"
start_s = 1.0
motor = 1
efficiency = 0.7
"""


@needs_jit
def test_a_busy_polling_lockstep_swarm_writes_the_same_logs_fused(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[no-untyped-def]
    """The simulator process (SimBridgeApp._run_lockstep_swarm) with the fused call (``--jit wait``)
    and without anything compiled (``--jit off``): every FC's log byte for byte."""
    from ground.sitl import Sitl, SitlOptions

    path = tmp_path / "trio.toml"
    path.write_text(_TRIO, encoding="utf-8")
    sc = Scenario.from_toml(path)
    monkeypatch.setattr(Sitl, "_spinning", lambda self: True)  # (whatever this machine's cores: states sent ahead)
    logs = {}
    for jit in ("wait", "off"):
        (tmp_path / jit).mkdir()
        opts = SitlOptions(scenario=sc, timed=True, lockstep=True, tlog=tmp_path / jit / "trio.tlog", log_dir=tmp_path / jit, watchdog_s=10.0,
                           fc_processes=1, sim_args=("--jit", jit))  # fmt: skip
        with Sitl(opts) as sitl:
            sitl.wait(timeout_s=120.0)
        assert "--spin-s" not in sitl.sim.proc.args
        phys = sitl.sim_summary["physics"]  # type: ignore[index]
        if jit == "wait":  # (the spans around the fault's start in Python, and each vehicle's first state)
            assert phys["states_fused"] > 3 * 990, phys
        else:
            assert phys["states_fused"] == 0, phys
        logs[jit] = [p.read_bytes() for p in sitl.tlogs]
    assert len(logs["off"]) == 3 and all(len(b) > 50_000 for b in logs["off"])
    assert logs["wait"] == logs["off"]
