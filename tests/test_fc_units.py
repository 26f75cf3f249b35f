"""Fast in-process tests of the FC's pieces: mixer, prefilter, position loop, yaw handling,
the in-process flight and plan parsing. Paper frame throughout (x north, y west, z up)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fc.config import FcConfig
from fc.flight import FlightControl, VehicleState
from fc.mixer import Mixer
from fc.position import PositionGains, position_step
from fc.prefilter import prefilter_step
from lab.runner import fly
from sim_bridge.environment import Environment
from sim_bridge.plants.rigid_body import RigidBodyPlant
from smcpilot.frames import rotation_matrix_from_euler, wrap_pi
from smcpilot.model import PaperModel
from smcpilot.plan import PlanError, PlanStep, parse_plan
from smcpilot.vehicle import DEFAULT_VEHICLE

V = DEFAULT_VEHICLE
W = V.weight_n
MIXER = Mixer(V)
MODEL = PaperModel.from_vehicle(V)
LO_SQ = V.rotor_speed_idle_radps**2
HI_SQ = V.rotor_speed_max_radps**2
T_MIN, T_MAX = MIXER.thrust_range_n


def omega_sq(commands) -> tuple[float, ...]:
    """Rotor speeds squared the commands ask for (thrust-linear above idle)."""
    return tuple(LO_SQ + c * (HI_SQ - LO_SQ) for c in commands)


def rel(a: float, b: float, scale: float) -> float:
    return abs(a - b) / scale


# -- mixer ------------------------------------------------------------------------------------
def test_mixer_realises_feasible_inputs_exactly_and_round_trips() -> None:
    u = (0.2, -0.15, 0.004, W)
    motors, realised, limited = MIXER.mix(*u)
    assert limited == (False, False, False, False)
    assert realised == pytest.approx(u, rel=1e-12, abs=1e-12)
    assert all(0.0 < c < 1.0 for c in motors)
    w_sq = omega_sq(motors)
    # The motors' speeds are the paper's eq. (11) inverse of u, and produce u again.
    assert w_sq == pytest.approx(MODEL.unmix(*u), rel=1e-9)
    assert MODEL.mix(*w_sq) == pytest.approx(u, rel=1e-9, abs=1e-12)


def test_mixer_hover_is_four_equal_commands() -> None:
    motors, realised, limited = MIXER.mix(0.0, 0.0, 0.0, W)
    assert len(set(motors)) == 1 and not any(limited)
    assert 4.0 * V.thrust_coeff_n_s2 * omega_sq(motors)[0] == pytest.approx(W)


def test_mixer_keeps_roll_pitch_when_thrust_saturates_high() -> None:
    u = (0.6, -0.4, 0.01, 2.0 * T_MAX)
    motors, realised, limited = MIXER.mix(*u)
    assert realised[0] == pytest.approx(u[0], rel=1e-12)
    assert realised[1] == pytest.approx(u[1], rel=1e-12)
    assert limited[3] and not limited[0] and not limited[1]
    assert realised[3] < T_MAX
    assert max(motors) == pytest.approx(1.0)
    assert MODEL.mix(*omega_sq(motors)) == pytest.approx(realised, rel=1e-9, abs=1e-12)


def test_mixer_keeps_roll_pitch_when_thrust_saturates_low() -> None:
    u = (-0.5, 0.3, 0.0, 0.0)  # no thrust asked (below idle)
    motors, realised, limited = MIXER.mix(*u)
    assert realised[0] == pytest.approx(u[0], rel=1e-12)
    assert realised[1] == pytest.approx(u[1], rel=1e-12)
    assert limited[3] and realised[3] >= T_MIN
    assert min(motors) == pytest.approx(0.0, abs=1e-12)
    assert MODEL.mix(*omega_sq(motors)) == pytest.approx(realised, rel=1e-9, abs=1e-12)


def test_mixer_gives_up_yaw_first() -> None:
    u = (0.8, 0.5, 1.0, W)  # a yaw torque the rotors cannot make next to this roll/pitch
    motors, realised, limited = MIXER.mix(*u)
    assert realised[0] == pytest.approx(u[0], rel=1e-12)
    assert realised[1] == pytest.approx(u[1], rel=1e-12)
    assert realised[3] == pytest.approx(u[3], rel=1e-12)
    assert limited == (False, False, True, False)
    assert 0.0 < realised[2] < u[2]
    assert max(motors) == pytest.approx(1.0) or min(motors) == pytest.approx(0.0, abs=1e-12)


def test_mixer_scales_roll_and_pitch_together() -> None:
    u = (20.0, -10.0, 0.0, W)  # far beyond the rotors' differential authority
    motors, realised, limited = MIXER.mix(*u)
    assert limited[0] and limited[1]
    assert realised[0] / realised[1] == pytest.approx(u[0] / u[1], rel=1e-12), "direction of the moment changed"
    assert 0.0 < realised[0] < u[0]
    assert all(0.0 <= c <= 1.0 for c in motors)


finite_u = st.tuples(
    st.floats(-50.0, 50.0), st.floats(-50.0, 50.0), st.floats(-5.0, 5.0), st.floats(-5.0, 3.0 * T_MAX)
)


@settings(max_examples=400, deadline=None)
@given(finite_u)
def test_mixer_property_commands_in_range_and_realised_is_what_motors_make(u) -> None:
    motors, realised, limited = MIXER.mix(*u)
    assert all(0.0 <= c <= 1.0 for c in motors), motors
    scale = (1.0, 1.0, 0.1, W)
    made = MODEL.mix(*omega_sq(motors))
    for i in range(4):
        assert rel(made[i], realised[i], scale[i]) < 1e-9, (i, made, realised)
        # never reversed: the realised input has the sign asked for (or is zero)
        assert realised[i] * u[i] >= -1e-12 or (i == 3 and u[3] < T_MIN)
        if not limited[i]:
            assert rel(realised[i], u[i], scale[i]) < 1e-9, (i, u, realised, limited)


@pytest.mark.parametrize("channel", range(4))
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), float("-inf")])
def test_mixer_non_finite_input_never_reaches_the_motors(channel: int, bad: float) -> None:
    """Regression (found by this suite, fixed in 87ee56b): a NaN u used to pass straight through the
    final clamps and reach the motors as NaN commands, with no limited flag."""
    u = [0.1, -0.1, 0.0, W]
    u[channel] = bad
    motors, realised, limited = MIXER.mix(*u)
    assert all(math.isfinite(c) and 0.0 <= c <= 1.0 for c in motors), motors
    assert all(math.isfinite(r) for r in realised), realised
    assert all(limited), "the law's anti-windup must hear that its input was not realised"
    if channel < 3:
        assert realised[channel] == 0.0, "a non-finite moment must be dropped, not saturated"


# -- prefilter --------------------------------------------------------------------------------
DT = 0.002


def run_prefilter(target: float, seconds: float, omega: float = 1.8, v_max: float = math.inf, a_max: float = math.inf,
                  x0: float = 0.0) -> np.ndarray:  # fmt: skip
    x, v, a = x0, 0.0, 0.0
    rows = [(x, v, a, 0.0)]
    for _ in range(int(round(seconds / DT))):
        x, v, a, j = prefilter_step(x, v, a, target, omega, DT, v_max, a_max)
        rows.append((x, v, a, j))
    return np.array(rows)


def test_prefilter_converges_to_the_target_without_overshoot() -> None:
    r = run_prefilter(2.5, 10.0)
    x, v, a = r[-1, :3]
    assert x == pytest.approx(2.5, abs=1e-4)
    assert abs(v) < 1e-3 and abs(a) < 1e-3
    assert r[:, 0].max() <= 2.5 + 1e-9, "critically damped: no overshoot"
    assert (np.diff(r[:, 0]) >= -1e-12).all(), "monotonic approach"
    # mirror image for a negative step from elsewhere
    m = run_prefilter(-2.5, 10.0)
    assert np.allclose(m[:, :3], -r[:, :3], atol=1e-12)


def test_prefilter_derivatives_match_finite_differences() -> None:
    r = run_prefilter(1.0, 4.0)
    x, v, a, j = r.T
    # The recursion itself: x' = v, v' = a, a' = j, one step at a time (semi-implicit Euler).
    assert np.allclose(np.diff(x) / DT, v[1:], rtol=0, atol=1e-9)
    assert np.allclose(np.diff(v) / DT, a[1:], rtol=0, atol=1e-9)
    assert np.allclose(np.diff(a) / DT, j[1:], rtol=0, atol=1e-6)
    # And as smooth signals: central differences agree to O(dt).
    assert np.allclose(np.gradient(x, DT)[5:-5], v[5:-5], atol=5e-3)
    assert np.allclose(np.gradient(v, DT)[5:-5], a[5:-5], atol=2e-2)


@pytest.mark.parametrize("target", [10.0, -7.0])
def test_prefilter_respects_speed_and_acceleration_limits(target: float) -> None:
    v_max, a_max = 3.0, 3.0
    r = run_prefilter(target, 15.0, v_max=v_max, a_max=a_max)
    x, v, a, _ = r.T
    assert np.abs(v).max() <= v_max + 1e-12
    assert np.abs(a).max() <= a_max + 1e-12
    assert np.abs(v).max() == pytest.approx(v_max), "a 10 m step should reach the speed limit"
    assert np.abs(np.diff(v) / DT).max() <= a_max + 1e-9, "velocity changed faster than the acceleration limit"
    assert x[-1] == pytest.approx(target, abs=1e-3)
    assert (np.sign(target) * (x - target)).max() <= 1e-9, "overshoot with limits"


# -- position loop ------------------------------------------------------------------------------
PG = PositionGains()
G = V.gravity_mps2


def pos_step(x_ref=0.0, y_ref=0.0, psi=0.0, az_ref=0.0, int_x=0.0, int_y=0.0, gains=PG, dt=DT):
    return position_step(gains, G, 0.0, 0.0, 0.0, 0.0, x_ref, y_ref, 0.0, 0.0, 0.0, 0.0, az_ref, psi, int_x, int_y, dt)


def test_position_north_demand_pitches_forward() -> None:
    phi, theta, _, _ = pos_step(x_ref=1.0)
    assert theta > 0.0 and phi == pytest.approx(0.0, abs=1e-12)


def test_position_west_demand_rolls_negative_at_zero_yaw() -> None:
    phi, theta, _, _ = pos_step(y_ref=1.0)  # +y is west in the paper frame
    assert phi < 0.0 and theta == pytest.approx(0.0, abs=1e-12)


@settings(max_examples=200, deadline=None)
@given(st.floats(-1.1, 1.1), st.floats(-1.1, 1.1), st.floats(-math.pi, math.pi))
def test_position_thrust_points_along_the_demanded_acceleration(ex: float, ey: float, psi: float) -> None:
    """For any heading, body z of R(phi_d, theta_d, psi) is parallel to (a_x, a_y, g)."""
    phi, theta, _, _ = pos_step(x_ref=ex, y_ref=ey, psi=psi)
    ax, ay = PG.kp_1ps2 * ex, PG.kp_1ps2 * ey  # below accel_max and tilt_max for these errors (|a| <= 3 * 1.1 * sqrt 2 < 5)
    R = rotation_matrix_from_euler(phi, theta, psi)
    zb = np.array([R[0][2], R[1][2], R[2][2]])
    want = np.array([ax, ay, G]) / math.sqrt(ax * ax + ay * ay + G * G)
    assert np.allclose(zb, want, atol=1e-9), (zb, want)


def test_position_tilt_limit() -> None:
    g = PositionGains(accel_max_mps2=100.0)
    for x_ref, y_ref in ((50.0, 0.0), (0.0, -50.0), (-40.0, 40.0)):
        phi, theta, _, _ = pos_step(x_ref=x_ref, y_ref=y_ref, psi=0.3, gains=g)
        assert abs(phi) <= g.tilt_max_rad + 1e-12 and abs(theta) <= g.tilt_max_rad + 1e-12
        assert max(abs(phi), abs(theta)) == pytest.approx(g.tilt_max_rad)
    # A free-fall reference (z'' = -g) must not divide by ~0 or flip the vehicle.
    phi, theta, _, _ = pos_step(x_ref=1.0, az_ref=-2.0 * G)
    assert 0.0 < theta <= PG.tilt_max_rad


def test_position_integrator_anti_windup() -> None:
    # Saturated demand (100 m away): the integrator does not move.
    _, _, ix, iy = pos_step(x_ref=100.0, y_ref=-100.0, int_x=0.3, int_y=-0.2)
    assert (ix, iy) == (0.3, -0.2)
    # Small error: it integrates e dt.
    _, _, ix, iy = pos_step(x_ref=0.5, y_ref=-0.25)
    assert (ix, iy) == pytest.approx((0.5 * DT, -0.25 * DT))
    # And is clamped at the vehicle's authority / ki: min(int_limit, accel_max, g tan(tilt_max)) / ki.
    auth = min(PG.int_limit_mps2, PG.accel_max_mps2, G * math.tan(PG.tilt_max_rad))
    assert auth == PG.accel_max_mps2 == 5.0
    lim = auth / PG.ki_1ps3
    _, _, ix, iy = pos_step(x_ref=0.5, y_ref=-0.5, int_x=lim, int_y=-lim)
    assert (ix, iy) == (lim, -lim)
    _, _, ix, iy = pos_step(x_ref=0.5, y_ref=-0.5, int_x=2.0 * lim, int_y=-2.0 * lim)
    assert (ix, iy) == (lim, -lim)
    # Conditional integration: while saturated, an axis integrates only if that unwinds the demand.
    _, _, ix, _ = position_step(PG, G, 0.0, 0.0, -20.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, DT)
    assert ix == -1.0  # demand saturated north (a_x > 0), error north: would wind up, frozen
    _, _, ix, _ = position_step(PG, G, 0.0, 0.0, 20.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, DT)
    assert ix == pytest.approx(1.0 + 0.5 * DT)  # demand saturated south (a_x < 0), error north: unwinds, integrates
    _, _, ix, _ = position_step(PG, G, 0.0, 0.0, 20.0, 0.0, -0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, DT)
    assert ix == 1.0  # demand saturated south, error south: would wind up further, frozen
    # A long saturated transit leaves it where it was (no windup to unwind afterwards).
    ix = iy = 0.0
    for _ in range(5000):
        _, _, ix, iy = position_step(PG, G, 0.0, 0.0, 2.0, 0.0, 30.0, 0.0, 3.0, 0.0, 0.0, 0.0, 0.0, 0.0, ix, iy, DT)
    assert (ix, iy) == (0.0, 0.0)


# -- FlightControl: yaw across +-180 -----------------------------------------------------------
def hover_state(psi: float, z: float = 3.0) -> VehicleState:
    return VehicleState(0.0, 0.0, z, 0.0, 0.0, 0.0, 0.0, 0.0, psi, 0.0, 0.0, 0.0)


@pytest.mark.parametrize("start_deg, target_deg, change_deg", [(170.0, -170.0, 20.0), (-170.0, 170.0, -20.0),
                                                              (179.0, -179.0, 2.0), (10.0, 370.0, 0.0)])  # fmt: skip
def test_flight_yaw_target_takes_the_short_way(start_deg: float, target_deg: float, change_deg: float) -> None:
    fl = FlightControl(FcConfig(), V)
    st0 = hover_state(math.radians(start_deg))
    fl.arm(st0)
    fl.set_target(0.0, 0.0, 3.0, math.radians(target_deg))
    assert fl.yaw_target_rad == pytest.approx(wrap_pi(math.radians(target_deg)))
    refs = []
    for _ in range(3000):  # 6 s; the vehicle is held still: only the reference matters here
        refs.append(fl.step(st0, 0.002).ref[2])
    refs = np.degrees(refs)
    assert refs[-1] - start_deg == pytest.approx(change_deg, abs=0.1)
    steps = np.diff(refs)
    if change_deg > 0:
        assert (steps >= -1e-9).all(), "the yaw reference reversed"
    elif change_deg < 0:
        assert (steps <= 1e-9).all(), "the yaw reference reversed"
    assert np.abs(refs - start_deg).max() <= abs(change_deg) + 1e-6, "the reference went the long way"


def test_flight_law_sees_the_wrapped_yaw_error() -> None:
    """Heading 179 deg, reference -179 deg (= 181): the psi sliding variable is that of a 2 deg
    error, not of a 358 deg one."""
    fl = FlightControl(FcConfig(), V)
    fl.arm(hover_state(math.radians(-179.0)))
    out = fl.step(hover_state(math.radians(179.0)), 0.002)
    c1 = FcConfig().gains[2].c1
    assert abs(out.diag.s[2]) <= c1 * math.radians(2.0) + 1e-6


# -- in-process flight ------------------------------------------------------------------------
def test_inprocess_takeoff_and_hold() -> None:
    plant = RigidBodyPlant(V, Environment())
    run = fly(FcConfig(), V, plant, (PlanStep(0.0, "takeoff", alt_m=3.0),), 8.0, record_every=10)
    assert run.ticks == 4000
    assert run.events and run.events[0][1].startswith("Armed")
    t = np.array(run.t_s)
    z = np.array([s.z_m for s in run.states])
    xy = np.array([(s.x_m, s.y_m) for s in run.states])
    tilt = np.array([max(abs(s.phi_rad), abs(s.theta_rad)) for s in run.states])
    hold = t >= 6.0
    assert np.abs(z[hold] - 3.0).max() < 0.02
    assert z.max() < 3.03, "altitude overshoot"
    assert np.abs(xy).max() < 1e-6 and np.degrees(tilt).max() < 0.1
    assert z[np.searchsorted(t, 1.0)] > 0.3, "did not climb"


# -- plan parsing ---------------------------------------------------------------------------------
def step(**kw) -> dict:
    return kw


PLAN_ERRORS = [
    ({}, "no [[step]] tables"),
    ({"step": [step(t_s=0.0, action="takeoff", alt_m=3.0)], "stepz": 1}, "unknown top-level key 'stepz'"),
    ({"step": [step(t_s=0.0, action="fly", alt_m=3.0)]}, "step 1: action must be one of"),
    ({"step": [step(t_s=0.0, action="takeoff")]}, "step 1 (takeoff): missing key 'alt_m'"),
    ({"step": [step(t_s=0.0, action="takeoff", alt_m=3.0), step(t_s=1.0, action="goto", north_m=1.0, alt_m=2.0)]},
     "step 2 (goto): missing key 'east_m'"),  # fmt: skip
    ({"step": [step(t_s=0.0, action="land", alt_m=1.0)]}, "step 1 (land): unknown key 'alt_m'"),
    ({"step": [step(t_s=0.0, action="takeoff", alt_m="high")]}, "step 1: alt_m must be a finite number"),
    ({"step": [step(t_s=0.0, action="takeoff", alt_m=float("nan"))]}, "step 1: alt_m must be a finite number"),
    ({"step": [step(t_s=0.0, action="takeoff", alt_m=True)]}, "step 1: alt_m must be a finite number"),
    ({"step": [step(t_s=5.0, action="takeoff", alt_m=3.0), step(t_s=1.0, action="land")]}, "step 2: t_s must be >= 0"),
    ({"step": [step(t_s=-1.0, action="takeoff", alt_m=3.0)]}, "step 1: t_s must be >= 0"),
    ({"step": [step(t_s=0.0, action="takeoff", alt_m=600.0)]}, "step 1: alt_m must lie in [0, 500]"),
    ({"step": ["takeoff"]}, "step 1: not a table"),
]


@pytest.mark.parametrize("doc, needle", PLAN_ERRORS)
def test_parse_plan_errors_name_the_step_and_key(doc: dict, needle: str) -> None:
    with pytest.raises(PlanError) as info:
        parse_plan(doc, "mission.toml")
    msg = str(info.value)
    assert msg.startswith("mission.toml"), msg
    assert needle in msg, msg


def test_parse_plan_accepts_a_good_plan() -> None:
    doc = {
        "name": "x",
        "step": [
            step(t_s=0, action="takeoff", alt_m=3),
            step(t_s=4.0, action="goto", north_m=1.0, east_m=-2.0, alt_m=3.0, yaw_deg=-170.0),
            step(t_s=9.0, action="land"),
            step(t_s=20.0, action="disarm"),
        ],
    }
    steps = parse_plan(doc)
    assert [s.action for s in steps] == ["takeoff", "goto", "land", "disarm"]
    assert steps[1] == PlanStep(4.0, "goto", 1.0, -2.0, 3.0, -170.0)
    assert isinstance(steps[0].t_s, float) and isinstance(steps[0].alt_m, float)
