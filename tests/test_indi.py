"""INDI (fc/control/indi.py, docs/indi.md): the filter against scipy, the increment against the
paper model, the pure-function rules and numba's bits, and closed-loop flights through the real FC
pipeline (take-off, hold, landing, a position and yaw step, a 30 % motor loss, sensor noise)."""

from __future__ import annotations

import contextlib
import math
import random
import types
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from bits_helpers import bits
from scipy import signal

from fc.config import FcConfig
from fc.control import indi as indi_mod
from fc.control import registry
from fc.control.indi import (
    INDI,
    INDI_FUNCTIONS,
    INDI_STATE_N,
    INDI_STATE_NAMES,
    Filter2,
    IndiConsts,
    IndiParams,
    filter2_zoh,
    indi_anti_windup,
    indi_filter,
    indi_initial_state,
    indi_step,
)
from fc.control.law import PARAM_NAME_MAX, LawContext, validate_law
from fc.control.purity import function_problems
from fc.flight import FlightControl
from fc.params import config_for
from fc.pipeline import DOB_OFF
from lab.runner import InProcessRun, fly
from sim_bridge.build import plant_for
from smcpilot.errors import InvalidGainError
from smcpilot.model import PaperModel, tilt_cos
from smcpilot.scenario import EnvironmentSpec, Scenario
from smcpilot.vehicle import DEFAULT_VEHICLE

#: the law by its built-in name.
LAW = "indi"
ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "examples" / "scenarios"
MODEL = PaperModel.from_vehicle()
RATE_HZ = 500.0
DT = 1.0 / RATE_HZ


def consts(**changes: float) -> IndiConsts:
    return INDI.consts(LawContext(DEFAULT_VEHICLE, MODEL, RATE_HZ), replace(IndiParams(), **changes))


def _leaf_types(x: object) -> list[type]:
    return [t for v in x for t in _leaf_types(v)] if isinstance(x, tuple) else [type(x)]


# -- the law as declared --------------------------------------------------------------------------
def test_the_law_loads_by_its_reference_and_declares_its_parameters() -> None:
    law = registry.resolve(LAW)
    assert law.name == "indi" and law.stage == "attitude" and law.prefix == "INDI"
    assert validate_law(INDI) is INDI
    names = law.param_names()
    assert len(names) == 12 and all(n.startswith("INDI_") and len(n) <= PARAM_NAME_MAX for n in names)
    assert law.observer_default == "none" and law.diagnostics == ("u_dot",)
    assert len(INDI_STATE_NAMES) == INDI_STATE_N == len(indi_initial_state((0.0,) * 8, consts()))
    p = law.params_from_values({"INDI_KP_RP": 20.0, "INDI_WN_Z": 15.0})
    assert p.kp_rp == 20.0 and p.wn_z == 15.0 and p.kd_rp == IndiParams().kd_rp
    with pytest.raises(InvalidGainError, match="zeta"):
        IndiParams(zeta=0.0)
    with pytest.raises(InvalidGainError, match="kp_rp"):
        IndiParams(kp_rp=math.nan)
    # the flight controller flies it without the disturbance observer (docs/indi.md: u_prev)
    fl = FlightControl(FcConfig(controller=LAW), DEFAULT_VEHICLE)
    assert fl.params.observer.mode == DOB_OFF
    # the constants are flat numbers: what a compiled hot path takes
    assert set(_leaf_types(fl.params.law)) == {float}


# -- (a) against independent references -----------------------------------------------------------
@pytest.mark.parametrize(("wn", "zeta", "dt"), [(100.0, 0.55, 0.002), (20.0, 0.55, 0.002), (50.0, 1.3, 0.004), (300.0, 0.3, 0.001)])
def test_filter_is_the_exact_zero_order_hold_discretisation(wn: float, zeta: float, dt: float) -> None:
    """H(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2) driven by a held random input: every sample equals
    scipy's continuous-time simulation (lsim, zero-order-hold input) and the coefficients equal
    cont2discrete's; a constant input settles at its value with zero slope."""
    c = filter2_zoh(wn, zeta, dt)
    a = np.array([[0.0, 1.0], [-wn * wn, -2.0 * zeta * wn]])
    b = np.array([[0.0], [wn * wn]])
    ad, bd, *_ = signal.cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), dt, method="zoh")
    assert np.allclose([[c.a11, c.a12], [c.a21, c.a22]], ad, rtol=1e-11, atol=1e-13)
    assert np.allclose([c.b1, c.b2], bd[:, 0], rtol=1e-11, atol=1e-13)
    r = random.Random(7)
    n = 300
    x = [r.gauss(0.0, 1.0) if k % 37 else 5.0 for k in range(n)]
    y, yd = 0.3, -2.0
    ours = [(y, yd)]
    for xk in x:
        y, yd = indi_filter(y, yd, xk, c)
        ours.append((y, yd))
    t = np.arange(n + 1) * dt
    _, _, xs = signal.lsim(signal.StateSpace(a, b, np.eye(2), np.zeros((2, 1))), np.array(x + [0.0]), t, X0=[0.3, -2.0], interp=False)
    scale = max(1.0, float(np.max(np.abs(xs[:, 1]))))
    assert np.allclose(np.array(ours)[:, 0], xs[:, 0], rtol=1e-9, atol=1e-9)
    assert np.allclose(np.array(ours)[:, 1], xs[:, 1], rtol=1e-9, atol=1e-9 * scale)
    slowest = wn * (zeta - math.sqrt(max(zeta * zeta - 1.0, 0.0)))  # the slower pole's rate, 1/s
    for _ in range(int(30.0 / (slowest * dt))):
        y, yd = indi_filter(y, yd, 1.5, c)
    assert y == pytest.approx(1.5, abs=1e-9) and yd == pytest.approx(0.0, abs=1e-6)


def test_actuator_model_is_the_exact_first_order_lag_and_its_mean() -> None:
    """The modelled actuator after a tick is the first-order lag's exact response to the held
    u_prev, and what enters the filter is its exact mean over the tick (what the finite-difference
    acceleration averages over)."""
    tau = DEFAULT_VEHICLE.motor_time_constant_s
    k = consts()
    assert k.lag_a == pytest.approx(math.exp(-DT / tau), rel=1e-15)
    # integrate the lag finely (trapezoid over an analytic-free Euler path at 1 us) from act0 toward u
    act0, u = 0.2, 1.0
    n = 2000
    h = DT / n
    a, area = act0, 0.0
    for _ in range(n):
        a_next = a + h * (u - a) / tau
        area += 0.5 * (a + a_next) * h
        a = a_next
    assert u + (act0 - u) * k.lag_a == pytest.approx(a, rel=1e-5)
    assert u + (act0 - u) * k.lag_b == pytest.approx(area / DT, rel=1e-5)
    # modelled as instantaneous (INDI_LAG_SCL 0): the actuator is u_prev
    k0 = consts(lag_scale=0.0)
    assert (k0.lag_a, k0.lag_b) == (0.0, 0.0)
    assert consts(lag_scale=2.0).lag_a == pytest.approx(math.exp(-DT / (2.0 * tau)), rel=1e-15)


def _paper_accel(x: tuple[float, ...], u: tuple[float, float, float, float], d: tuple[float, float, float, float]) -> tuple[float, ...]:
    """d/dt of (phi, phi', theta, theta', psi, psi', z, z') on smcpilot.model's dynamics + d."""
    phi, phid, th, thd, _psi, psid, _z, zd = x
    ob = MODEL.omega_bar_of_inputs(*u)
    a = MODEL.accelerations(phi, phid, th, thd, psid, zd, u[0], u[1], u[2], u[3], ob)
    return (phid, a[0] + d[0], thd, a[1] + d[1], psid, a[2] + d[2], zd, a[3] + d[3])


def _rk4(x: tuple[float, ...], u: tuple[float, float, float, float], d: tuple[float, float, float, float], h: float) -> tuple[float, ...]:
    k1 = _paper_accel(x, u, d)
    k2 = _paper_accel(tuple(a + 0.5 * h * b for a, b in zip(x, k1)), u, d)
    k3 = _paper_accel(tuple(a + 0.5 * h * b for a, b in zip(x, k2)), u, d)
    k4 = _paper_accel(tuple(a + h * b for a, b in zip(x, k3)), u, d)
    return tuple(a + h / 6.0 * (p + 2.0 * q + 2.0 * r + s) for a, p, q, r, s in zip(x, k1, k2, k3, k4))


def _paper_loop(
    k: IndiConsts, x: tuple[float, ...], st: tuple[float, ...], act: tuple[float, float, float, float], ref: tuple[float, ...], seconds: float
) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, float, float, float], list[tuple[float, ...]]]:
    """INDI at 500 Hz on smcpilot.model's dynamics with D_CONST, the actuators through the rotors'
    first-order lag (exact at 2 kHz, midpoint value held in each RK4 step), no mixer: (final state,
    law state, last command, the state after every tick)."""
    tau = DEFAULT_VEHICLE.motor_time_constant_s
    sub = 4
    e_lag = math.exp(-DT / sub / tau)
    u_prev = act
    path = []
    for _ in range(int(round(seconds * RATE_HZ))):
        u, st, _ = indi_step(x, ref, st, DT, k, (0.0,) * 4, u_prev)
        for _ in range(sub):
            x = _rk4(x, tuple(c + (a - c) * math.sqrt(e_lag) for a, c in zip(act, u)), D_CONST, DT / sub)
            act = tuple(c + (a - c) * e_lag for a, c in zip(act, u))
        u_prev = u
        path.append(x)
    return x, st, u_prev, path


D_CONST = (3.0, -2.0, 0.4, -1.2)  # rad/s^2 x3, m/s^2


def _equilibrium(phi: float, theta: float, k: IndiConsts) -> tuple[tuple[float, float, float, float], tuple[float, ...]]:
    """The input holding the paper model at rest at (phi, theta) against D_CONST, and the law's
    state after a long time there (previous rates 0, actuators and their filters at that input)."""
    ctc = math.cos(phi) * math.cos(theta)
    u0 = (-D_CONST[0] / MODEL.b1, -D_CONST[1] / MODEL.b2, -D_CONST[2] / MODEL.b3, MODEL.mass_kg * (MODEL.gravity_mps2 - D_CONST[3]) / ctc)
    state = (0.0,) * 4 + u0 + (0.0,) * 8 + (u0[0], 0.0, u0[1], 0.0, u0[2], 0.0, ctc * u0[3], 0.0) + (1.0,) * 4 + (1.0,)
    assert _paper_accel((phi, 0.0, theta, 0.0, 0.7, 0.0, 2.0, 0.0), u0, D_CONST)[1::2] == pytest.approx((0.0,) * 4, abs=1e-12)
    return u0, state


@pytest.mark.parametrize(("phi", "theta"), [(0.0, 0.0), (0.2, -0.15)])
def test_one_step_realises_the_commanded_acceleration_on_the_paper_model(phi: float, theta: float) -> None:
    """A perfect model, no actuator lag, the vehicle at rest against a constant disturbance: one
    INDI step commands the input under which smcpilot.model's dynamics (integrated over the tick)
    accelerate by exactly nu = x_d'' + kd (x_d' - x') + kp (x_d - x) on every channel."""
    k = consts(lag_scale=0.0)
    u0, state = _equilibrium(phi, theta, k)
    x0 = (phi, 0.0, theta, 0.0, 0.7, 0.0, 2.0, 0.0)
    ref = (phi + 0.05, 0.3, 2.0, 0.0, theta - 0.02, -0.2, -1.0, 0.0, 0.7 + 0.1, 0.05, 0.5, 0.0, 2.0 - 0.03, 0.4, 1.5, 0.0)
    u, new, diag = indi_step(x0, ref, state, DT, k, (9.0, 9.0, 9.0, 9.0), u0)
    nu = [ref[4 * i + 2] + k.kd[i] * (ref[4 * i + 1] - x0[2 * i + 1]) + k.kp[i] * (ref[4 * i] - x0[2 * i]) for i in range(4)]
    x = x0
    for _ in range(20):
        x = _rk4(x, u, D_CONST, DT / 20)
    realised = [(x[2 * i + 1] - x0[2 * i + 1]) / DT for i in range(4)]
    # what remains is the drift's own change within the tick (the gyroscopic and drag terms grow
    # with the rates, from zero; the tilt moves g_z a little): its mean, half its change
    ob = MODEL.omega_bar_of_inputs(*u)
    f0 = MODEL.drift(x0[1], x0[3], x0[5], x0[7], ob)
    f1 = MODEL.drift(x[1], x[3], x[5], x[7], ob)
    assert [r - 0.5 * (b - a) for r, a, b in zip(realised, f0, f1)] == pytest.approx(nu, abs=5e-5), (realised, nu)
    assert realised == pytest.approx(nu, abs=5e-3)
    assert max(abs(v) for v in nu) > 1.0  # a real demand, on every channel
    assert diag[3] == pytest.approx(tuple((u[i] - u0[i]) / DT for i in range(4)), rel=1e-12)
    assert diag[:3] == ((0.0,) * 4,) * 3
    # the increment is the demand over G: the model's effectiveness, the tilt on z
    ctc = tilt_cos(phi, theta, 0.05)
    assert [(u[i] - u0[i]) for i in range(3)] == pytest.approx([nu[0] / MODEL.b1, nu[1] / MODEL.b2, nu[2] / MODEL.b3], rel=1e-9)
    assert u[3] - u0[3] == pytest.approx(MODEL.mass_kg * nu[3] / ctc, rel=1e-9)
    assert new[:4] == (0.0, 0.0, 0.0, 0.0) and new[24:] == (1.0, 1.0, 1.0, 1.0, 1.0)


def test_the_first_step_after_initialisation_differences_nothing() -> None:
    """The pipeline initialises a law with the rates zeroed (on arming, and in flight after a change
    of law): the first step must not take (x' - 0) / dt as an acceleration. It commands hover trim
    plus nu / G; the second differences the rates it has seen."""
    k = consts()
    st = indi_initial_state((0.1, 0.0, -0.05, 0.0, 0.3, 0.0, 3.0, 0.0), k)
    assert st[28] == 0.0
    meas = (0.1, 0.8, -0.05, -0.6, 0.3, 0.4, 3.0, 0.5)
    ref = (0.1, 0.8, 0.0, 0.0, -0.05, -0.6, 0.0, 0.0, 0.3, 0.4, 0.0, 0.0, 3.0, 0.5, 0.0, 0.0)  # on the reference: nu = 0
    hover = k.hover_n / tilt_cos(0.1, -0.05, k.tilt_min)
    u, new, _ = indi_step(meas, ref, st, DT, k, (0.0,) * 4, (0.0, 0.0, 0.0, hover))
    assert u == pytest.approx((0.0, 0.0, 0.0, hover), rel=1e-12, abs=1e-12)
    assert new[:4] == (0.8, -0.6, 0.4, 0.5) and new[28] == 1.0
    meas2 = (0.1, 0.9, -0.05, -0.6, 0.3, 0.4, 3.0, 0.5)
    _, new2, _ = indi_step(meas2, ref, new, DT, k, (0.0,) * 4, u)
    assert new2[8] == pytest.approx(k.f_rp.b1 * 0.1 / DT, rel=1e-12)  # the filtered 50 rad/s^2 roll step


def test_increments_vanish_at_steady_state() -> None:
    """At the equilibrium with the reference met the command is the realised input (no increment);
    and in closed loop on the paper model, with the rotors' lag and a constant disturbance and no
    integrator anywhere, the tracking error and the increments go to zero while u settles at the
    input that cancels the disturbance."""
    k = consts()
    u0, state = _equilibrium(0.1, -0.05, k)
    x0 = (0.1, 0.0, -0.05, 0.0, 0.7, 0.0, 2.0, 0.0)
    ref = (0.1, 0.0, 0.0, 0.0, -0.05, 0.0, 0.0, 0.0, 0.7, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0)
    u, new, _ = indi_step(x0, ref, state, DT, k, (0.0,) * 4, u0)
    assert u == pytest.approx(u0, rel=1e-12, abs=1e-15)
    assert new == pytest.approx(state, rel=1e-12, abs=1e-12)
    # closed loop: actuators through the first-order lag (tau of the vehicle), physics at 2 kHz
    target = (0.12, -0.08, 0.5, 3.0)
    ref = (target[0], 0.0, 0.0, 0.0, target[1], 0.0, 0.0, 0.0, target[2], 0.0, 0.0, 0.0, target[3], 0.0, 0.0, 0.0)
    x0 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0)
    x, st, u_prev, _ = _paper_loop(k, x0, indi_initial_state(x0, k), MODEL.hover_inputs(), ref, 6.0)
    errors = [target[i] - x[2 * i] for i in range(4)]
    assert max(abs(e) for e in errors) < 1e-5, errors
    u_next, _, _ = indi_step(x, ref, st, DT, k, (0.0,) * 4, u_prev)
    assert max(abs(a - b) for a, b in zip(u_next, u_prev)) < 1e-6
    ctc = math.cos(target[0]) * math.cos(target[1])
    want = (-D_CONST[0] / MODEL.b1, -D_CONST[1] / MODEL.b2, -D_CONST[2] / MODEL.b3, MODEL.mass_kg * (MODEL.gravity_mps2 - D_CONST[3]) / ctc)
    assert u_next == pytest.approx(want, rel=1e-3)


def test_synchronised_filters_leave_the_tracking_response_alone() -> None:
    """Smeur's point: with the actuator filtered by the same H as the acceleration, the response to
    nu is the actuators' alone, A nu; H only shapes the rejection of a changing disturbance. A roll
    step (feedback only, from the equilibrium against D_CONST) flown with H at 25 and at 150 rad/s
    gives the same trajectory within 0.5 % of the step; the second-order reference model
    kp / (s^2 + kd s + kp) is followed within 3 % (the actuators' 20 ms lag)."""
    step = 0.05
    ref = (step, 0.0, 0.0, 0.0) + (0.0,) * 4 + (0.7, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0)
    x0 = (0.0, 0.0, 0.0, 0.0, 0.7, 0.0, 2.0, 0.0)
    paths = []
    for wn in (25.0, 150.0):
        k = consts(wn_rp=wn)
        u0, state = _equilibrium(0.0, 0.0, k)
        paths.append([x[0] for x in _paper_loop(k, x0, state, u0, ref, 1.5)[3]])
    assert max(abs(a - b) for a, b in zip(*paths)) < 0.005 * step
    kp, kd = IndiParams().kp_rp, IndiParams().kd_rp
    t = np.arange(1, len(paths[0]) + 1) * DT
    _, model_step = signal.step(signal.lti([kp], [1.0, kd, kp]), T=t)
    assert max(abs(a - b) for a, b in zip(paths[1], step * model_step)) < 0.03 * step


def test_anti_windup_keeps_the_state_and_the_increment_builds_on_what_was_realised() -> None:
    """Nothing winds up: the anti-windup keeps the state, and a limited (smaller) realised input
    moves the next command by the filtered difference, not by the unrealised remainder."""
    k = consts()
    st = indi_initial_state((0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0), k)
    prev = tuple(float(i) for i in range(INDI_STATE_N))
    assert indi_anti_windup(prev, st, (0.0,) * 4, (True,) * 4, k) is st
    ref = (0.0,) * 12 + (3.0, 0.0, 0.0, 0.0)
    meas = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0)
    hover = MODEL.hover_inputs()
    u_free, _, _ = indi_step(meas, ref, st, DT, k, (0.0,) * 4, (0.5, 0.0, 0.0, hover[3]))
    u_lim, _, _ = indi_step(meas, ref, st, DT, k, (0.0,) * 4, (0.2, 0.0, 0.0, hover[3]))
    c = k.f_rp
    assert u_free[0] - u_lim[0] == pytest.approx(c.b1 * (1.0 - k.lag_b) * 0.3, rel=1e-9)


# -- (b) the pure-function rules, and numba's bits ------------------------------------------------
_PURE = set(INDI_FUNCTIONS) | {tilt_cos}


@pytest.mark.parametrize("fn", INDI_FUNCTIONS, ids=lambda f: f.__name__)
def test_pure_function_follows_the_rules(fn: types.FunctionType) -> None:
    """The rules of fc/control/purity.py (what tests/test_compilable.py holds every hot-path function to)."""
    problems = function_problems(fn, _PURE)
    assert not problems, problems


@contextlib.contextmanager
def compiled():
    """INDI's pure functions (and the model's tilt_cos they call) as numba dispatchers, in the
    module's namespace too (undone after)."""
    numba = pytest.importorskip("numba")
    jit = {fn: numba.njit(fn) for fn in _PURE}
    with pytest.MonkeyPatch.context() as mp:
        for name, value in list(vars(indi_mod).items()):
            if isinstance(value, types.FunctionType) and value in jit:
                mp.setattr(indi_mod, name, jit[value])
        yield jit


def test_compiled_functions_give_the_same_bits() -> None:
    pytest.importorskip("numba")
    r = random.Random(11)
    ks = (consts(), consts(adapt_rate=20.0), consts(lag_scale=0.0, zeta=1.2, wn_rp=30.0), consts()._replace(tilt_min=0.3))
    cases = []
    for i in range(400):
        k = ks[i % len(ks)]
        meas = tuple(r.uniform(-1.2, 1.2) for _ in range(6)) + (r.uniform(0.0, 5.0), r.uniform(-2.0, 2.0))
        ref = tuple(r.uniform(-2.0, 2.0) for _ in range(16))
        st = tuple(r.uniform(-3.0, 3.0) for _ in range(24)) + tuple(r.uniform(0.3, 3.0) for _ in range(4)) + (float(i % 2),)
        u_prev = (r.uniform(-1.0, 1.0), r.uniform(-1.0, 1.0), r.uniform(-0.05, 0.05), r.uniform(0.0, 12.0))
        limited = tuple(r.random() < 0.3 for _ in range(4))
        dt = (0.002, 0.004, 0.001)[i % 3]
        want = (
            indi_step(meas, ref, st, dt, k, u_prev, u_prev),
            indi_initial_state(meas, k),
            indi_anti_windup(st, st[::-1], u_prev, limited, k),
            indi_filter(st[0], st[1], meas[0], k.f_yaw),
        )
        cases.append((meas, ref, st, dt, k, u_prev, limited, want))
    with compiled() as jit:
        for meas, ref, st, dt, k, u_prev, limited, want in cases:
            got = (
                jit[indi_step](meas, ref, st, dt, k, u_prev, u_prev),
                jit[indi_initial_state](meas, k),
                jit[indi_anti_windup](st, st[::-1], u_prev, limited, k),
                jit[indi_filter](st[0], st[1], meas[0], k.f_yaw),
            )
            assert bits(got) == bits(want)
        assert isinstance(jit[indi_filter](0.0, 0.0, 1.0, Filter2(1.0, 0.0, 0.0, 1.0, 0.0, 0.0)), tuple)


# -- (c) closed-loop flights through the FC pipeline --------------------------------------------------
def _fly(sc: Scenario, every: int = 5) -> InProcessRun:
    return fly(config_for(sc), sc.vehicle, plant_for(sc), sc.plan, sc.duration_s, record_every=every)


def _scenario(name: str, **changes: object) -> Scenario:
    return Scenario.from_toml(SCENARIOS / f"{name}.toml").with_changes(controller=LAW, params=(), **changes)


def _window(run: InProcessRun, t0: float, t1: float) -> list:
    return [(t, s, o) for t, s, o in zip(run.t_s, run.states, run.outputs) if t0 <= t < t1]


def _motor_rms_pct(rows: list) -> float:
    """RMS deviation of each motor command from its mean, % of the range, averaged over the motors."""
    m = np.array([o.motors for _, _, o in rows])
    return float(np.mean(np.sqrt(np.mean((m - m.mean(axis=0)) ** 2, axis=0)))) * 100.0


@pytest.mark.parametrize("noise", [False, True], ids=["clean", "noise"])
def test_take_off_hold_and_land(noise: bool) -> None:
    """examples/scenarios/hover.toml: take-off to 3 m, hold, LAND at 14 s. Clean: at 3 m by 5 s
    (within 2 cm), hold error < 2 mm over 8-14 s (measured 0.2 mm). With --noise the error of the
    state the FC sees stays < 10 cm (measured 45 mm; the cascade and the PID-SMC 45 mm too) and
    the motors' noise < 1.3 % RMS (measured 0.97 %). Both land and disarm."""
    run = _fly(_scenario("hover", environment=EnvironmentSpec(noise=noise)))
    at5 = next(s for t, s in zip(run.t_s, run.states) if t >= 5.0)
    assert abs(at5.z_m - 3.0) < 0.02 + 0.03 * noise
    hold = _window(run, 8.0, 14.0)
    err = max(math.sqrt(s.x_m**2 + s.y_m**2 + (s.z_m - 3.0) ** 2) for _, s, _ in hold)
    tilt = max(max(abs(s.phi_rad), abs(s.theta_rad)) for _, s, _ in hold)
    if noise:
        assert err < 0.10 and math.degrees(tilt) < 2.0
        assert _motor_rms_pct(hold) < 1.3
    else:
        assert err < 0.002 and math.degrees(tilt) < 0.05
    landed = [t for t, text in run.events if text == "Landed: disarmed"]
    assert len(landed) == 1 and 14.0 < landed[0] < 20.0, run.events
    assert not run.outputs[-1].armed and all(o.armed for t, _, o in _window(run, 0.1, landed[0] - 0.1))


def test_position_and_yaw_step_across_180_deg() -> None:
    """examples/scenarios/step-yaw.toml: (4 N, -3 E, 3 m) with yaw 170 deg at 6 s, then -170 deg
    at 16 s (the short way, 20 deg across +-180). Measured: within 10 cm by 10.6 s (the PID-SMC
    10.6 s), 1.5 mm and 0.00 deg at 15.9 s, tilt 18.7 deg, height within 5 mm, yaw never nearer
    than 170 deg to 0 after 16 s."""
    run = _fly(_scenario("step-yaw"))
    target = (4.0, 3.0)  # north 4, east -3 in the paper frame (x north, y west)

    def pos_err(s) -> float:
        return math.hypot(s.x_m - target[0], s.y_m - target[1])

    def yaw_err_deg(s, yaw_ned_deg: float) -> float:
        return math.degrees(math.remainder(s.psi_rad + math.radians(yaw_ned_deg), 2.0 * math.pi))

    first = _window(run, 11.0, 16.0)
    assert max(pos_err(s) for _, s, _ in first) < 0.1
    t, s, _ = first[-1]
    assert pos_err(s) < 0.01 and abs(yaw_err_deg(s, 170.0)) < 0.5
    after = _window(run, 16.0, 25.0)
    assert min(abs(math.remainder(s.psi_rad, 2.0 * math.pi)) for _, s, _ in after) > math.radians(165.0), "the short way"
    end = run.states[-1]
    assert pos_err(end) < 0.01 and abs(yaw_err_deg(end, -170.0)) < 0.5
    flown = _window(run, 6.0, 25.0)
    assert max(abs(s.z_m - 3.0) for _, s, _ in flown) < 0.02
    assert math.degrees(max(max(abs(s.phi_rad), abs(s.theta_rad)) for _, s, _ in flown)) < 25.0


def test_30_percent_motor_loss_at_hover() -> None:
    """examples/scenarios/motor-loss.toml: motor 1 at 70 % from 10 s. INDI measures the lost
    torque as angular acceleration and re-trims within its filter's time: measured (defaults)
    26 cm largest deviation, 7.9 deg tilt, 0.5 deg yaw, 3 mm left over 20-25 s; the cascaded PID at
    the same roll bandwidth 90 cm and 15 deg (the PID-SMC with its observer 27 cm)."""
    sc = _scenario("motor-loss")
    run = _fly(sc)
    assert all(o.armed for o in run.outputs)
    after = _window(run, 10.0, 25.0)
    dev = max(math.sqrt(s.x_m**2 + s.y_m**2 + (s.z_m - 3.0) ** 2) for _, s, _ in after)
    tilt = math.degrees(max(max(abs(s.phi_rad), abs(s.theta_rad)) for _, s, _ in after))
    assert dev < 0.35 and tilt < 10.0
    assert max(abs(math.degrees(s.psi_rad)) for _, s, _ in after) < 2.0
    assert max(math.sqrt(s.x_m**2 + s.y_m**2 + (s.z_m - 3.0) ** 2) for _, s, _ in _window(run, 20.0, 25.0)) < 0.01
    # the roll input re-trimmed to the lost thrust's torque (no integrator): u_phi = -0.3 m g / 2.8
    u_phi = np.mean([o.pipeline.u[0] for _, _, o in _window(run, 20.0, 25.0)])
    # (thrust, roll and yaw balanced: Kp w1^2 = m g / 2.8, Kp w3^2 = m g / 4)
    assert u_phi == pytest.approx(-0.3 * MODEL.mass_kg * MODEL.gravity_mps2 / 2.8, rel=0.02)
    cascade = _fly(sc.with_changes(controller="cascade_pid"))
    dev_c = max(math.sqrt(s.x_m**2 + s.y_m**2 + (s.z_m - 3.0) ** 2) for _, s, _ in _window(cascade, 10.0, 25.0))
    assert dev < 0.5 * dev_c, (dev, dev_c)
