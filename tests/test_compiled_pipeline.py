"""The FC process's compiled pipeline (:mod:`fc.compiled_pipeline`): the same outputs bit for bit.

Oracle: the CPython pipeline itself. A :class:`fc.flight.FlightControl` with the compiled tick
attached and one without fly the same randomized inputs — arming, set-points with yaw, ALT_HOLD,
a parameter change, a landing to touchdown, an IMU for the law that measures acceleration — and
must give equal outputs and equal carried state after every tick. Then the real FC process in
lockstep SITL: ``--jit wait`` (the compiled pipeline cached by this test) and ``--jit off`` must
write the same ``.tlog`` byte for byte.
"""

from __future__ import annotations

import dataclasses
import math
import random

import pytest
from bits_helpers import needs_jit

from fc.compiled_pipeline import attach_compiled
from fc.config import FcConfig
from fc.flight import FlightControl, LawFault
from fc.pipeline import VehicleState
from smcpilot import jit
from smcpilot.vehicle import DEFAULT_VEHICLE
from tests.sitl_helpers import fly_sitl

HOVER = VehicleState(0.1, -0.2, 1.0, 0.0, 0.0, 0.0, 0.01, -0.02, 0.3, 0.0, 0.0, 0.0)


def _pair(controller: str) -> tuple[FlightControl, FlightControl]:
    plain = FlightControl(FcConfig(controller=controller), DEFAULT_VEHICLE)
    compiled = FlightControl(FcConfig(controller=controller), DEFAULT_VEHICLE)
    why = attach_compiled(compiled, compile_new=True)
    assert why is None, why
    assert compiled.compiled and not plain.compiled
    return plain, compiled


@needs_jit
@pytest.mark.parametrize("controller", ["adaptive_pid_smc", "se3_geometric", "indi"])
def test_the_compiled_pipeline_gives_the_cpython_outputs_bit_for_bit(controller: str) -> None:
    seed = 20261202
    rng = random.Random(seed)
    plain, compiled = _pair(controller)
    st = HOVER
    for f in (plain, compiled):
        f.arm(st)
        f.set_target(1.0, 0.5, 2.0, 0.7)
    touched_down = False
    for i in range(2500):
        # a vehicle wandering around the set-point; descending after the landing command
        drift = -0.004 if i >= 1600 else 0.0
        st = VehicleState(*(v + rng.gauss(0.0, 0.01) for v in st))
        st = st._replace(z_m=max(0.0, st.z_m + drift), vz_mps=drift / 0.002 * 0.01 if i >= 1600 else st.vz_mps)
        if i >= 1600 and st.z_m < 0.05:
            st = st._replace(z_m=0.0, vz_mps=0.0, vx_mps=0.0, vy_mps=0.0)
        accel = (rng.gauss(0.0, 0.5), rng.gauss(0.0, 0.5), -9.81 + rng.gauss(0.0, 0.2))
        if i == 400:
            for f in (plain, compiled):
                f.set_target(-1.0, 2.0, 3.0, -2.5)  # yaw through +-pi
        if i == 700:
            for f in (plain, compiled):
                f.position_hold = False  # ALT_HOLD
        if i == 900:
            cfg = dataclasses.replace(plain.config, pos_filter_omega_radps=plain.config.pos_filter_omega_radps * 1.5)
            for f in (plain, compiled):
                f.position_hold = True
                f.reconfigure(cfg)  # a parameter change in flight: the held parameters follow
        if i == 1600:
            for f in (plain, compiled):
                f.land()
        a = plain.step(st, 0.002, accel)
        b = compiled.step(st, 0.002, accel)
        assert a == b, f"tick {i} (seed {seed}): {a} != {b}"
        assert plain.armed == compiled.armed
        if i % 100 == 0:
            assert plain.pipeline_state == compiled.pipeline_state, f"tick {i} (seed {seed})"
        if not plain.armed:
            touched_down = True
            break
    assert compiled.compiled, "the compiled tick was detached"
    assert compiled.compiled_ticks > 1000
    assert touched_down, "the landing never touched down: the test did not reach the disarm path"
    assert plain.pipeline_state == compiled.pipeline_state


@needs_jit
def test_a_non_finite_command_is_flown_again_in_cpython_and_reported() -> None:
    plain, compiled = _pair("adaptive_pid_smc")
    for f in (plain, compiled):
        f.arm(HOVER)
        f.step(HOVER, 0.002)
    before = compiled.pipeline_state
    bad = HOVER._replace(phi_rad=math.nan)
    for f in (plain, compiled):
        with pytest.raises(LawFault, match="non-finite"):
            f.step(bad, 0.002)
    assert compiled.pipeline_state == before == plain.pipeline_state  # nothing kept
    assert compiled.law_faults == plain.law_faults == 1
    assert plain.step(HOVER, 0.002) == compiled.step(HOVER, 0.002)


@needs_jit
def test_a_law_change_in_flight_keeps_parity_or_detaches() -> None:
    plain, compiled = _pair("adaptive_pid_smc")
    for f in (plain, compiled):
        f.arm(HOVER)
        f.step(HOVER, 0.002)
    # the same law functions with other constants (the non-adaptive variant): still compiled, same outputs
    for f in (plain, compiled):
        f.reconfigure(dataclasses.replace(f.config, controller="pid_smc"))
    if compiled.compiled:
        assert plain.step(HOVER, 0.002) == compiled.step(HOVER, 0.002)
    # a law with other functions: the compiled tick cannot fly it; CPython takes over with the state
    state = compiled.pipeline_state
    for f in (plain, compiled):
        f.reconfigure(dataclasses.replace(f.config, controller="cascade_pid"))
    assert not compiled.compiled
    assert compiled.pipeline_state.x_r == state.x_r  # the references carry over
    assert plain.step(HOVER, 0.002) == compiled.step(HOVER, 0.002)


def test_the_jit_switch_off_flies_cpython(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SMCPILOT_JIT", "0")
    f = FlightControl(FcConfig(), DEFAULT_VEHICLE)
    assert attach_compiled(f, compile_new=True) == "SMCPILOT_JIT=0"
    assert not f.compiled


@needs_jit
@pytest.mark.parametrize("controller", ["adaptive_pid_smc", "se3_geometric", "indi"])
def test_the_fc_process_writes_the_same_log_compiled_and_in_cpython(tmp_path, controller: str) -> None:  # type: ignore[no-untyped-def]
    _pair(controller)  # compiles and caches the FC's pipeline for the law
    plan = ({"t_s": 0.0, "action": "takeoff", "alt_m": 2.0}, {"t_s": 4.0, "action": "goto", "north_m": 1.0, "east_m": 1.0, "alt_m": 2.0, "yaw_deg": 90.0},
            {"t_s": 8.0, "action": "land"})  # fmt: skip
    sitl_c, _ = fly_sitl(tmp_path, "compiled", 12.0, plan=plan, controller=controller, fc_args=("--jit", "wait"))
    sitl_p, _ = fly_sitl(tmp_path, "cpython", 12.0, plan=plan, controller=controller, fc_args=("--jit", "off"))
    pc, pp = sitl_c.fc_summary["pipeline"], sitl_p.fc_summary["pipeline"]
    assert pc["compiled"] and pc["compiled_ticks"] > 1000, pc
    # (fc.state_kernel: the same log from its decoded states and its encoded answers and records too)
    assert pc["states_decoded_compiled"] > 1000 and pc["answers_encoded_compiled"] > 1000, pc
    # (fc.lockstep_kernel: most ticks flown in one compiled call each; the take-off, the goto's
    # arrival and the touchdown are not plain and fly the ordinary way, in the same log; INDI
    # measures acceleration: the kernel gives it the IMU's)
    assert pc["lockstep_kernel_ticks"] > 1000 and pc["lockstep_kernel_ticks"] < pc["compiled_ticks"], pc
    assert pp["lockstep_kernel_ticks"] == 0, pp
    assert not pp["compiled"] and pp["why_not"] == "--jit off" and pp["states_decoded_compiled"] == pp["answers_encoded_compiled"] == 0, pp
    log_c = (tmp_path / "compiled" / "compiled.tlog").read_bytes()
    log_p = (tmp_path / "cpython" / "cpython.tlog").read_bytes()
    assert len(log_c) > 100_000
    assert log_c == log_p


def test_auto_leaves_a_short_lockstep_flight_in_cpython(tmp_path) -> None:  # type: ignore[no-untyped-def]
    sitl, _ = fly_sitl(tmp_path, "short", 2.0, fc_args=("--jit", "auto"))
    pipe = sitl.fc_summary["pipeline"]
    assert not pipe["compiled"] and "shorter than 60 s" in pipe["why_not"], pipe


def test_one_background_compile_at_a_time() -> None:
    from fc import compiled_pipeline as cp

    held = jit.compile_lock(blocking=False)  # as a compiling process holds it
    assert held is not None
    try:
        assert cp.compile_in_background("adaptive_pid_smc") is None  # nobody else starts
    finally:
        jit.release_compile_lock()
    pytest.importorskip("fcntl")
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "fc.compiled_pipeline", "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "compile and cache the FC's pipeline" in r.stdout
