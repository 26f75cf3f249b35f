"""The disturbance observer (fc/control/observer.py) against exact discrete oracles, and its use in the pipeline."""

from __future__ import annotations

import dataclasses
import math

import pytest

from fc.config import FcConfig
from fc.control.observer import observer_estimate, observer_reset, observer_update
from fc.control.pid_smc import DISTURBANCE_ESTIMATES, PidSmc, PidSmcParams
from fc.flight import FlightControl, observer_authority
from fc.pipeline import VehicleState
from smcpilot.errors import ConfigError, InvalidGainError
from smcpilot.model import PaperModel, drift, omega_bar_of_inputs
from smcpilot.vehicle import DEFAULT_VEHICLE

INF4 = (math.inf,) * 4


def _channel_accel(model: tuple, meas: tuple, u: tuple) -> tuple[float, float, float, float]:
    """f + g u of the nominal model at ``meas`` for input ``u`` (the observer's own a_nom)."""
    wbar = omega_bar_of_inputs(model, *u)
    f = drift(model, meas[1], meas[3], meas[5], meas[7], wbar)
    gz = math.cos(meas[0]) * math.cos(meas[2]) / model[0]
    return (f[0] + model[13] * u[0], f[1] + model[14] * u[1], f[2] + model[15] * u[2], f[3] + gz * u[3])


@pytest.mark.parametrize("lag_tau_s", [0.0, 0.02])
def test_constant_disturbance_is_estimated_with_the_exact_first_order_response(lag_tau_s: float) -> None:
    """A plant that is the nominal model (with the same rotor lag) plus a constant d: d_hat(k) =
    d (1 - (1 - L dt)^k) exactly, whatever the input does, and the lag never reads as a disturbance."""
    model = PaperModel.from_vehicle().consts()
    w = (40.0, 30.0, 20.0, 10.0)
    d = (5.0, -3.0, 0.7, 1.5)
    dt = 0.002
    lag_a = math.exp(-dt / lag_tau_s) if lag_tau_s else 0.0
    lag_b = lag_tau_s * (1.0 - lag_a) / dt if lag_tau_s else 0.0
    hover = model[0] * model[1]
    meas = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0]
    u_eff = [0.0, 0.0, 0.0, hover]
    obs = observer_reset(meas, u_eff, w)
    for k in range(300):
        d_hat = observer_estimate(obs, meas, w, INF4)
        factor = 1.0 - (1.0 - w[0] * dt) ** k
        for i in range(4):
            want = d[i] * (1.0 - (1.0 - w[i] * dt) ** k)
            assert d_hat[i] == pytest.approx(want, rel=1e-9, abs=1e-9), (k, i, factor)
        # an input that keeps changing (a step at k = 50 on every channel)
        u = (0.02, -0.01, 0.001, hover + 0.3) if k >= 50 else (0.0, 0.0, 0.0, hover)
        v = [u[i] + (u_eff[i] - u[i]) * lag_b for i in range(4)]  # the period's average input
        a = _channel_accel(model, tuple(meas), tuple(v))
        obs = observer_update(obs, tuple(meas), d_hat, u, model, w, 0.05, 1.0 / model[0], lag_a, lag_b, dt)
        # the plant: the same model, the same lag, plus d; rates integrate exactly, angles stay small
        for i, j in enumerate((1, 3, 5, 7)):
            meas[j] += dt * (a[i] + d[i])
        u_eff = [u[i] + (u_eff[i] - u[i]) * lag_a for i in range(4)]


def test_estimate_is_clamped_and_a_clamp_does_not_wind_up() -> None:
    model = PaperModel.from_vehicle().consts()
    w = (50.0,) * 4
    d_max = (2.0, 2.0, 2.0, 2.0)
    meas = [0.0] * 8
    u = (0.0, 0.0, 0.0, model[0] * model[1])
    obs = observer_reset(meas, u, w)
    dt = 0.002
    d = 10.0  # far above the clamp, for 0.5 s
    for _ in range(250):
        d_hat = observer_estimate(obs, meas, w, d_max)
        assert all(abs(x) <= 2.0 for x in d_hat)
        a = _channel_accel(model, tuple(meas), u)
        obs = observer_update(obs, tuple(meas), d_hat, u, model, w, 0.05, 1.0 / model[0], 0.0, 0.0, dt)
        meas[1] += dt * (a[0] + d)
    assert observer_estimate(obs, meas, w, d_max)[0] == 2.0
    # the disturbance goes: the estimate leaves the clamp within a few steps, not after unwinding 0.5 s
    for _ in range(10):
        d_hat = observer_estimate(obs, meas, w, d_max)
        a = _channel_accel(model, tuple(meas), u)
        obs = observer_update(obs, tuple(meas), d_hat, u, model, w, 0.05, 1.0 / model[0], 0.0, 0.0, dt)
        meas[1] += dt * a[0]
    assert observer_estimate(obs, meas, w, d_max)[0] < 2.0 * (1 - 50 * dt) ** 9 + 1e-9


def test_disturbance_estimate_options_are_validated() -> None:
    assert DISTURBANCE_ESTIMATES == ("none", "sigma", "lumped", "input")
    with pytest.raises(InvalidGainError, match="disturbance_estimate"):
        PidSmcParams(disturbance_estimate="magic")  # type: ignore[arg-type]
    with pytest.raises(InvalidGainError, match="observer_bandwidth_radps"):
        PidSmcParams(observer_bandwidth_radps=(1.0, 1.0, 0.0, 1.0))
    with pytest.raises(InvalidGainError, match="observer_motor_tau_s"):
        PidSmcParams(observer_motor_tau_s=math.nan)
    with pytest.raises(ConfigError, match="disturbance_estimate"):
        FcConfig(disturbance_estimate="magic")
    with pytest.raises(ConfigError, match="dob_bandwidth_att_radps"):
        FcConfig(dob_bandwidth_att_radps=0.0)


def test_law_without_estimate_ignores_dist_bit_for_bit() -> None:
    """"none" (the paper's law, what `smcpilot paper` flies) is untouched by a d_hat passed in."""
    from fc.control.pid_smc import pid_smc_law

    law = PidSmc(PaperModel.from_vehicle(), PidSmcParams())
    meas = (0.1, 0.2, -0.05, 0.1, 0.3, -0.2, 2.0, 0.4)
    ref = tuple(0.01 * i for i in range(16))
    state = law.initial_state(meas)
    zero = pid_smc_law(meas, ref, state, law.consts, (0.0,) * 4, False)
    assert pid_smc_law(meas, ref, state, law.consts, (0.0,) * 4, False, (3.0, -2.0, 1.0, 0.5)) == zero
    lumped = PidSmc(PaperModel.from_vehicle(), PidSmcParams(disturbance_estimate="lumped"))
    assert pid_smc_law(meas, ref, state, lumped.consts, (0.0,) * 4, False, (0.0,) * 4) == zero
    assert pid_smc_law(meas, ref, state, lumped.consts, (0.0,) * 4, False, (3.0, 0.0, 0.0, 0.0)) != zero


def _hover_state(z_m: float = 3.0, p: float = 0.0) -> VehicleState:
    return VehicleState(0.0, 0.0, z_m, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, p, 0.0, 0.0)


def test_input_compensation_cancels_the_estimate_at_the_mixer() -> None:
    """"input": the mixer receives u - d_hat/g; "none": the same law state gives u unchanged."""
    out = {}
    for mode in ("none", "input"):
        fl = FlightControl(dataclasses.replace(FcConfig(), disturbance_estimate=mode), DEFAULT_VEHICLE)
        fl.arm(_hover_state())
        fl.step(_hover_state(), 0.002)
        # a roll rate appears that the nominal model cannot explain: the observer reads it as d
        o = fl.step(_hover_state(p=0.05), 0.002)
        out[mode] = o
    assert out["none"].d_hat == (0.0, 0.0, 0.0, 0.0)
    d_phi = out["input"].d_hat[0]
    assert d_phi == pytest.approx(40.0 * 0.05, rel=0.05)  # L x' after one step
    b1 = PaperModel.from_vehicle().b1
    assert out["input"].diag.u[0] == pytest.approx(out["none"].diag.u[0] - d_phi / b1, rel=1e-6, abs=1e-9)


def test_observer_holds_zero_on_the_ground() -> None:
    fl = FlightControl(FcConfig(), DEFAULT_VEHICLE)
    fl.arm(_hover_state(z_m=0.0))
    for _ in range(50):
        o = fl.step(_hover_state(z_m=0.0), 0.002)
        assert o.d_hat == (0.0, 0.0, 0.0, 0.0)


def test_observer_authority_is_the_vehicles() -> None:
    v = DEFAULT_VEHICLE
    f_max = v.thrust_coeff_n_s2 * v.rotor_speed_max_radps**2
    a = observer_authority(v)
    assert a[0] == pytest.approx(2 * v.arm_length_m * f_max / v.ixx_kg_m2)
    assert a[3] == pytest.approx(2 * v.gravity_mps2)
