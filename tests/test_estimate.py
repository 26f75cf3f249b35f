"""The FC's estimate (fc/estimate.py): dead reckoning through a sensor dropout and its timeout,
the state-loss failsafe for a missing attitude, and the filtered hold point — in pure unit tests
(oracle values, simulated time) and in in-process flights (lab.runner) whose plant reports NaN
fields for a while, as the simulator does for a dropped sensor."""

from __future__ import annotations

import math
import random
from collections.abc import Callable

import pytest

from fc.core import FlightCore
from fc.estimate import (
    EST_ATTITUDE_LOST,
    EST_DEAD_RECKONING,
    EST_OK,
    EST_POSITION_LOST,
    ESTIMATOR_START,
    MISSING_ATTITUDE,
    MISSING_POSITION,
    MISSING_RATES,
    MISSING_VELOCITY,
    EstimatorConfig,
    EstimatorState,
    estimate_step,
    estimator_params,
    hold_point,
)
from fc.flight import VehicleState
from fc.params import config_for, options_for
from lab.runner import simulate
from sim_bridge.build import plant_for
from smcpilot.errors import ConfigError
from smcpilot.frames import wrap_pi
from smcpilot.plan import PlanStep
from smcpilot.protocol import Mode
from smcpilot.scenario import EnvironmentSpec, Scenario

NAN = math.nan
DT = 0.002
P = estimator_params(EstimatorConfig(), DT)


def _st(x=1.0, y=2.0, z=3.0, vx=0.5, vy=-0.2, vz=0.1, phi=0.01, theta=-0.02, psi=0.3, pd=0.0, td=0.0, yd=0.0) -> VehicleState:
    return VehicleState(x, y, z, vx, vy, vz, phi, theta, psi, pd, td, yd)


def _run(states: list[VehicleState], est: EstimatorState = ESTIMATOR_START, p=P) -> list[tuple]:
    out = []
    for m in states:
        est, state, status, missing = estimate_step(est, m, DT, p)
        out.append((est, state, status, missing, hold_point(est, p)))
    return out


# -- the pure estimator -------------------------------------------------------------------------
def test_a_measured_state_is_flown_as_it_is() -> None:
    m = _st()
    (est, state, status, missing, hold), = _run([m])
    assert state is m and status == EST_OK and missing == 0
    assert tuple(hold) == (m.x_m, m.y_m, m.z_m, m.psi_rad)


def test_missing_position_is_dead_reckoned_from_the_measured_velocity() -> None:
    good = _st()
    k = 200
    rows = _run([good] + [_st(x=NAN, y=NAN, z=NAN)] * k)
    for i, (_, state, status, missing, _) in enumerate(rows[1:], start=1):
        assert status == EST_DEAD_RECKONING and missing == MISSING_POSITION
        # the velocity is measured and constant: the trapezoid is p0 + v * t exactly (to rounding)
        assert state.x_m == pytest.approx(1.0 + 0.5 * i * DT, abs=1e-12)
        assert state.y_m == pytest.approx(2.0 - 0.2 * i * DT, abs=1e-12)
        assert state.z_m == pytest.approx(3.0 + 0.1 * i * DT, abs=1e-12)
        assert (state.vx_mps, state.psi_rad) == (0.5, 0.3)  # measured fields pass through
    # a measured velocity that changes: the trapezoid of the last two velocities
    _, state, _, _, _ = _run([_st(x=NAN, y=NAN, z=NAN, vx=1.5)], rows[-1][0])[0]
    assert state.x_m == pytest.approx(rows[-1][1].x_m + 0.5 * DT * (0.5 + 1.5), abs=1e-12)


def test_missing_position_and_velocity_hold_the_velocity() -> None:
    rows = _run([_st(vx=2.0, vy=0.0, vz=-1.0)] + [_st(x=NAN, y=NAN, z=NAN, vx=NAN, vy=NAN, vz=NAN)] * 100)
    _, state, status, missing, _ = rows[-1]
    assert status == EST_DEAD_RECKONING and missing == MISSING_POSITION | MISSING_VELOCITY
    assert (state.vx_mps, state.vy_mps, state.vz_mps) == (2.0, 0.0, -1.0)
    assert (state.x_m, state.y_m, state.z_m) == pytest.approx((1.0 + 2.0 * 100 * DT, 2.0, 3.0 - 100 * DT), abs=1e-12)
    # only the velocity missing: held, the position measured
    _, state, status, missing, _ = _run([_st(x=5.0, vx=NAN)], rows[-1][0])[0]
    assert status == EST_DEAD_RECKONING and missing == MISSING_VELOCITY
    assert (state.x_m, state.vx_mps, state.vy_mps) == (5.0, 2.0, 0.0)


@pytest.mark.parametrize("timeout_s", [1.0, 0.25, 0.0])
def test_dead_reckoning_lasts_at_most_the_timeout(timeout_s: float) -> None:
    p = estimator_params(EstimatorConfig(pos_timeout_s=timeout_s), DT)
    n_ok = round(timeout_s / DT)  # ticks of dead reckoning allowed
    rows = _run([_st()] + [_st(x=NAN, y=NAN, z=NAN)] * (n_ok + 3), p=p)
    statuses = [r[2] for r in rows[1:]]
    assert statuses == [EST_DEAD_RECKONING] * n_ok + [EST_POSITION_LOST] * 3
    # back: measured again, at once
    _, state, status, missing, _ = _run([_st(x=7.0)], rows[-1][0], p=p)[0]
    assert status == EST_OK and missing == 0 and state.x_m == 7.0


def test_nothing_to_reckon_from_and_a_missing_attitude_are_losses() -> None:
    (_, _, status, missing, _), = _run([_st(x=NAN)])  # no position ever measured
    assert status == EST_POSITION_LOST and missing == MISSING_POSITION
    (_, _, status, _, _), = _run([_st(vz=NAN)])
    assert status == EST_POSITION_LOST
    good = _run([_st()])[0][0]
    for bad, bits in ((_st(theta=NAN), MISSING_ATTITUDE), (_st(yd=math.inf), MISSING_RATES)):
        (_, _, status, missing, _), = _run([bad], good)
        assert status == EST_ATTITUDE_LOST and missing == bits


def test_hold_point_is_the_sample_itself_without_noise_even_when_accelerating() -> None:
    """A clean flight must take exactly the set-points it took before the filter existed."""
    est = ESTIMATOR_START
    for k in range(3000):
        t = k * DT
        a = 2.0 if k < 1500 else -3.0  # m/s^2, and a yaw rate ramp through +-pi
        m = _st(x=0.5 * a * t * t, y=-t, z=3.0 + 0.1 * math.sin(t), vx=a * t, vy=-1.0, vz=0.1 * math.cos(t),
                psi=wrap_pi(3.0 + 0.8 * t * t), yd=1.6 * t)  # fmt: skip
        est, state, status, _ = estimate_step(est, m, DT, P)
        hold = hold_point(est, P)
        assert state is m and status == EST_OK
        assert tuple(hold) == (m.x_m, m.y_m, m.z_m, m.psi_rad), k
    assert est.innov_pos_m2 < 1e-9  # far below the 1 mm floor


def test_hold_point_filters_a_noisy_position_and_yaw_across_pi() -> None:
    """At rest with the simulator's --noise (0.01 m, 0.02 m/s, 0.002 rad, 0.01 rad/s): the hold
    point's error is a small fraction of one sample's; its yaw stays by +-pi, not 0."""
    errs_hold, errs_sample, yaw_hold, yaw_sample = [], [], [], []
    for seed in range(8):
        r = random.Random(seed)
        est = ESTIMATOR_START
        for _ in range(500):  # 1 s: five time constants
            g = r.gauss
            m = _st(x=g(0.0, 0.01), y=g(0.0, 0.01), z=g(0.0, 0.01), vx=g(0.0, 0.02), vy=g(0.0, 0.02), vz=g(0.0, 0.02),
                    psi=wrap_pi(math.pi + g(0.0, 0.002)), yd=g(0.0, 0.01))  # fmt: skip
            est = estimate_step(est, m, DT, P)[0]
        hold = hold_point(est, P)
        errs_hold.append(math.hypot(hold.x_m, hold.y_m))
        errs_sample.append(math.hypot(m.x_m, m.y_m))
        yaw_hold.append(abs(wrap_pi(hold.psi_rad - math.pi)))
        yaw_sample.append(abs(wrap_pi(m.psi_rad - math.pi)))
    assert max(errs_hold) < 0.004 and sum(errs_sample) / 8 > 0.006, (errs_hold, errs_sample)
    assert max(yaw_hold) < 0.001 and sum(yaw_sample) / 8 > 0.001, (yaw_hold, yaw_sample)


def test_a_position_jump_restarts_the_hold_filter() -> None:
    rows = _run([_st(x=0.0, vx=0.0)] * 50 + [_st(x=5.0, vx=0.0)])
    assert rows[-1][4].x_m == 5.0 and rows[-1][0].hold_x_m == 5.0


def test_estimator_settings_are_validated() -> None:
    with pytest.raises(ConfigError, match="pos_timeout_s"):
        EstimatorConfig(pos_timeout_s=NAN)
    with pytest.raises(ConfigError, match="hold_tau_s"):
        EstimatorConfig(hold_tau_s=0.0)


# -- in-process flights with a sensor dropout ---------------------------------------------------
HOVER = (PlanStep(0.0, "takeoff", alt_m=3.0),)


def _fly(duration_s: float, *, dropout: tuple[float, float, str] | None = None, params: tuple = (), noise: bool = False,
         seed: int = 0, plan: tuple = HOVER, estimator: EstimatorConfig | None = None,
         on_tick: Callable | None = None) -> tuple[FlightCore, list[tuple[float, str]], list]:  # fmt: skip
    """Fly in-process; ``dropout`` = (start_s, stop_s, observation field) reported as NaN."""
    sc = Scenario(duration_s=duration_s, plan=plan, params=params, seed=seed, environment=EnvironmentSpec(noise=noise))
    events: list[tuple[float, str]] = []
    core = FlightCore(config_for(sc), sc.vehicle, plan=sc.plan, event=lambda s, t: events.append((core.t_us * 1e-6, t)),
                      estimator=estimator if estimator is not None else options_for(sc).estimator)  # fmt: skip
    plant = plant_for(sc)
    if dropout is not None:
        t0, t1, name = dropout
        inner = plant.observe

        def observe():
            obs = inner()
            if t0 - 1e-9 <= obs.t_s < t1 - 1e-9:
                return obs._replace(**{name: (NAN, NAN, NAN)})
            return obs

        plant.observe = observe  # type: ignore[method-assign]
    rows: list = []

    def hook(k, t_us, wire, st, out, motors):
        assert all(math.isfinite(c) and 0.0 <= c <= 1.0 for c in motors), (t_us, motors)
        rows.append((t_us * 1e-6, st, out, core.state))
        if on_tick is not None:
            on_tick(core, st, out)

    simulate(core, plant, sc.n_ticks, rate_hz=sc.rate_hz, physics_hz=sc.physics_hz, on_tick=hook)
    return core, events, rows


def _texts(events: list[tuple[float, str]]) -> list[str]:
    return [t for _, t in events]


def test_a_short_position_dropout_is_flown_through_without_landing() -> None:
    core, events, rows = _fly(12.0, dropout=(8.0, 8.5, "position_m"))
    assert _texts(events) == ["Armed", "Takeoff to 3.0 m", "position lost: dead reckoning", "position back"]
    (t_lost, _), (t_back, _) = events[2], events[3]
    assert t_lost == pytest.approx(8.0, abs=1e-6) and t_back == pytest.approx(8.5, abs=1e-6)
    assert core.states_missing == core.dead_reckoning_ticks == 250 and core.failsafe_events == 0
    assert core.flight.armed and core.mode == Mode.GUIDED and not core.flight.landing
    during = [st for t, _, _, st in rows if 8.0 <= t < 8.5]
    assert max(abs(st.z_m - 3.0) for st in during) < 0.05  # the estimate the FC flew on
    last = rows[-1][3]
    assert math.dist((last.x_m, last.y_m, last.z_m), (0.0, 0.0, 3.0)) < 0.05


def test_a_position_dropout_longer_than_fs_pos_tmo_is_the_state_loss_failsafe() -> None:
    core, events, _ = _fly(20.0, dropout=(8.0, 10.0, "position_m"), params=(("FS_POS_TMO", 0.6),))
    texts = _texts(events)
    assert texts[:5] == ["Armed", "Takeoff to 3.0 m", "position lost: dead reckoning",
                         "FAILSAFE: position lost, level and descend", "position back"]  # fmt: skip
    assert events[3][0] == pytest.approx(8.6, abs=1e-6)  # FS_POS_TMO after the loss
    assert events[4][0] == pytest.approx(10.0, abs=1e-6)
    assert "State back: failsafe landing" in texts and texts[-1] == "Landed: disarmed"
    assert core.failsafe_events == 1 and not core.flight.armed


def test_an_attitude_dropout_is_the_failsafe_at_once() -> None:
    core, events, rows = _fly(10.0, dropout=(6.0, 6.1, "euler_rad"))
    assert ("FAILSAFE: attitude lost, level and descend" in _texts(events)
            and events[_texts(events).index("FAILSAFE: attitude lost, level and descend")][0] == pytest.approx(6.0, abs=1e-6))  # fmt: skip
    assert "attitude back" in _texts(events) and "State back: failsafe landing" in _texts(events)
    assert all(st is not None and math.isfinite(st.phi_rad) for _, _, _, st in rows)  # the core never holds a NaN


def test_clean_flight_hold_point_is_the_state_every_tick() -> None:
    """Take-off, a 4 m step, LOITER and LAND at the current place while moving: every set-point
    "here" is the sample itself, as before the filter."""
    plan = (PlanStep(0.0, "takeoff", alt_m=3.0), PlanStep(6.0, "goto", north_m=4.0, east_m=-3.0, alt_m=3.0),
            PlanStep(7.0, "land"))  # fmt: skip
    seen = []

    def check(core, st, out) -> None:
        assert core.commander.estimate is not None
        h = core.commander.here(st)
        s = core.state
        assert (h.x_m, h.y_m, h.z_m, h.psi_rad) == (s.x_m, s.y_m, s.z_m, s.psi_rad)
        seen.append(s)

    core, events, rows = _fly(9.0, plan=plan, on_tick=check)
    assert len(seen) == len(rows) == 4501 and "Mode LAND" in _texts(events)
    t_land = next(t for t, text in events if text == "Mode LAND")
    at = next(st for t, _, _, st in rows if t >= t_land - 1e-9)
    assert core.flight.target[:2] == (at.x_m, at.y_m)  # LAND where it was, sample exact


@pytest.mark.parametrize("filtered", [True, False])
def test_take_off_set_point_from_the_filtered_estimate_with_noise(filtered: bool) -> None:
    """With --noise the vehicle sits at (0, 0) and each sample is off by ~1.4 cm (0.01 m per
    axis); a take-off at 1 s takes its horizontal set-point and heading from the hold point.
    ``filtered`` False: the filter switched off (its noise floor out of reach) — what it was."""
    est = EstimatorConfig() if filtered else EstimatorConfig(hold_noise_floor_m=1e3, hold_noise_floor_rad=1e3)
    errs, yaws = [], []
    for seed in range(1, 7):
        core, events, _ = _fly(1.1, noise=True, seed=seed, plan=(PlanStep(1.0, "takeoff", alt_m=3.0),), estimator=est)
        assert _texts(events)[:2] == ["Armed", "Takeoff to 3.0 m"]
        errs.append(math.hypot(*core.flight.target[:2]))
        yaws.append(abs(core.flight.yaw_target_rad))
    print(f"\nfiltered={filtered}: take-off set-point error {[f'{e * 1000:.2f}' for e in errs]} mm,"
          f" heading {[f'{y * 1000:.2f}' for y in yaws]} mrad")
    if filtered:
        assert max(errs) < 0.004 and max(yaws) < 0.001, (errs, yaws)
    else:
        assert sum(errs) / len(errs) > 0.006 and sum(yaws) / len(yaws) > 0.0008, (errs, yaws)
