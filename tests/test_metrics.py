"""ground.logs.metrics: flight metrics on synthetic traces with analytic answers, on synthetic
logs, and end to end on a real in-process flight (``smcpilot run`` and ``smcpilot log summary``
give the same numbers).

Oracles: a constant error e over T s gives IAE e·T, ISE e²·T, ITAE e·T²/2; a ramp e = a·t gives
a·T²/2, a²·T³/3, a·T³/3; the trapezoid is exact for the linear integrands and within h²/(2T²) for
the quadratic ones.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_logtools import LogBuilder, paper_target

from ground.logs import load_log, summarize
from ground.logs.metrics import (
    MetricsError,
    divergence_from_events,
    fault_starts_from_events,
    flight_metrics,
    integrate,
    lowpass,
)
from ground.logs.summary import log_metrics
from smcpilot.errors import SmcpilotError

ROOT = Path(__file__).resolve().parents[1]
G = 9.81


def flight(t: np.ndarray, **over: object) -> dict[str, object]:
    """Arguments of flight_metrics for a vehicle hovering exactly on a set-point 3 m up, armed,
    not landing, hover thrust 0.5, level; ``over`` replaces any of them."""
    n = t.size
    args: dict[str, object] = {
        "t_s": t,
        "position_m": np.tile([0.0, 0.0, 3.0], (n, 1)),
        "target_m": np.tile([0.0, 0.0, 3.0], (n, 1)),
        "euler_rad": np.zeros((n, 3)),
        "euler_ref_rad": np.zeros((n, 3)),
        "motors": np.full((n, 4), 0.5),
        "armed": np.ones(n, dtype=bool),
        "landing": np.zeros(n, dtype=bool),
        "velocity_m_s": np.zeros((n, 3)),
    }
    args.update(over)
    return args


def metrics(t: np.ndarray, **over: object) -> dict:
    args = flight(t, **over)
    positional = [args.pop(k) for k in ("t_s", "position_m", "target_m", "euler_rad", "euler_ref_rad", "motors", "armed", "landing")]
    return flight_metrics(*positional, **args)  # type: ignore[arg-type]


# -- integrals ---------------------------------------------------------------------------------------
def test_constant_position_and_attitude_error_give_the_textbook_integrals() -> None:
    T, e, a = 4.0, 0.25, 0.1
    t = np.linspace(0.0, T, 2001)
    pos = np.tile([0.0, 0.0, 3.0], (t.size, 1)) + np.array([0.6, 0.0, 0.8]) * e  # |(0.6, 0, 0.8)| = 1
    eul = np.tile([0.0, a, 0.0], (t.size, 1))
    m = metrics(t, position_m=pos, euler_rad=eul)
    assert m["iae_pos_m_s"] == pytest.approx(e * T, rel=1e-12)
    assert m["ise_pos_m2_s"] == pytest.approx(e * e * T, rel=1e-12)
    assert m["itae_pos_m_s2"] == pytest.approx(e * T * T / 2, rel=1e-12)
    assert m["iae_att_rad_s"] == pytest.approx(a * T, rel=1e-12)
    assert m["ise_att_rad2_s"] == pytest.approx(a * a * T, rel=1e-12)
    assert m["itae_att_rad_s2"] == pytest.approx(a * T * T / 2, rel=1e-12)
    assert m["max_pos_err_m"] == pytest.approx(e)
    assert m["flight_time_s"] == pytest.approx(T) and m["armed_time_s"] == pytest.approx(T)
    json.dumps(m, allow_nan=False)


def test_a_linear_ramp_gives_the_textbook_integrals() -> None:
    T, a, h = 2.0, 0.5, 1e-3
    t = np.arange(0.0, T + h / 2, h)
    pos = np.column_stack([a * t, np.zeros(t.size), np.full(t.size, 3.0)])
    m = metrics(t, position_m=pos)
    assert m["iae_pos_m_s"] == pytest.approx(a * T**2 / 2, rel=1e-12)
    assert m["ise_pos_m2_s"] == pytest.approx(a * a * T**3 / 3, rel=1e-6)
    assert m["itae_pos_m_s2"] == pytest.approx(a * T**3 / 3, rel=1e-6)
    assert m["max_pos_err_m"] == pytest.approx(a * T)


def test_yaw_error_is_wrapped_across_180_deg() -> None:
    T = 2.0
    t = np.linspace(0.0, T, 401)
    eul = np.tile([0.0, 0.0, math.pi - 0.05], (t.size, 1))
    ref = np.tile([0.0, 0.0, -math.pi + 0.05], (t.size, 1))
    m = metrics(t, euler_rad=eul, euler_ref_rad=ref)
    assert m["iae_att_rad_s"] == pytest.approx(0.1 * T, rel=1e-9)  # not (2π − 0.1)·T


def test_itae_clock_restarts_at_each_set_point_change() -> None:
    """Constant error e; the set-point moves 4 m at T/2 and the vehicle with it: two steps of
    length T/2, ITAE 2·e(T/2)²/2 = e·T²/4 (IAE stays e·T)."""
    T, e = 4.0, 0.2
    t = np.linspace(0.0, T, 4001)
    target = np.tile([0.0, 0.0, 3.0], (t.size, 1))
    target[t >= T / 2, 0] = 4.0
    pos = target + [0.0, e, 0.0]
    m = metrics(t, position_m=pos, target_m=target)
    assert m["iae_pos_m_s"] == pytest.approx(e * T, rel=1e-12)
    assert m["itae_pos_m_s2"] == pytest.approx(e * T * T / 4, rel=1e-3)
    # A heading set-point change restarts it too.
    yaw_t = np.where(t >= T / 2, 1.0, 0.0)
    m2 = metrics(t, position_m=np.tile([0.0, e, 3.0], (t.size, 1)), target_yaw_rad=yaw_t)
    assert m2["itae_pos_m_s2"] == pytest.approx(e * T * T / 4, rel=1e-3)


def test_only_armed_not_landing_time_counts_and_nan_intervals_are_left_out() -> None:
    t = np.linspace(0.0, 10.0, 10001)  # h = 1 ms
    pos = np.tile([0.0, 0.0, 3.5], (t.size, 1))  # 0.5 m error everywhere
    armed = t >= 1.0
    landing = t >= 9.0
    pos[armed & ~landing & (t > 4.0) & (t < 5.0), :] = np.nan  # a 1 s dropout
    m = metrics(t, position_m=pos, armed=armed, landing=landing, motors=np.full((t.size, 4), 0.5))
    # In flight 1..9 s minus the dropout: (1, 4] and [5, 9) -> 3.001 s + 4.0 s... of intervals
    # with both ends finite: [1, 4.0] (3 s) and [5.0, 9.0) (4 s - 1 ms).
    assert m["flight_time_s"] == pytest.approx(8.0 - 1e-3, abs=1e-9)
    assert m["iae_pos_m_s"] == pytest.approx(0.5 * (3.0 + 4.0 - 1e-3), rel=1e-9)
    assert m["max_pos_err_m"] == pytest.approx(0.5)
    assert m["armed_time_s"] == pytest.approx(9.0)
    assert m["effort_u2_s"] == pytest.approx(4 * 0.25 * 9.0)


def test_never_flown_gives_none_not_zero() -> None:
    t = np.linspace(0.0, 1.0, 11)
    m = metrics(t, armed=np.zeros(11, dtype=bool))
    assert m["iae_pos_m_s"] is None and m["effort_u2_s"] is None and m["motor_tv"] is None
    assert m["max_tilt_deg"] is None and m["crashed"] is False
    json.dumps(m, allow_nan=False)


# -- motors -------------------------------------------------------------------------------------------
def test_effort_of_constant_commands() -> None:
    T = 10.0
    t = np.linspace(0.0, T, 1001)
    m = metrics(t, motors=np.tile([0.1, 0.2, 0.3, 0.4], (t.size, 1)))
    assert m["effort_u2_s"] == pytest.approx((0.01 + 0.04 + 0.09 + 0.16) * T, rel=1e-12)
    assert m["motor_tv"] == 0.0 and m["motor_tv_per_s"] == 0.0
    hover = metrics(t)
    assert hover["effort_u2_s"] == pytest.approx(10.0)  # four motors at 0.5 for 10 s


def test_motor_total_variation_of_a_square_wave() -> None:
    """All four motors switch between 0.4 and 0.6 every 0.1 s for 1 s: 10 switches of 0.2 each."""
    t = np.linspace(0.0, 1.0, 1001)
    k = np.arange(t.size)
    c = np.where((k // 100) % 2 == 0, 0.4, 0.6)
    m = metrics(t, motors=np.column_stack([c, c, c, c]))
    assert m["motor_tv"] == pytest.approx(4 * 10 * 0.2, rel=1e-12)
    assert m["motor_tv_per_s"] == pytest.approx(8.0, rel=1e-12)
    one = metrics(t, motors=np.column_stack([c, np.full(t.size, 0.5), np.full(t.size, 0.5), np.full(t.size, 0.5)]))
    assert one["motor_tv"] == pytest.approx(2.0, rel=1e-12)
    # The step from 0 to idle at arming is not flight: only armed-to-armed pairs count.
    armed = t >= 0.5
    m_arm = metrics(t, motors=np.where(armed[:, None], 0.5, 0.0) * np.ones((1, 4)), armed=armed)
    assert m_arm["motor_tv"] == 0.0


# -- tilt and crashes ---------------------------------------------------------------------------------
def test_tilt_of_a_known_attitude() -> None:
    t = np.linspace(0.0, 1.0, 101)
    eul = np.zeros((t.size, 3))
    eul[50] = (math.radians(30.0), math.radians(40.0), 2.0)
    m = metrics(t, euler_rad=eul)
    expected = math.degrees(math.acos(math.cos(math.radians(30.0)) * math.cos(math.radians(40.0))))
    assert m["max_tilt_deg"] == pytest.approx(expected, rel=1e-12)  # 50.6 deg
    assert m["crashed"] is False


def test_tilt_beyond_60_deg_while_armed_is_a_crash_not_while_disarmed() -> None:
    t = np.linspace(0.0, 2.0, 201)
    eul = np.zeros((t.size, 3))
    eul[t >= 1.5, 0] = math.radians(61.0)
    m = metrics(t, euler_rad=eul)
    assert m["crashed"] is True and m["crash_reason"] == "tilt"
    assert m["crash_t_s"] == pytest.approx(1.5)
    assert "tilt 61.0 deg > 60 deg" in m["crash_detail"]
    calm = metrics(t, euler_rad=eul, armed=t < 1.5)
    assert calm["crashed"] is False and calm["crash_t_s"] is None


def free_fall(h: float = 1e-3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, altitude, climb rate): dropped from 3 m at t = 1 s onto rigid ground (which zeroes the
    velocity at contact)."""
    t = np.arange(0.0, 3.0, h)
    tau = np.clip(t - 1.0, 0.0, None)
    alt = 3.0 - 0.5 * G * tau**2
    climb = -G * tau
    on_ground = alt <= 0.0
    alt[on_ground], climb[on_ground] = 0.0, 0.0
    return t, alt, climb


def test_ground_impact_is_a_crash() -> None:
    t, alt, climb = free_fall()
    pos = np.column_stack([np.zeros(t.size), np.zeros(t.size), alt])
    vel = np.column_stack([np.zeros(t.size), np.zeros(t.size), climb])
    t_hit = 1.0 + math.sqrt(2 * (3.0 - 0.05) / G)  # below 0.05 m at 1.776 s, at 7.6 m/s
    m = metrics(t, position_m=pos, velocity_m_s=vel)
    assert m["crashed"] is True and m["crash_reason"] == "impact"
    assert m["crash_t_s"] == pytest.approx(t_hit, abs=2e-3)
    assert "7.6 m/s" in m["crash_detail"]
    # The same from the altitude alone (no velocity given: a backward difference).
    m2 = metrics(t, position_m=pos, velocity_m_s=None)
    assert m2["crash_reason"] == "impact" and m2["crash_t_s"] == pytest.approx(t_hit, abs=2e-3)
    # Disarmed in the air (a failsafe cut) still hits the ground.
    assert metrics(t, position_m=pos, velocity_m_s=vel, armed=t < 1.0)["crash_reason"] == "impact"


def landing(speed_mps: float, h: float = 2e-3) -> dict[str, np.ndarray]:
    """Hold 3 m until 2 s, then descend at ``speed_mps`` with the landing flag, touch down (the
    ground stops it) and disarm 0.5 s later."""
    t = np.arange(0.0, 2.0 + 3.0 / speed_mps + 1.0, h)
    alt = np.clip(3.0 - speed_mps * np.clip(t - 2.0, 0.0, None), 0.0, None)
    climb = np.where((t > 2.0) & (alt > 0.0), -speed_mps, 0.0)
    t_down = 2.0 + 3.0 / speed_mps
    return {
        "t": t,
        "position_m": np.column_stack([np.zeros(t.size), np.zeros(t.size), alt]),
        "velocity_m_s": np.column_stack([np.zeros(t.size), np.zeros(t.size), climb]),
        "landing": (t >= 2.0) & (t < t_down + 0.5),
        "armed": t < t_down + 0.5,
    }


def test_a_normal_landing_is_not_a_crash() -> None:
    d = landing(0.7)  # the FC's default LAND_SPD
    t = d.pop("t")
    m = metrics(t, **d)
    assert m["crashed"] is False and m["crash_reason"] is None
    # A faster LAND speed the FC was told to use is a normal touchdown too...
    d2 = landing(2.0)
    t2 = d2.pop("t")
    assert metrics(t2, **d2, land_speed_mps=2.0)["crashed"] is False
    # ... but 2 m/s into the ground without that setting is an impact.
    assert metrics(t2, **d2)["crash_reason"] == "impact"


def test_a_divergence_is_a_crash_and_the_earliest_reason_wins() -> None:
    t = np.linspace(0.0, 2.0, 201)
    m = metrics(t, diverged_t_s=1.25)
    assert m["crashed"] is True and m["crash_reason"] == "diverged" and m["crash_t_s"] == 1.25
    eul = np.zeros((t.size, 3))
    eul[t >= 1.0, 1] = 1.3  # 74 deg from 1 s
    m2 = metrics(t, euler_rad=eul, diverged_t_s=1.25)
    assert m2["crash_reason"] == "tilt" and m2["crash_t_s"] == pytest.approx(1.0)


# -- recovery -----------------------------------------------------------------------------------------
def error_trace(t: np.ndarray, peak_m: float = 1.0, back: bool = True) -> np.ndarray:
    """0.1 m until 2 s, linear to ``peak_m`` at 3 s, then (``back``) linear to 0 at 5 s."""
    e = np.full(t.size, 0.1)
    up = (t >= 2.0) & (t < 3.0)
    e[up] = 0.1 + (peak_m - 0.1) * (t[up] - 2.0)
    down = t >= 3.0
    e[down] = np.clip(peak_m * (1.0 - (t[down] - 3.0) / 2.0), 0.0, None) if back else peak_m
    return e


def with_error(t: np.ndarray, e: np.ndarray) -> np.ndarray:
    return np.column_stack([e, np.zeros(t.size), np.full(t.size, 3.0)])


def test_recover_time_of_a_synthetic_error_trace() -> None:
    t = np.arange(0.0, 8.0, 1e-3)
    pos = with_error(t, error_trace(t))
    # Back within 0.3 m for good where 1 − (t − 3)/2 = 0.3: t = 4.4 s, 2.4 s after the fault.
    m = metrics(t, position_m=pos, fault_starts_s=[2.0])
    assert m["fault_start_s"] == 2.0 and m["recovered"] is True
    assert m["recover_s"] == pytest.approx(2.4, abs=1e-9)
    # A larger radius: back within 0.5 m at t = 4.0 s. The first of several starts counts.
    m = metrics(t, position_m=pos, fault_starts_s=[6.0, 2.0], recover_radius_m=0.5)
    assert m["recover_s"] == pytest.approx(2.0, abs=1e-9) and m["recover_radius_m"] == 0.5
    # Never left the radius: 0.
    m = metrics(t, position_m=pos, fault_starts_s=[2.0], recover_radius_m=1.5)
    assert m["recover_s"] == 0.0 and m["recovered"] is True
    # Never came back: None and recovered False (no inf anywhere).
    m = metrics(t, position_m=with_error(t, error_trace(t, back=False)), fault_starts_s=[2.0])
    assert m["recover_s"] is None and m["recovered"] is False
    json.dumps(m, allow_nan=False)
    # No fault: None, None.
    m = metrics(t, position_m=pos)
    assert m["fault_start_s"] is None and m["recover_s"] is None and m["recovered"] is None


def test_recovery_is_judged_before_the_next_set_point_change_or_landing() -> None:
    t = np.arange(0.0, 8.0, 1e-3)
    pos = with_error(t, error_trace(t))
    # Landing from 4.0 s (error still 0.5 m): not back before the landing.
    m = metrics(t, position_m=pos, fault_starts_s=[2.0], landing=t >= 4.0)
    assert m["recovered"] is False and m["recover_s"] is None
    # A new set-point at 4.0 s ends the stretch the same way (error measured to the old one).
    target = np.tile([0.0, 0.0, 3.0], (t.size, 1))
    target[t >= 4.0, 1] = 2.0
    pos2 = pos.copy()
    pos2[t >= 4.0, 1] = 2.0
    m = metrics(t, position_m=pos2, target_m=target, fault_starts_s=[2.0])
    assert m["recovered"] is False
    # A crash after the fault is never a recovery; a fault while disarmed cannot be judged.
    eul = np.zeros((t.size, 3))
    eul[t >= 6.0, 0] = 1.5
    assert metrics(t, position_m=pos, euler_rad=eul, fault_starts_s=[2.0])["recovered"] is False
    m = metrics(t, position_m=pos, fault_starts_s=[2.0], armed=t < 1.0)
    assert m["recovered"] is None and m["recover_s"] is None


def test_fault_starts_and_divergence_from_events() -> None:
    events = [
        (1.0, "INFO", "Armed"),
        (5.0, "WARNING", "SIM: motor 1 at 70%"),
        (6.0, 4, "SIM: motor 2 off"),  # a start, by its severity, although it says "off"
        (7.0, "INFO", "SIM: motor 1 ok"),
        (8.0, "WARNING", "SIM: SIM_ENGINE_MUL rejected: 1.5"),
        (8.5, "ERROR", "SIM: SIM_ENGINE_MUL must lie in [0, 1]"),  # a refused parameter
        (8.7, 2, "SIM: this plant takes no live parameters"),
        (9.0, "WARNING", "Motor 1 at 70%"),  # not the simulator's
        (10.0, "CRITICAL", "Simulation diverged at t = 10.000 s"),
    ]
    assert fault_starts_from_events(events) == [5.0, 6.0]
    assert divergence_from_events(events) == 10.0
    assert divergence_from_events(events[:3]) is None


# -- sigma --------------------------------------------------------------------------------------------
def test_sigma_low_pass_separates_dither_from_distance_to_the_surface() -> None:
    t = np.arange(0.0, 10.0, 0.002)  # 500 Hz
    n = t.size
    dither = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    sig = np.column_stack([dither, np.full(n, 0.3), 0.3 + 0.01 * dither, np.full(n, np.nan)])
    m = metrics(t, sigma=sig)
    lpf, dit = m["sigma_lpf_rms"], m["sigma_dither_rms"]
    # Pure ±1 dither: the low-pass of the alternating sequence has amplitude α/(2 − α) ≈ 0.01.
    alpha = -math.expm1(-0.002 / 0.1)
    assert lpf[0] == pytest.approx(alpha / (2 - alpha), rel=1e-3) and lpf[0] < 0.02
    assert dit[0] == pytest.approx(1.0, abs=0.02)
    # Constant sigma: that constant, no dither.
    assert lpf[1] == pytest.approx(0.3, rel=1e-12) and dit[1] == pytest.approx(0.0, abs=1e-12)
    # A constant offset with a small dither: the offset, and the dither.
    assert lpf[2] == pytest.approx(0.3, rel=1e-3) and dit[2] == pytest.approx(0.01, rel=0.02)
    assert lpf[3] is None and dit[3] is None  # a channel without sigma
    assert m["sigma_window_s"] == 5.0 and m["sigma_tau_s"] == 0.1


def test_low_pass_step_response_and_nan_restart() -> None:
    t = np.arange(0.0, 1.0, 0.001)
    x = np.where(t >= 0.5, 1.0, 0.0)
    y = lowpass(t, x, 0.1)
    k0 = int(np.flatnonzero(t >= 0.5)[0])
    # Exact for an input held over each sample interval: 1 − exp(−(t − t_k0−1)/τ).
    np.testing.assert_allclose(y[k0:], 1.0 - np.exp(-(t[k0:] - t[k0 - 1]) / 0.1), rtol=1e-9)
    assert np.all(y[:k0] == 0.0)
    x2 = np.full(t.size, 2.0)
    x2[100] = np.nan
    x2[101:] = 5.0
    y2 = lowpass(t, x2, 0.1)
    assert np.isnan(y2[100]) and y2[101] == 5.0 and y2[99] == 2.0  # restarts at the next finite sample
    with pytest.raises(MetricsError, match="tau_s"):
        lowpass(t, x, 0.0)


def test_low_pass_compiled_is_the_cpython_loop_bit_for_bit() -> None:
    """A process that flies compiled scores compiled (``score_compiled``): the same floats."""
    import ground.logs.metrics as metrics_mod
    from smcpilot.jit import jit_enabled

    if not jit_enabled(say=False):  # no numba, or the compiled path switched off: CPython stays
        assert not metrics_mod.score_compiled() and metrics_mod._COMPILED[0] is None
        return

    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.001, 0.02, 3000))
    x = rng.normal(size=(3000, 4))
    x[rng.integers(0, 3000, 40), rng.integers(0, 4, 40)] = np.nan
    x[:5, 2] = np.nan  # a column that starts unmeasured
    saved = metrics_mod._COMPILED[0]
    try:
        metrics_mod._COMPILED[0] = None
        y_py = lowpass(t, x, 0.3)
        assert metrics_mod.score_compiled()
        assert metrics_mod._COMPILED[0] is not None
        y_jit = lowpass(t, x, 0.3)
        y_jit_1d = lowpass(t, x[:, 1], 0.3)
    finally:
        metrics_mod._COMPILED[0] = saved
    assert y_py.tobytes() == y_jit.tobytes()
    assert y_jit_1d.tobytes() == y_py[:, 1].tobytes()
    assert np.isnan(y_py[:5, 2]).all() and np.isfinite(y_py[5:, 0]).sum() > 2900


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 50), st.integers(1, 5), st.integers(0, 2**32 - 1))
def test_row_reductions_are_numpys_bit_for_bit(n: int, m: int, seed: int) -> None:
    """The scoring's column-by-column row sums, norms and any() are numpy's own reductions along
    axis 1, bit for bit (wide magnitudes, so a different summation order would show), C or F order."""
    from ground.logs.metrics import _row_any, _row_norm, _row_sum

    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, m)) * 10.0 ** rng.integers(-9, 9, (n, m))
    x[rng.random((n, m)) < 0.05] = np.nan
    for a in (x, np.asfortranarray(x), x[::-1]):
        assert _row_sum(a).tobytes() == np.sum(a, axis=1).tobytes()
        assert _row_norm(a).tobytes() == np.linalg.norm(a, axis=1).tobytes()
        b = a > 0.0
        assert np.array_equal(_row_any(b), np.any(b, axis=1))


def test_sigma_window_is_the_last_seconds_of_flight_before_landing() -> None:
    t = np.arange(0.0, 20.0, 0.01)
    sig = np.where(t < 14.0, 0.2, 3.0)[:, None] * np.ones((1, 4))
    m = metrics(t, sigma=sig, landing=t >= 14.0)  # sigma jumps to 3 while landing: not in the window
    assert m["sigma_lpf_rms"] == pytest.approx([0.2] * 4, rel=1e-9)


# -- bad input ----------------------------------------------------------------------------------------
def test_bad_arrays_and_parameters_are_clear_errors() -> None:
    t = np.linspace(0.0, 1.0, 11)
    with pytest.raises(MetricsError, match=r"motors must have shape \(11, 4\)") as info:
        metrics(t, motors=np.zeros((11, 3)))
    assert isinstance(info.value, SmcpilotError)
    with pytest.raises(MetricsError, match=r"fault_starts_s\[1\] must be a finite number"):
        metrics(t, fault_starts_s=[1.0, math.nan])
    with pytest.raises(MetricsError, match="recover_radius_m must be a finite number > 0"):
        metrics(t, recover_radius_m=0.0)
    with pytest.raises(MetricsError, match="t_s must not decrease: sample 5"):
        metrics(t[[0, 1, 2, 3, 5, 4, 6, 7, 8, 9, 10]])
    with pytest.raises(MetricsError, match="t_s must be finite"):
        metrics(np.where(t > 0.5, np.nan, t))
    assert integrate(np.zeros(1), np.zeros(1), np.ones(1, dtype=bool)) == 0.0


# -- from a log ---------------------------------------------------------------------------------------
def write_fault_flight(path: Path, *, diverge: bool = False) -> None:
    """50 Hz lockstep-style log: hold 3 m; a "SIM:" fault at 4 s pushes the vehicle 1 m east,
    linear back to the set-point from 5 s to 7 s (within 0.3 m at 6.4 s); then land."""
    b = LogBuilder(path)
    dt_us = 20_000
    b.event(0, "Armed")
    for k in range(500):  # 0 .. 9.98 s
        t_us = k * dt_us
        t = t_us * 1e-6
        east = 0.0 if t < 4.0 else (1.0 if t < 5.0 else max(0.0, 1.0 - (t - 5.0) / 2.0))
        landing = t >= 9.0
        b.state(t_us, (0.0, east, -3.0))
        b.actuators(t_us, [0.5] * 4, True)
        b.smc(t_us, **paper_target(0.0, 0.0, 3.0, 0.0), ref_phi=0.0, ref_theta=0.0, ref_psi=0.0, ref_z=3.0,
              sigma_phi=0.0, sigma_theta=0.0, sigma_psi=0.0, sigma_z=0.0, flags=float(1 | 8 | (2 if landing else 0)))  # fmt: skip
        if k == 200:
            b.event(t_us, "SIM: force 0,5,0 N NED", severity=4)
        if k == 250:
            b.event(t_us, "SIM: force off", severity=6)
        if diverge and k == 499:
            b.event(t_us, "Simulation diverged at t = 9.980 s", severity=2)
        b.end_tick(t_us)
    b.close()


def test_log_summary_finds_the_fault_and_the_recovery(tmp_path: Path) -> None:
    path = tmp_path / "fault.tlog"
    write_fault_flight(path)
    m = summarize(load_log(path))["metrics"]
    assert m["fault_start_s"] == pytest.approx(4.0)
    assert m["recovered"] is True and m["recover_s"] == pytest.approx(2.4, abs=1e-6)
    assert m["max_pos_err_m"] == pytest.approx(1.0, rel=1e-6)
    assert m["crashed"] is False
    # IAE: 1 m for 1 s (4..5 s, the step at 4 s inside one 20 ms interval) + the 2 s ramp down (1 m·s).
    assert m["iae_pos_m_s"] == pytest.approx(1.0 + 1.0 + 0.5 * 0.02, abs=1e-6)
    assert m["flight_time_s"] == pytest.approx(8.98)  # 0 .. 8.98 s, the last tick before landing


def test_a_divergence_event_in_the_log_is_a_crash(tmp_path: Path) -> None:
    path = tmp_path / "diverged.tlog"
    write_fault_flight(path, diverge=True)
    m = summarize(load_log(path))["metrics"]
    assert m["crashed"] is True and m["crash_reason"] == "diverged" and m["crash_t_s"] == pytest.approx(9.98)


@pytest.mark.slow
def test_sitl_divergence_note_is_appended_to_the_fc_log(tmp_path: Path) -> None:
    from lab.run import _note_divergence_in_tlog

    path = tmp_path / "sitl.tlog"
    write_fault_flight(path)
    assert summarize(load_log(path))["metrics"]["crashed"] is False
    _note_divergence_in_tlog(path)
    log = load_log(path)
    assert not log.truncated and log.events[-1].text == "Simulation diverged at t = 9.980 s"
    m = summarize(log)["metrics"]
    assert m["crash_reason"] == "diverged" and m["crash_t_s"] == pytest.approx(9.98)


def test_an_in_process_divergence_is_logged_and_is_a_crash(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The plant raising DivergenceError mid-flight: the run says "diverged", and its log says so too."""
    import lab.run as run
    from smcpilot.errors import DivergenceError
    from smcpilot.scenario import Scenario

    real = run.plant_for

    class Exploding:
        def __init__(self, plant: object) -> None:
            self._p = plant

        def __getattr__(self, name: str) -> object:
            return getattr(self._p, name)

        def step(self, t_s: float, dt_s: float, motors: object, armed: bool) -> None:
            if t_s >= 1.5:
                raise DivergenceError("test: state became non-finite", t_s + dt_s)
            self._p.step(t_s, dt_s, motors, armed)

    monkeypatch.setattr(run, "plant_for", lambda sc: Exploding(real(sc)))
    sc = Scenario.from_toml(ROOT / "examples" / "scenarios" / "hover.toml").with_changes(duration_s=3.0)
    res = run.fly(sc, tmp_path)
    assert res.status == "diverged"
    m = res.as_json()["metrics"]
    assert m["crashed"] is True and m["crash_reason"] == "diverged" and m["crash_t_s"] == pytest.approx(1.5, abs=0.003)


# -- end to end ---------------------------------------------------------------------------------------
@pytest.mark.slow
def test_run_json_and_log_summary_report_the_same_plausible_metrics(tmp_path: Path) -> None:
    out_json = tmp_path / "out.json"
    r = subprocess.run(
        [sys.executable, "-m", "lab.cli", "run", str(ROOT / "examples" / "scenarios" / "hover.toml"),
         "--json", str(out_json), "--no-plots", "--quiet", "--out", str(tmp_path / "run")],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    assert "IAE" in r.stdout and "crashed             no" in r.stdout
    doc = json.loads(out_json.read_text())
    m = doc["metrics"]
    # Take-off to 3 m at 0 s, hold, LAND at 14 s: in flight 14 s, armed until the touchdown (~19 s).
    assert m["flight_time_s"] == pytest.approx(14.0, abs=0.01)
    assert 17.0 < m["armed_time_s"] < 20.0
    assert m["max_pos_err_m"] == pytest.approx(3.0, abs=0.01)  # the take-off step
    assert 2.0 < m["iae_pos_m_s"] < 10.0 and 0.0 < m["ise_pos_m2_s"] < 3.0**2 * 14
    assert m["max_tilt_deg"] < 5.0 and m["crashed"] is False and m["crash_reason"] is None
    # About 0.5 per motor (hover) over the armed time: 4·0.25·19 s ≈ 19.
    assert 10.0 < m["effort_u2_s"] < 25.0 and m["motor_tv"] > 0.0
    assert m["fault_start_s"] is None and m["recovered"] is None
    assert len(m["sigma_lpf_rms"]) == 4 and len(m["sigma_dither_rms"]) == 4
    assert doc["summary"]["sigma_lpf_rms"] == m["sigma_lpf_rms"]
    r2 = subprocess.run(
        [sys.executable, "-m", "lab.cli", "log", "summary", doc["tlog"], "--json", "-"],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )  # fmt: skip
    assert r2.returncode == 0, r2.stdout + r2.stderr
    assert json.loads(r2.stdout)["metrics"] == m


def test_in_process_recorder_gives_the_numbers_of_the_log_summary(tmp_path: Path) -> None:
    """lab.metrics.MetricsRecorder (no tlog) and the summary of the same flight's tlog: equal to
    the float32 rounding of the log."""
    from fc.core import FlightCore
    from fc.params import config_for
    from lab.metrics import MetricsRecorder
    from lab.run import _TlogRecorder
    from lab.runner import simulate
    from sim_bridge.build import plant_for
    from smcpilot.scenario import Scenario

    sc = Scenario.from_toml(ROOT / "examples" / "scenarios" / "step-yaw.toml").with_changes(duration_s=12.0)
    holder: list[_TlogRecorder] = []
    core = FlightCore(config_for(sc), sc.vehicle, plan=sc.plan, event=lambda sev, text: holder[0].event(sev, text))
    tlog = _TlogRecorder(tmp_path / "f.tlog", core)
    holder.append(tlog)
    rec = MetricsRecorder(core)

    def both(*a: object) -> None:
        tlog.on_tick(*a)  # type: ignore[arg-type]
        rec.on_tick(*a)  # type: ignore[arg-type]

    simulate(core, plant_for(sc), sc.n_ticks, rate_hz=sc.rate_hz, physics_hz=sc.physics_hz, on_tick=both)
    tlog.close()
    mine = rec.metrics(fault_starts_s=[6.0])
    ref = log_metrics(load_log(tmp_path / "f.tlog"), recover_radius_m=0.3)
    assert ref is not None and len(rec) == sc.n_ticks == ref["samples"]
    # Step at 5 s to (4, -3) m and a heading change: the ITAE clock restarts, the max error is the step.
    assert mine["max_pos_err_m"] == pytest.approx(5.0, abs=1e-3)
    for key in ("flight_time_s", "iae_pos_m_s", "ise_pos_m2_s", "itae_pos_m_s2", "iae_att_rad_s", "itae_att_rad_s2",
                "effort_u2_s", "motor_tv", "max_tilt_deg", "max_pos_err_m"):  # fmt: skip
        assert mine[key] == pytest.approx(ref[key], rel=1e-4, abs=1e-9), key
    assert mine["crashed"] is ref["crashed"] is False
    np.testing.assert_allclose(mine["sigma_dither_rms"], ref["sigma_dither_rms"], rtol=1e-3)
    # A "fault" at the step (6 s): recover_s is then the time to come within 0.3 m of the new set-point for good.
    assert mine["fault_start_s"] == 6.0 and mine["recovered"] is True and 2.0 < mine["recover_s"] < 6.0  # 3.36 s
    assert ref["fault_start_s"] is None  # the log has no "SIM:" event
    # Fault starts from noted events, as from a log's.
    rec.note_event(6.0, 4, "SIM: motor 1 at 70%")
    rec.note_event(7.0, 6, "SIM: motor 1 ok")
    assert rec.metrics()["fault_start_s"] == 6.0 and rec.metrics()["recover_s"] == mine["recover_s"]
