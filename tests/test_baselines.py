"""The fair baselines (docs/baselines.md): the cascaded PID's filters, D term and integrator clamp,
the position loop's authority clamp, and the tuning claims, measured in simulated time."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from fc.config import FC_CASCADE, FcConfig
from fc.control.cascade_pid import CascadePid, CascadePidParams, cascade_pid_anti_windup, cascade_pid_step, lowpass_step
from fc.flight import FlightControl
from fc.params import ParamStore
from lab.tuning.bandwidth import Hover, bandwidth_hz, roll_frequency_response
from lab.tuning.stiffness import HoldFlight, wind_offset_m
from smcpilot.errors import InvalidGainError, ParamError
from smcpilot.model import PaperModel
from smcpilot.vehicle import DEFAULT_VEHICLE

MODEL = PaperModel.from_vehicle()
DT = 0.002
HOVER_MEAS = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0)
LEVEL_REF = (0.0,) * 12 + (3.0, 0.0, 0.0, 0.0)


def _law(**kw) -> CascadePid:
    return CascadePid(MODEL, replace(FC_CASCADE, **kw))


# -- the cascade's filters ----------------------------------------------------------------------------
@pytest.mark.parametrize("f_hz", [5.0, 20.0, 80.0])
def test_gyro_low_pass_step_response_is_the_analytic_first_order_one(f_hz: float) -> None:
    """A unit rate step through the gyro filter: w_f(k dt) = 1 - exp(-2 pi f k dt), the sampled
    first-order low-pass being exact for a held input."""
    law = _law(gyro_filter_hz=f_hz, kd_rate=(0.0, 0.0, 0.0))
    state: tuple[float, ...] = (0.0,) * 10
    meas = (0.0, 1.0, 0.0, -2.0, 0.0, 0.5, 3.0, 0.0)
    for k in range(1, 200):
        _, state = cascade_pid_step(meas, LEVEL_REF, state, DT, law.consts)
        want = 1.0 - math.exp(-2.0 * math.pi * f_hz * k * DT)
        assert state[4] == pytest.approx(want, rel=1e-12, abs=1e-15)
        assert state[5] == pytest.approx(-2.0 * want, rel=1e-12, abs=1e-15)
        assert state[6] == pytest.approx(0.5 * want, rel=1e-12, abs=1e-15)
    # the time constant: 63.2 % after 1 / (2 pi f)
    assert lowpass_step(0.0, 1.0, 2.0 * math.pi * f_hz, 1.0 / (2.0 * math.pi * f_hz)) == pytest.approx(1.0 - math.exp(-1.0), rel=1e-12)
    # 0 Hz: off, the raw value
    assert lowpass_step(0.3, 1.0, 0.0, DT) == 1.0


def test_d_term_low_pass_step_response_and_sign() -> None:
    """A ramp of the measured rate (constant angular acceleration a) with the gyro filter off: the
    D state is LPF_d(a) = a (1 - exp(-w_d t)), and u falls by kd D / b1 against the P term alone."""
    a = 3.0  # rad/s^2
    fd = 20.0
    law = _law(gyro_filter_hz=0.0, d_filter_hz=fd, kd_rate=(0.25, 0.0, 0.0), ki_inner=(0.0, 0.0, 0.0, 0.0))
    bare = _law(gyro_filter_hz=0.0, d_filter_hz=fd, kd_rate=(0.0, 0.0, 0.0), ki_inner=(0.0, 0.0, 0.0, 0.0))
    state = bare_state = (0.0,) * 10
    for k in range(1, 100):
        meas = (0.0, a * k * DT, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0)
        u, state = cascade_pid_step(meas, LEVEL_REF, state, DT, law.consts)
        ub, bare_state = cascade_pid_step(meas, LEVEL_REF, bare_state, DT, bare.consts)
        d = a * (1.0 - math.exp(-2.0 * math.pi * fd * k * DT))
        assert state[7] == pytest.approx(d, rel=1e-9)
        assert (u[0] - ub[0]) * MODEL.b1 == pytest.approx(-0.25 * d, rel=1e-9)


def test_d_acts_on_the_measurement_not_on_the_error() -> None:
    """A step of the rate command (reference rate x_d') moves u by the P term only: no derivative
    kick; the same step of the measured rate kicks the D term."""
    law = _law()
    kp = FC_CASCADE.k_inner[0]
    state = law.initial_state(HOVER_MEAS)
    u0, s0 = cascade_pid_step(HOVER_MEAS, LEVEL_REF, state, DT, law.consts)
    stepped = (0.0, 0.5) + LEVEL_REF[2:]
    u1, s1 = cascade_pid_step(HOVER_MEAS, stepped, state, DT, law.consts)
    assert s1[4:] == s0[4:], "the filters saw nothing"
    assert (u1[0] - u0[0]) * MODEL.b1 == pytest.approx(kp * 0.5, rel=1e-12)
    # the measurement stepping by 0.5 rad/s instead: the D term reacts
    meas = (0.0, 0.5) + HOVER_MEAS[2:]
    _, s2 = cascade_pid_step(meas, LEVEL_REF, state, DT, law.consts)
    wg, wd = law.consts.gyro_w_radps, law.consts.d_w_radps
    w_f = 0.5 * (1.0 - math.exp(-wg * DT))
    assert s2[4] == pytest.approx(w_f, rel=1e-12)
    assert s2[7] == pytest.approx((1.0 - math.exp(-wd * DT)) * w_f / DT, rel=1e-12)


def test_integrator_clamp_and_anti_windup() -> None:
    """A constant rate error: the I term grows as ki e t up to i_max and stays there; it unwinds as
    soon as the error reverses; a limited channel freezes its integrator but not its filters."""
    imax = 4.0
    law = _law(i_max=(imax, imax, imax, 1.0), gyro_filter_hz=0.0)
    ki = FC_CASCADE.ki_inner[0]
    meas = (0.0, -0.1, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0)  # rate error +0.1 rad/s on roll
    state: tuple[float, ...] = (0.0,) * 10
    for k in range(1, 1500):
        _, state = cascade_pid_step(meas, LEVEL_REF, state, DT, law.consts)
        assert ki * state[0] == pytest.approx(min(ki * 0.1 * k * DT, imax), rel=1e-9)
    assert ki * state[0] == pytest.approx(imax)
    back = (0.0, 0.1) + meas[2:]
    _, after = cascade_pid_step(back, LEVEL_REF, state, DT, law.consts)
    assert after[0] == pytest.approx(state[0] - 0.1 * DT, rel=1e-12)
    prev = (1.0, 2.0, 3.0, 4.0) + (0.0,) * 6
    new = tuple(float(i) for i in range(10, 20))
    assert cascade_pid_anti_windup(prev, new, (True, False, True, False)) == (1.0, 11.0, 3.0, 13.0) + new[4:]
    # the continuous form stops at the clamp too
    d, _ = law.derivatives(meas, LEVEL_REF, state)
    assert d[0] == 0.0


def test_cascade_params_validate_and_map_to_parameters() -> None:
    with pytest.raises(InvalidGainError, match="d_filter_hz"):
        CascadePidParams(kd_rate=(0.1, 0.0, 0.0))
    with pytest.raises(InvalidGainError, match="gyro_filter_hz"):
        CascadePidParams(gyro_filter_hz=-1.0)
    with pytest.raises(InvalidGainError, match="i_max"):
        CascadePidParams(i_max=(1.0, math.nan, 1.0, 1.0))
    with pytest.raises(InvalidGainError, match="kd_rate"):
        CascadePidParams(kd_rate=(0.1, 0.1))
    store = ParamStore(FcConfig(controller="cascade_pid"))
    assert store.value("INS_GYRO_FILTER") == FC_CASCADE.gyro_filter_hz == 20.0
    assert store.value("ATC_RAT_PIT_D") == FC_CASCADE.kd_rate[1]
    store.set("ATC_ANG_PIT_P", 4.5)
    store.set("PSC_VELZ_IMAX", 3.0)
    assert store.config.cascade.k_outer == (3.0, 4.5, 4.0, 2.0) and store.config.cascade.i_max[3] == 3.0
    store.set("ATC_RAT_RLL_D", 0.0)
    store.set("ATC_RAT_PIT_D", 0.0)
    store.set("ATC_RAT_FLTD", 0.0)
    with pytest.raises(ParamError, match="ATC_RAT_YAW_D.*d_filter_hz"):
        store.set("ATC_RAT_YAW_D", 0.1)
    assert store.config.cascade.kd_rate == (0.0, 0.0, 0.0), "a refused value changes nothing"
    # a live change reaches the flying law
    fl = FlightControl(FcConfig(controller="cascade_pid"), DEFAULT_VEHICLE)
    fl.reconfigure(store.config)
    assert fl.params.law.k_outer[1] == 4.5 and fl.params.law.d_w_radps == 0.0 and len(fl.pipeline_state.law) == 10


# -- the tuning, measured --------------------------------------------------------------------------------
def test_bandwidth_interpolation_of_an_analytic_first_order_loop() -> None:
    fc = 0.8
    freqs = (0.1, 0.2, 0.4, 0.7, 1.0, 2.0)
    gains = [1.0 / math.hypot(1.0, f / fc) for f in freqs]
    assert bandwidth_hz(freqs, gains) == pytest.approx(fc, rel=0.02)
    assert bandwidth_hz(freqs, [1.0] * len(freqs)) is None


def test_cascade_roll_bandwidth_matches_the_pid_smc() -> None:
    """The documented tuning: the FC's cascade has the FC's PID-SMC's -3 dB roll bandwidth (within 10 %)."""
    freqs = (0.35, 0.5, 0.6, 0.7, 0.85)
    hov = Hover(settle_s=0.5, cycles=2, lead_cycles=1)
    bw = {}
    for law in ("adaptive_pid_smc", "cascade_pid"):
        gains = [roll_frequency_response(FcConfig(controller=law), f, hov)[0] for f in freqs]
        bw[law] = bandwidth_hz(freqs, gains)
    assert bw["adaptive_pid_smc"] is not None and bw["cascade_pid"] is not None, bw
    assert bw["cascade_pid"] == pytest.approx(bw["adaptive_pid_smc"], rel=0.10), bw
    # and the old cascade (angle P 6) was much faster: the measurement sees the gain
    fast = replace(FcConfig(controller="cascade_pid"), cascade=replace(FC_CASCADE, k_outer=(6.0, 6.0, 4.0, 2.0)))
    assert roll_frequency_response(fast, 0.85, hov)[0] > 0.85 > roll_frequency_response(FcConfig(controller="cascade_pid"), 0.85, hov)[0]


def test_no_steady_offset_in_a_1p5_n_wind() -> None:
    """1.5 N from the north (3.1 m/s^2 on 0.486 kg, within the 5 m/s^2 authority): the position loop's
    integrator takes it all. The old 2 m/s^2 clamp (PSC_INT_MAX 2) leaves a visible offset."""
    flight = HoldFlight(duration_s=40.0, settle_s=30.0, window_s=5.0)
    assert wind_offset_m(flight, 1.5) < 0.002
    old_clamp = replace(flight, params=(("PSC_INT_MAX", 2.0),))
    assert wind_offset_m(old_clamp, 1.5) > 0.1
