"""The pure hot path (fc.pipeline, the laws' module-level steps, the mixer, the model equations)
against the public wrappers and against each other: same results, no hidden state."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fc.config import FC_CASCADE, FcConfig
from fc.control import CascadePid, PidSmc, PidSmcParams, SignSmc
from fc.control.base import integrators_anti_windup
from fc.control.cascade_pid import cascade_pid_output, cascade_pid_step
from fc.control.pid_smc import (
    AdaptationBounds,
    pid_smc_anti_windup,
    pid_smc_initial_state,
    pid_smc_law,
    pid_smc_step,
    pid_smc_step_measured,
)
from fc.control.sign_smc import sign_smc_step
from fc.flight import FlightControl, VehicleState
from fc.mixer import Mixer, mix
from fc.pipeline import PipelineInputs, PipelineState, pipeline_reset, pipeline_step
from smcpilot import model as M
from smcpilot.model import PaperModel
from smcpilot.typos import MODEL_TYPOS
from smcpilot.vehicle import DEFAULT_VEHICLE


def _f(lo: float, hi: float):
    return st.floats(min_value=lo, max_value=hi, allow_nan=False, allow_infinity=False)


meas_st = st.tuples(_f(-1.0, 1.0), _f(-3.0, 3.0), _f(-1.0, 1.0), _f(-3.0, 3.0), _f(-2.0, 2.0), _f(-3.0, 3.0), _f(0.0, 5.0), _f(-2.0, 2.0))
ref_st = st.lists(_f(-1.5, 1.5), min_size=16, max_size=16).map(tuple)
state_st = st.tuples(
    *[_f(-2.0, 2.0)] * 4, _f(-0.3, 0.3), _f(-0.3, 0.3), _f(-0.02, 0.02), _f(2.0, 12.0), *[_f(0.0, 3.0)] * 4
)
accel_st = st.tuples(*[_f(-20.0, 20.0)] * 4)
dt_st = st.sampled_from((0.001, 0.002, 0.01))
MODEL = PaperModel.from_vehicle()


def bits(x):
    """A value with every float as its exact bits (so -0.0 != 0.0 and NaN == NaN)."""
    if isinstance(x, float):
        return x.hex()
    if isinstance(x, tuple):
        return tuple(bits(v) for v in x)
    return x


# -- the model equations: one copy, callable on the model or on its flat constants ---------------------
@pytest.mark.parametrize("typos", [frozenset(), MODEL_TYPOS])
def test_model_functions_on_consts_equal_the_methods(typos) -> None:
    model = PaperModel.from_vehicle(typos=typos)
    k = model.consts()
    assert k.z_drift_typo == ("z-drift" in typos) and k.fdot_typo == ("fdot" in typos)
    r = random.Random(1)
    for _ in range(200):
        x = [r.uniform(-3.0, 3.0) for _ in range(11)]
        u = (r.uniform(-1, 1), r.uniform(-1, 1), r.uniform(-0.1, 0.1), r.uniform(0, 20))
        assert M.drift(k, *x[:5]) == model.drift(*x[:5])
        assert M.drift_rates(k, *x) == model.drift_rates(*x)
        assert M.unmix(k, *u) == model.unmix(*u)
        assert M.omega_bar_of_inputs(k, *u) == model.omega_bar_of_inputs(*u)
        assert M.tilt_cos(x[0], x[1], 0.05) == model.tilt_cos(x[0], x[1], 0.05)


# -- the laws ---------------------------------------------------------------------------------------------
@settings(max_examples=150, deadline=None)
@given(meas=meas_st, ref=ref_st, state=state_st, dt=dt_st, adaptive=st.booleans())
def test_pure_pid_smc_step_equals_the_wrapper_and_euler_of_derivatives(meas, ref, state, dt, adaptive) -> None:
    ctrl = PidSmc(MODEL, PidSmcParams(adaptive=adaptive))
    u, new, diag = pid_smc_step(meas, ref, state, dt, ctrl.consts)
    assert bits((u, new, diag)) == bits(ctrl.step(meas, ref, state, dt))
    # The sampled form is forward Euler of the continuous form (no input limits, no projection here).
    d, diag_c = ctrl.derivatives(meas, ref, state)
    euler = tuple(x + dt * dx for x, dx in zip(state, d))
    if all(c >= 0.0 for c in euler[8:]):
        assert bits(new) == bits(euler)
    assert bits((diag.s, diag.sigma, diag.chi_hat, diag.u_dot)) == bits((diag_c.s, diag_c.sigma, diag_c.chi_hat, diag_c.u_dot))
    assert u == new[4:8]


@settings(max_examples=100, deadline=None)
@given(meas=meas_st, ref=ref_st, state=state_st, dt=dt_st, accel=accel_st)
def test_pure_pid_smc_oracle_step_uses_the_measured_accelerations(meas, ref, state, dt, accel) -> None:
    oracle = PidSmc(MODEL, PidSmcParams(sigma_source="oracle"))
    nominal = PidSmc(MODEL, PidSmcParams())
    assert bits(pid_smc_step_measured(meas, ref, state, dt, oracle.consts, accel)) == bits(oracle.step(meas, ref, state, dt, accel))
    # Without accelerations, or with "model" constants, the measured ones are ignored.
    assert bits(oracle.step(meas, ref, state, dt)) == bits(pid_smc_step(meas, ref, state, dt, oracle.consts))
    assert bits(pid_smc_law(meas, ref, state, nominal.consts, accel, True)) == bits(pid_smc_law(meas, ref, state, nominal.consts, accel, False))


@settings(max_examples=100, deadline=None)
@given(meas=meas_st, ref=ref_st, state=state_st, dt=dt_st)
def test_pure_pid_smc_step_with_limits_and_bounds(meas, ref, state, dt) -> None:
    params = PidSmcParams(
        adaptation=AdaptationBounds(dead_zone=0.2, leakage_per_s=0.3, chi_hat_min=0.1, chi_hat_max=2.0),
        u_min=(-0.1, -0.1, -0.005, 4.0),
        u_max=(0.1, 0.1, 0.005, 10.0),
    )
    ctrl = PidSmc(MODEL, params)
    u, new, diag = pid_smc_step(meas, ref, state, dt, ctrl.consts)
    assert bits((u, new, diag)) == bits(ctrl.step(meas, ref, state, dt))
    for i in range(4):
        assert params.u_min[i] <= new[4 + i] <= params.u_max[i]
        free = state[4 + i] + dt * diag.u_dot[i]
        if not params.u_min[i] <= free <= params.u_max[i]:
            assert new[i] == state[i] and new[8 + i] == state[8 + i]  # clamped: int S and chi_hat frozen
        else:
            assert new[4 + i] == free and 0.1 <= new[8 + i] <= 2.0


@settings(max_examples=100, deadline=None)
@given(prev=state_st, new=state_st, realised=accel_st, limited=st.tuples(*[st.booleans()] * 4))
def test_pure_anti_windup(prev, new, realised, limited) -> None:
    out = pid_smc_anti_windup(prev, new, realised, limited)
    assert out == PidSmc(MODEL).anti_windup(prev, new, realised, limited)
    for i in range(4):
        if limited[i]:
            assert (out[i], out[4 + i], out[8 + i]) == (prev[i], realised[i], prev[8 + i])
        else:
            assert (out[i], out[4 + i], out[8 + i]) == (new[i], new[4 + i], new[8 + i])
    assert integrators_anti_windup(prev, new, limited) == tuple(prev[i] if limited[i] else new[i] for i in range(4))


@settings(max_examples=100, deadline=None)
@given(meas=meas_st, ref=ref_st, state=st.tuples(*[_f(-2.0, 2.0)] * 10), dt=dt_st)
def test_pure_baseline_steps_equal_the_wrappers(meas, ref, state, dt) -> None:
    # the plain cascade (no filters): u is algebraic, the integrators a forward-Euler step
    cp = CascadePid(MODEL)
    u, new = cascade_pid_step(meas, ref, state, dt, cp.consts)
    assert bits((u, new)) == bits(cp.step(meas, ref, state, dt)[:2])
    assert u == cascade_pid_output(meas, ref, state, cp.consts)[0] == cp.command(meas, ref, state)
    d, _ = cp.derivatives(meas, ref, state)
    assert bits(new[:4]) == bits(tuple(x + dt * dx for x, dx in zip(state[:4], d[:4])))
    assert new[4:7] == (meas[1], meas[3], meas[5])  # no gyro filter: the raw rates
    # the FC's cascade (filters, D, clamp): the wrapper is the pure step; u is the output on the filtered state
    fc = CascadePid(MODEL, FC_CASCADE)
    u, new = cascade_pid_step(meas, ref, state, dt, fc.consts)
    assert bits((u, new)) == bits(fc.step(meas, ref, state, dt)[:2])
    assert bits(u) == bits(cascade_pid_output(meas, ref, state[:4] + new[4:], fc.consts)[0])
    ss = SignSmc(MODEL)
    u, new, s = sign_smc_step(meas, ref, state, dt, ss.consts)
    uw, neww, diag = ss.step(meas, ref, state, dt)
    assert bits((u, new, s)) == bits((uw, neww, diag.sigma))
    d, _ = ss.derivatives(meas, ref, state)
    assert bits(new) == bits(tuple(x + dt * dx for x, dx in zip(state, d)))


def test_pure_initial_state_is_hover_trim() -> None:
    ctrl = PidSmc(MODEL)
    s0 = pid_smc_initial_state((0.1, 0.0, -0.2, 0.0, 1.0, 0.0, 2.0, 0.0), ctrl.consts)
    assert s0 == ctrl.initial_state((0.1, 0.0, -0.2, 0.0, 1.0, 0.0, 2.0, 0.0))
    assert s0[:4] == (0.0,) * 4 and s0[8:] == (0.5,) * 4
    assert s0[7] == pytest.approx(MODEL.mass_kg * MODEL.gravity_mps2 / (math.cos(0.1) * math.cos(-0.2)), rel=1e-12)
    with_u0 = PidSmc(MODEL, PidSmcParams(u0=(1, 2, 3, 4)))
    assert pid_smc_initial_state((0.0,) * 8, with_u0.consts)[4:8] == (1.0, 2.0, 3.0, 4.0)


# -- the mixer --------------------------------------------------------------------------------------------
@settings(max_examples=200, deadline=None)
@given(u=st.tuples(_f(-5, 5), _f(-5, 5), _f(-0.5, 0.5), _f(-10, 60)))
def test_pure_mix_equals_the_mixer(u) -> None:
    mixer = Mixer(DEFAULT_VEHICLE)
    assert bits(mix(mixer.params, *u)) == bits(mixer.mix(*u))


@pytest.mark.parametrize("bad", [0, 1, 2, 3])
def test_pure_mix_of_non_finite_input_is_safe_and_flags_every_channel(bad) -> None:
    p = Mixer(DEFAULT_VEHICLE).params
    u = [0.01, -0.01, 0.001, 8.0]
    u[bad] = math.nan
    motors, realised, limited = mix(p, *u)
    fixed = list(u)
    fixed[bad] = 4.0 * p.kp * 0.5 * (p.lo + p.hi) if bad == 3 else 0.0
    assert limited == (True,) * 4
    assert (motors, realised) == mix(p, *fixed)[:2]


# -- the pipeline -----------------------------------------------------------------------------------------
def _states(n: int, seed: int) -> list[VehicleState]:
    r = random.Random(seed)
    out = []
    z = 0.0
    for _k in range(n):
        z = max(0.0, z + r.uniform(-0.01, 0.03))
        out.append(VehicleState(r.uniform(-0.1, 0.1), r.uniform(-0.1, 0.1), z, r.uniform(-0.2, 0.2), r.uniform(-0.2, 0.2),
                                r.uniform(-0.3, 0.3), r.uniform(-0.05, 0.05), r.uniform(-0.05, 0.05), r.uniform(-3.2, 3.2),
                                r.uniform(-0.5, 0.5), r.uniform(-0.5, 0.5), r.uniform(-0.5, 0.5)))  # fmt: skip
    return out


@pytest.mark.parametrize("controller", ["adaptive_pid_smc", "pid_smc", "cascade_pid", "sign_smc"])
def test_pipeline_step_is_what_flight_control_steps_and_is_pure(controller) -> None:
    cfg = FcConfig(controller=controller)
    fl = FlightControl(cfg, DEFAULT_VEHICLE)
    states = _states(300, 4)
    fl.arm(states[0])
    fl.set_target(1.0, -2.0, 3.0, 2.5)
    p = fl.params
    law = fl.law_functions
    ps = pipeline_reset(states[0], p, law)
    assert ps == fl.pipeline_state
    for k, s in enumerate(states):
        if k == 150:
            fl.position_hold = False
        if k == 200:
            fl.land()
        cmd = PipelineInputs(1.0, -2.0, 3.0, fl._psi_target, True, fl.landing, fl.position_hold, cfg.speed_max_xy_mps)
        new, out = pipeline_step(ps, s, cmd, p, 0.002, law)
        again = pipeline_step(ps, s, cmd, p, 0.002, law)
        assert bits(again) == bits((new, out)), "the same inputs give the same outputs"
        assert isinstance(new, PipelineState)
        o = fl.step(s, 0.002)
        assert bits((o.motors, o.u, o.limited, o.ref)) == bits((out[0], out[1], out[2], out[8]))
        assert bits(fl.pipeline_state) == bits(new)
        assert o.diag.u == out[6]
        assert fl.law_state == new.law and len(new.law) == len(fl.law.state_names)
        ps = new


def test_pipeline_disarmed_is_motors_off_and_state_unchanged() -> None:
    fl = FlightControl(FcConfig(), DEFAULT_VEHICLE)
    s = _states(1, 0)[0]
    ps = pipeline_reset(s, fl.params, fl.law_functions)
    cmd = PipelineInputs(0.0, 0.0, 1.0, 0.0, False, False, True, 3.0)
    new, out = pipeline_step(ps, s, cmd, fl.params, 0.002, fl.law_functions)
    assert new is ps and out[0] == (0.0,) * 4 and out[2] == (False,) * 4 and all(math.isnan(r) for r in out[8])


def test_pipeline_touchdown_is_reported_after_land_detect_s_on_the_ground() -> None:
    cfg = FcConfig()
    fl = FlightControl(cfg, DEFAULT_VEHICLE)
    ground = VehicleState(*(0.0,) * 12)
    ps = pipeline_reset(ground, fl.params, fl.law_functions)
    cmd = PipelineInputs(0.0, 0.0, 0.0, 0.0, True, True, True, 3.0)
    n = 0
    while True:
        ps, out = pipeline_step(ps, ground, cmd, fl.params, 0.002, fl.law_functions)
        n += 1
        if out[9]:
            break
        assert n < 1000
    assert ps.landed_s >= cfg.land_detect_s and n == math.ceil(cfg.land_detect_s / 0.002 - 1e-9)
    # The wrapper disarms on it, like before.
    fl.arm(ground)
    fl.land()
    for _ in range(n):
        fl.step(ground, 0.002)
    assert not fl.armed and fl.position_hold and fl.speed_xy_mps is None
