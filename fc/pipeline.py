"""The flight pipeline of one control tick as a pure function: (state, inputs, params) -> (state, outputs).

:func:`pipeline_step` is everything :meth:`fc.flight.FlightControl.step` computes — position and
altitude prefilters, the outer position loop, the attitude and yaw prefilters, the control law, the
priority mixer, anti-windup and touchdown detection — over floats, tuples and NamedTuples only:

- :class:`PipelineParams`: the configuration, validated once in the frozen dataclasses
  (:class:`fc.config.FcConfig`, the law's parameters, :class:`smcpilot.vehicle.VehicleParams`)
  and flattened by :func:`pipeline_params` at start-up (and on a live parameter change);
- :class:`PipelineState`: what carries over between ticks (prefilter states, the position loop's
  integrators, the law's state, the landed timer);
- :class:`PipelineInputs`: what the commander sets (target, yaw target, flags, speed limit);
- the outputs, a plain tuple (see :func:`pipeline_step`): motor commands, realised inputs, limited
  flags, the law's internals, the references, and whether the vehicle has touched down (the
  caller then disarms).

No objects with methods, no lists, dicts, exceptions, string formatting or ``getattr`` on the way:
the same functions run under CPython and, unchanged, under numba's ``njit`` (see
``tests/test_compilable.py``). :class:`fc.flight.FlightControl` is the thin stateful object the
rest of the FC uses around them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from fc.config import FcConfig
from fc.control import LAW_FUNCTIONS
from fc.control.builtin import BUILTIN_FLIGHT_FUNCTIONS
from fc.control.law import Law, LawContext, LawFunctions
from fc.control.observer import observer_estimate, observer_reset, observer_update, observer_update_gz
from fc.control.pid_smc import DISTURBANCE_ESTIMATES, DOB_INPUT, DOB_LUMPED, DOB_NONE, DOB_SIGMA
from fc.mixer import MixerParams, mix, mixer_params
from fc.position import PositionLoopParams, position_step
from fc.prefilter import prefilter_step
from smcpilot.frames import wrap_pi
from smcpilot.model import PaperModel, tilt_cos
from smcpilot.vehicle import VehicleParams

_INF = math.inf
_NAN = math.nan
_ZERO4 = (0.0, 0.0, 0.0, 0.0)
_ZERO8 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

#: :attr:`ObserverConsts.mode` values (``DOB_MODE``, :data:`fc.control.pid_smc.DISTURBANCE_ESTIMATES`
#: order): no observer; the estimate handed to the law, which uses it in its sigma or lumped into its
#: model (the PID-SMC; other laws may ignore it); cancelled at the law's output (u_cmd = u - d_hat/g).
DOB_OFF = DOB_NONE
#: smallest |cos phi cos theta| in the observer's and the hover trim's g_z.
TILT_COS_MIN = 0.05


class ObserverConsts(NamedTuple):
    """The disturbance observer's configuration, flattened (:mod:`fc.control.observer`)."""

    #: :data:`DOB_OFF`, :data:`DOB_SIGMA`, :data:`DOB_LUMPED` or :data:`DOB_INPUT`.
    mode: int
    #: bandwidth per channel, rad/s.
    w: tuple[float, float, float, float]
    #: largest |d_hat| per channel (rad/s^2 x3, m/s^2).
    d_max: tuple[float, float, float, float]
    #: the rotors' time constant the observer models, s (0: none).
    tau: float
    #: the nominal model's constants (ModelConsts order).
    model: tuple[float | bool, ...]
    tilt_min: float
    inv_mass: float
    #: the control period the rotors' lag below was computed for, s (the FC's; another period
    #: computes its own), and that lag (:func:`observer_lag`; zeros without a lag model).
    lag_dt: float
    lag_a: float
    lag_b: float


class VehicleState(NamedTuple):
    """Estimated vehicle state in the paper frame (m, m/s, rad, rad/s; Euler-angle rates)."""

    x_m: float
    y_m: float
    z_m: float
    vx_mps: float
    vy_mps: float
    vz_mps: float
    phi_rad: float
    theta_rad: float
    psi_rad: float
    phi_dot_radps: float
    theta_dot_radps: float
    psi_dot_radps: float


class PipelineParams(NamedTuple):
    """The configuration of the pipeline, flattened (floats, ints, bools and NamedTuples of them)."""

    #: position/altitude prefilter bandwidth, rad/s.
    pos_filter_omega_radps: float
    accel_ref_max_mps2: float
    speed_max_xy_mps: float
    speed_max_z_mps: float
    land_speed_mps: float
    att_filter_omega_radps: float
    yaw_filter_omega_radps: float
    yaw_rate_max_radps: float
    land_detect_height_m: float
    land_detect_s: float
    gravity_mps2: float
    position: PositionLoopParams
    mixer: MixerParams
    #: the disturbance observer in front of the law.
    observer: ObserverConsts
    #: the law's constants (whatever its ``consts`` returned: a tuple of numbers and tuples).
    law: tuple


class PipelineState(NamedTuple):
    """What the pipeline carries from one tick to the next (paper frame)."""

    #: position/altitude prefilters: (reference, rate, acceleration) per axis.
    x_r: float
    vx_r: float
    ax_r: float
    y_r: float
    vy_r: float
    ay_r: float
    z_r: float
    vz_r: float
    az_r: float
    #: roll and pitch reference prefilters.
    phi_r: float
    phi_v: float
    phi_a: float
    theta_r: float
    theta_v: float
    theta_a: float
    #: yaw reference prefilter (unwrapped).
    psi_r: float
    psi_v: float
    psi_a: float
    #: the position loop's integrators.
    int_x: float
    int_y: float
    #: the law's state (its own length and layout).
    law: tuple
    #: True: the law's state is a placeholder, initialised from the measurement on the next step
    #: (after a change of law while armed).
    law_init: bool
    #: time spent settled on the ground while landing, s.
    landed_s: float
    #: the disturbance observer's state (:mod:`fc.control.observer`; 8 floats, zeros when unused).
    dob: tuple[float, ...] = _ZERO8
    #: the input the mixer realised on the previous tick (u_phi N, u_theta N, u_psi N m, u_z N).
    u_prev: tuple[float, float, float, float] = _ZERO4


class PipelineInputs(NamedTuple):
    """What the commander decides, as the pipeline reads it (paper frame)."""

    target_x_m: float
    target_y_m: float
    target_z_m: float
    #: yaw set-point on the unwrapped scale of :attr:`PipelineState.psi_r`, rad.
    psi_target_rad: float
    armed: bool
    landing: bool
    #: False in ALT_HOLD: level attitude, no horizontal position control.
    position_hold: bool
    #: the horizontal reference speed limit in force, m/s.
    speed_xy_mps: float


# -- start-up: validated configuration -> flat parameters ---------------------------------------------
def observer_authority(vehicle: VehicleParams) -> tuple[float, float, float, float]:
    """Largest |d_hat| worth estimating per channel: the angular accelerations full differential thrust
    gives (rad/s^2) and 2 g vertically (m/s^2). Beyond that no input can cancel it anyway."""
    v = vehicle
    f_max = v.thrust_coeff_n_s2 * v.rotor_speed_max_radps**2
    q_max = v.drag_coeff_n_m_s2 * v.rotor_speed_max_radps**2
    return (
        2.0 * v.arm_length_m * f_max / v.ixx_kg_m2,
        2.0 * v.arm_length_m * f_max / v.iyy_kg_m2,
        4.0 * q_max / v.izz_kg_m2,
        2.0 * v.gravity_mps2,
    )


def observer_mode(config: FcConfig, law: Law) -> str:
    """The observer mode in force: ``DOB_MODE``, or the law's own default where it is "auto" (-1)."""
    return law.observer_default if config.disturbance_estimate == "auto" else config.disturbance_estimate


def observer_consts(config: FcConfig, vehicle: VehicleParams, model: PaperModel, mode: str) -> ObserverConsts:
    """The observer stage of ``config`` (``DOB_*``) for ``vehicle`` in ``mode``, flattened."""
    c = config
    wa = float(c.dob_bandwidth_att_radps)
    tau = float(vehicle.motor_time_constant_s) if c.dob_motor_lag else 0.0
    lag_dt = c.period_s
    lag_a, lag_b = observer_lag(tau, lag_dt)
    return ObserverConsts(
        mode=DISTURBANCE_ESTIMATES.index(mode),
        w=(wa, wa, float(c.dob_bandwidth_yaw_radps), float(c.dob_bandwidth_z_radps)),
        d_max=tuple(float(x) for x in observer_authority(vehicle)),  # type: ignore[arg-type]
        tau=tau,
        model=tuple(model.consts()),
        tilt_min=TILT_COS_MIN,
        inv_mass=1.0 / model.mass_kg,
        lag_dt=lag_dt,
        lag_a=lag_a,
        lag_b=lag_b,
    )


def law_context(config: FcConfig, vehicle: VehicleParams, model: PaperModel | None = None) -> LawContext:
    return LawContext(vehicle, model if model is not None else PaperModel.from_vehicle(vehicle), float(config.rate_hz), config)


def pipeline_params(config: FcConfig, vehicle: VehicleParams, law: Law, law_params: object) -> PipelineParams:
    """Flatten a validated configuration, a vehicle, the law and its parameters (once, not per tick)."""
    model = PaperModel.from_vehicle(vehicle)
    c = config
    return PipelineParams(
        pos_filter_omega_radps=float(c.pos_filter_omega_radps),
        accel_ref_max_mps2=float(c.accel_ref_max_mps2),
        speed_max_xy_mps=float(c.speed_max_xy_mps),
        speed_max_z_mps=float(c.speed_max_z_mps),
        land_speed_mps=float(c.land_speed_mps),
        att_filter_omega_radps=float(c.att_filter_omega_radps),
        yaw_filter_omega_radps=float(c.yaw_filter_omega_radps),
        yaw_rate_max_radps=float(c.yaw_rate_max_radps),
        land_detect_height_m=float(c.land_detect_height_m),
        land_detect_s=float(c.land_detect_s),
        gravity_mps2=float(vehicle.gravity_mps2),
        position=c.position.flat(),
        mixer=mixer_params(vehicle),
        observer=observer_consts(c, vehicle, model, observer_mode(c, law)),
        law=law.consts(law_context(c, vehicle, model), law_params),
    )


# -- the pure functions -------------------------------------------------------------------------------
def observer_lag(tau: float, dt_s: float) -> tuple[float, float]:
    """(lag_a, lag_b) of :func:`fc.control.observer.observer_update` for rotors of time constant
    ``tau`` over a control period of ``dt_s``: exp(-dt/tau) and tau (1 - lag_a)/dt; zeros for no lag."""
    lag_a = lag_b = 0.0
    if tau > 0.0:
        lag_a = math.exp(-dt_s / tau)
        lag_b = tau * (1.0 - lag_a) / dt_s
    return lag_a, lag_b


def hover_input(phi: float, theta: float, ob: ObserverConsts) -> tuple[float, float, float, float]:
    """The input that holds the nominal vehicle at this attitude: no torques, u_z = m g / (cos phi cos theta)."""
    m = ob.model
    return (0.0, 0.0, 0.0, m[0] * m[1] / tilt_cos(phi, theta, ob.tilt_min))  # mass_kg * gravity_mps2


def pipeline_reset(st: VehicleState, p: PipelineParams, law: LawFunctions) -> PipelineState:
    """The state on arming at ``st``: references start where the vehicle is, the law at its initial state."""
    meas = (st.phi_rad, st.phi_dot_radps, st.theta_rad, st.theta_dot_radps, st.psi_rad, st.psi_dot_radps, st.z_m, st.vz_mps)
    law_state = law.initial_state(meas, p.law)
    dob = observer_reset(meas, hover_input(st.phi_rad, st.theta_rad, p.observer), p.observer.w)
    return PipelineState(
        st.x_m, st.vx_mps, 0.0, st.y_m, st.vy_mps, 0.0, st.z_m, st.vz_mps, 0.0,
        st.phi_rad, 0.0, 0.0, st.theta_rad, 0.0, 0.0, st.psi_rad, 0.0, 0.0,
        0.0, 0.0, law_state, False, 0.0, dob, _ZERO4,
    )  # fmt: skip


def pipeline_reset_full(st: VehicleState, p: PipelineParams, law: LawFunctions) -> PipelineState:
    """:func:`pipeline_reset` for a whole-stack law (its initial state from the 12-float state)."""
    law_state = law.initial_state(st, p.law)
    meas = (st.phi_rad, st.phi_dot_radps, st.theta_rad, st.theta_dot_radps, st.psi_rad, st.psi_dot_radps, st.z_m, st.vz_mps)
    dob = observer_reset(meas, hover_input(st.phi_rad, st.theta_rad, p.observer), p.observer.w)
    return PipelineState(
        st.x_m, st.vx_mps, 0.0, st.y_m, st.vy_mps, 0.0, st.z_m, st.vz_mps, 0.0,
        st.phi_rad, 0.0, 0.0, st.theta_rad, 0.0, 0.0, st.psi_rad, 0.0, 0.0,
        0.0, 0.0, law_state, False, 0.0, dob, _ZERO4,
    )  # fmt: skip


Vec4 = tuple[float, float, float, float]
#: the outputs of :func:`pipeline_step`, in order (see there).
PipelineOutputs = tuple[Vec4, Vec4, tuple[bool, bool, bool, bool], Vec4, Vec4, Vec4, Vec4, Vec4, Vec4, bool, Vec4]


def pipeline_off() -> PipelineOutputs:
    """The outputs when disarmed: motors stopped, nothing limited, references unknown."""
    return (_ZERO4, _ZERO4, (False, False, False, False), _ZERO4, _ZERO4, _ZERO4, _ZERO4, _ZERO4,
            (_NAN, _NAN, _NAN, _NAN), False, _ZERO4)  # fmt: skip


def observer_in(dob: tuple[float, ...], meas: tuple[float, ...], z_m: float, land_h: float, ob: ObserverConsts) -> tuple[Vec4, Vec4]:
    """(d_hat, the share of it the law is given) before the law runs: zeros without an observer or on
    the ground (the ground's reaction is no disturbance to cancel); the law gets it only in the
    sigma and lumped modes."""
    d_hat = _ZERO4
    if ob.mode != DOB_OFF and z_m >= land_h:
        d_hat = observer_estimate(dob, meas, ob.w, ob.d_max)
    if ob.mode == DOB_SIGMA or ob.mode == DOB_LUMPED:
        return d_hat, d_hat
    return d_hat, _ZERO4


def actuate(
    law: LawFunctions,
    prev: tuple,
    new: tuple,
    u: Vec4,
    meas: tuple[float, ...],
    d_hat: Vec4,
    dob: tuple[float, ...],
    landing: bool,
    land_h: float,
    p: PipelineParams,
    dt_s: float,
) -> tuple[Vec4, Vec4, tuple[bool, bool, bool, bool], tuple, tuple[float, ...], Vec4, Vec4]:
    """After the law: the observer's compensation at the input (``DOB_MODE`` 3), the priority mixer,
    the law's anti-windup on what was realised, the observer's update. Returns (motors, realised u,
    limited, the law's state, the observer's state, the input commanded to the mixer, the law's own
    share of the realised input: what the law's next step gets as ``u_prev``)."""
    ob = p.observer
    c0 = c1 = c2 = c3 = 0.0
    # the observer's input gain of the z channel (the compensation's and the update's)
    gz = tilt_cos(meas[0], meas[2], ob.tilt_min) * ob.inv_mass if ob.mode != DOB_OFF else 0.0
    if ob.mode == DOB_INPUT:
        mm = ob.model
        c0 = d_hat[0] / mm[13]
        c1 = d_hat[1] / mm[14]
        c2 = d_hat[2] / mm[15]
        c3 = d_hat[3] / gz
        u = (u[0] - c0, u[1] - c1, u[2] - c2, u[3] - c3)
    motors, realised, limited = mix(p.mixer, u[0], u[1], u[2], u[3])
    if landing and meas[6] < 3.0 * land_h:
        # Ground contact is not a disturbance to learn: freeze the z channel's integrators.
        limited = (limited[0], limited[1], limited[2], True)
    # the law's own share of what was realised (the compensation is not the law's)
    law_realised = (realised[0] + c0, realised[1] + c1, realised[2] + c2, realised[3] + c3)
    if limited[0] or limited[1] or limited[2] or limited[3]:
        new = law.anti_windup(prev, new, law_realised, limited, p.law)
    if ob.mode != DOB_OFF:
        if dt_s == ob.lag_dt:
            lag_a = ob.lag_a
            lag_b = ob.lag_b
        else:
            lag_a, lag_b = observer_lag(ob.tau, dt_s)
        dob = observer_update_gz(dob, meas, d_hat, realised, ob.model, ob.w, gz, lag_a, lag_b, dt_s)
    return motors, realised, limited, new, dob, u, law_realised


def touchdown_step(landing: bool, z_m: float, vz_m: float, landed_s: float, land_h: float, land_s: float, dt_s: float) -> tuple[float, bool]:
    """(time settled on the ground, touched down): while landing, low and slow for ``land_s``."""
    if landing:
        if z_m < land_h and abs(vz_m) < 0.2:
            landed_s += dt_s
            if landed_s >= land_s:
                return landed_s, True
        else:
            landed_s = 0.0
    return landed_s, False


def pipeline_step(
    ps: PipelineState, st: VehicleState, cmd: PipelineInputs, p: PipelineParams, dt_s: float, law: LawFunctions
) -> tuple[PipelineState, PipelineOutputs]:
    """One control tick of ``dt_s`` seconds with an attitude-stage ``law`` that takes no sensed
    quantity beyond the state: :func:`pipeline_step_sensed` with none."""
    return pipeline_step_sensed(ps, st, cmd, p, dt_s, law, ())


def pipeline_step_sensed(
    ps: PipelineState, st: VehicleState, cmd: PipelineInputs, p: PipelineParams, dt_s: float, law: LawFunctions, sensed: tuple
) -> tuple[PipelineState, PipelineOutputs]:
    """One control tick of ``dt_s`` seconds with an attitude-stage ``law``: (new state, outputs).
    Disarmed: motors stopped, state unchanged. ``sensed`` follows the 8 state floats in the law's
    ``meas`` (``()``, or the measured acceleration of a law that asks for it,
    :attr:`fc.control.law.Law.measures_accel`); nothing else reads it.

    The outputs are a tuple ``(motors, u, limited, s, sigma, chi_hat, u_law, u_dot, ref, touchdown, d_hat)``:
    motor commands c1..c4 in [0, 1]; the inputs the motors realise (u_phi N, u_theta N, u_psi N m,
    u_z N); which channels the mixer limited; the law's S, sigma, chi_hat in use (0 where the law
    has none), its u before the mixer and u_dot; the references it tracked (phi_r, theta_r, psi_r,
    z_r); True once landed long enough while landing (the caller then disarms); and the
    disturbance estimate d_hat (zeros without an observer).
    """
    x_m, y_m, z_m, vx_m, vy_m, vz_m, phi, theta, psi, phi_dot, theta_dot, psi_dot = st
    tx, ty, tz, psi_target, armed, landing, position_hold, vxy = cmd
    if not armed:
        return ps, pipeline_off()
    (px, pvx, pax, py, pvy, pay, pz, pvz, paz, a0x, a0v, a0a, a1x, a1v, a1a, yx, yv, ya,
     int_x, int_y, law_state, law_init, landed_s, dob, _u_prev) = ps  # fmt: skip
    (w, amax, _vxy_max, vz_max, land_speed, wa, wy, yaw_rate_max, land_h, land_s, g,
     pos, _mixp, ob, k) = p  # fmt: skip
    if law_init:
        law_state = law.initial_state((phi, phi_dot, theta, theta_dot, psi, psi_dot, z_m, vz_m), k)
        dob = observer_reset((phi, phi_dot, theta, theta_dot, psi, psi_dot, z_m, vz_m), hover_input(phi, theta, ob), ob.w)
    # 1. Position/altitude references.
    if landing:
        tz = z_m - 10.0  # keep descending until touchdown
        vz_max = land_speed
    if not position_hold:
        # ALT_HOLD: the horizontal references follow the vehicle, so position hold can resume smoothly.
        px, pvx, pax = x_m, vx_m, 0.0
        py, pvy, pay = y_m, vy_m, 0.0
        tx, ty = x_m, y_m
    x_r, vx_r, ax_r, _ = prefilter_step(px, pvx, pax, tx, w, dt_s, vxy, amax)
    y_r, vy_r, ay_r, _ = prefilter_step(py, pvy, pay, ty, w, dt_s, vxy, amax)
    z_r, vz_r, az_r, jz_r = prefilter_step(pz, pvz, paz, tz, w, dt_s, vz_max, amax)
    # 2. Outer loop -> attitude set-points.
    phi_d, theta_d, ix, iy = position_step(
        pos, g, x_m, y_m, vx_m, vy_m, x_r, y_r, vx_r, vy_r, ax_r, ay_r, az_r, psi, int_x, int_y, dt_s
    )
    if not position_hold:
        phi_d = theta_d = 0.0
        int_x = int_y = 0.0
    elif z_m < land_h and (landing or z_r < land_h):
        # On (or at) the ground the horizontal loop has no authority: do not wind up or tilt.
        phi_d = theta_d = 0.0
    else:
        int_x = ix
        int_y = iy
    phi_r, phi_v, phi_a, phi_j = prefilter_step(a0x, a0v, a0a, phi_d, wa, dt_s, _INF, _INF)
    th_r, th_v, th_a, th_j = prefilter_step(a1x, a1v, a1a, theta_d, wa, dt_s, _INF, _INF)
    psi_r, psi_v, psi_a, psi_j = prefilter_step(yx, yv, ya, psi_target, wy, dt_s, yaw_rate_max, _INF)
    # 3. The observer's estimate, then the law, on the wrapped yaw error.
    ref = (phi_r, phi_v, phi_a, phi_j, th_r, th_v, th_a, th_j, psi_r, psi_v, psi_a, psi_j, z_r, vz_r, az_r, jz_r)
    meas = (phi, phi_dot, theta, theta_dot, psi_r + wrap_pi(psi - psi_r), psi_dot, z_m, vz_m)
    d_hat, d_law = observer_in(dob, meas, z_m, land_h, ob)
    u, new, diag = law.step(meas + sensed, ref, law_state, dt_s, k, d_law, ps.u_prev)
    # 4. Compensation, mixer with priorities, anti-windup on what was realised, observer update.
    motors, realised, limited, new, dob, u, u_law = actuate(law, law_state, new, u, meas, d_hat, dob, landing, land_h, p, dt_s)
    # 5. Touchdown while landing -> the caller disarms.
    landed_s, touchdown = touchdown_step(landing, z_m, vz_m, landed_s, land_h, land_s, dt_s)
    state = PipelineState(
        x_r, vx_r, ax_r, y_r, vy_r, ay_r, z_r, vz_r, az_r, phi_r, phi_v, phi_a, th_r, th_v, th_a,
        psi_r, psi_v, psi_a, int_x, int_y, new, False, landed_s, dob, u_law,
    )  # fmt: skip
    return state, (motors, realised, limited, diag[0], diag[1], diag[2], u, diag[3], (phi_r, th_r, psi_r, z_r), touchdown, d_hat)


def pipeline_step_full(
    ps: PipelineState, st: VehicleState, cmd: PipelineInputs, p: PipelineParams, dt_s: float, law: LawFunctions
) -> tuple[PipelineState, PipelineOutputs]:
    """One control tick with a whole-stack ``law`` that takes no sensed quantity beyond the state:
    :func:`pipeline_step_full_sensed` with none."""
    return pipeline_step_full_sensed(ps, st, cmd, p, dt_s, law, ())


def pipeline_step_full_sensed(
    ps: PipelineState, st: VehicleState, cmd: PipelineInputs, p: PipelineParams, dt_s: float, law: LawFunctions, sensed: tuple
) -> tuple[PipelineState, PipelineOutputs]:
    """One control tick with a whole-stack ``law`` (position set-point -> thrust and torques); the
    same outputs as :func:`pipeline_step`, the references being the attitude the law commands;
    ``sensed`` follows the 12 state floats in the law's ``meas`` (:func:`pipeline_step_sensed`).

    The position and yaw prefilters shape the set-point as for any law; the position loop and the
    attitude prefilters are the law's. In ALT_HOLD, and on the ground before take-off or while
    landing, the horizontal references follow the vehicle (no horizontal correction); the law's
    attitude references are stored in the attitude prefilter's slots for telemetry.
    """
    x_m, y_m, z_m, vx_m, vy_m, vz_m, phi, theta, psi, phi_dot, theta_dot, psi_dot = st
    tx, ty, tz, psi_target, armed, landing, position_hold, vxy = cmd
    if not armed:
        return ps, pipeline_off()
    (px, pvx, pax, py, pvy, pay, pz, pvz, paz, _a0x, _a0v, _a0a, _a1x, _a1v, _a1a, yx, yv, ya,
     int_x, int_y, law_state, law_init, landed_s, dob, _u_prev) = ps  # fmt: skip
    (w, amax, _vxy_max, vz_max, land_speed, _wa, wy, yaw_rate_max, land_h, land_s, _g,
     _pos, _mixp, ob, k) = p  # fmt: skip
    if law_init:
        law_state = law.initial_state(st, k)
        dob = observer_reset((phi, phi_dot, theta, theta_dot, psi, psi_dot, z_m, vz_m), hover_input(phi, theta, ob), ob.w)
    if landing:
        tz = z_m - 10.0
        vz_max = land_speed
    # ALT_HOLD, and on the ground before take-off or while landing: no horizontal correction, and the
    # law's integrators hold (anti-windup with every channel limited), as the position loop's do.
    hold = not position_hold or (z_m < land_h and (landing or pz < land_h))
    if hold:
        px, pvx, pax = x_m, vx_m, 0.0
        py, pvy, pay = y_m, vy_m, 0.0
        tx, ty = x_m, y_m
    x_r, vx_r, ax_r, jx_r = prefilter_step(px, pvx, pax, tx, w, dt_s, vxy, amax)
    y_r, vy_r, ay_r, jy_r = prefilter_step(py, pvy, pay, ty, w, dt_s, vxy, amax)
    z_r, vz_r, az_r, jz_r = prefilter_step(pz, pvz, paz, tz, w, dt_s, vz_max, amax)
    psi_r, psi_v, psi_a, psi_j = prefilter_step(yx, yv, ya, psi_target, wy, dt_s, yaw_rate_max, _INF)
    psi_u = psi_r + wrap_pi(psi - psi_r)
    ref = (x_r, vx_r, ax_r, jx_r, y_r, vy_r, ay_r, jy_r, z_r, vz_r, az_r, jz_r, psi_r, psi_v, psi_a, psi_j)
    full = (x_m, y_m, z_m, vx_m, vy_m, vz_m, phi, theta, psi_u, phi_dot, theta_dot, psi_dot)
    meas = (phi, phi_dot, theta, theta_dot, psi_u, psi_dot, z_m, vz_m)
    d_hat, d_law = observer_in(dob, meas, z_m, land_h, ob)
    u, new, diag, att = law.step(full + sensed, ref, law_state, dt_s, k, d_law, ps.u_prev)
    motors, realised, limited, new, dob, u, u_law = actuate(law, law_state, new, u, meas, d_hat, dob, landing, land_h, p, dt_s)
    if hold:
        new = law.anti_windup(law_state, new, u_law, (True, True, True, True), k)
    landed_s, touchdown = touchdown_step(landing, z_m, vz_m, landed_s, land_h, land_s, dt_s)
    state = PipelineState(
        x_r, vx_r, ax_r, y_r, vy_r, ay_r, z_r, vz_r, az_r, att[0], 0.0, 0.0, att[1], 0.0, 0.0,
        psi_r, psi_v, psi_a, int_x, int_y, new, False, landed_s, dob, u_law,
    )  # fmt: skip
    return state, (motors, realised, limited, diag[0], diag[1], diag[2], u, diag[3], (att[0], att[1], psi_r, z_r), touchdown, d_hat)


#: every function the per-tick pipeline runs (the pure hot path): what ``tests/test_compilable.py``
#: checks against the rules above and compiles with numba's ``njit``, unchanged. The law's own
#: functions arrive as the ``law`` argument (:class:`fc.control.law.LawFunctions`).
PURE_FUNCTIONS = (
    pipeline_step,
    pipeline_step_full,
    pipeline_step_sensed,
    pipeline_step_full_sensed,
    pipeline_reset,
    pipeline_reset_full,
    pipeline_off,
    hover_input,
    observer_in,
    actuate,
    touchdown_step,
    prefilter_step,
    position_step,
    mix,
    wrap_pi,
    observer_reset,
    observer_estimate,
    observer_update,
    observer_update_gz,
    observer_lag,
    *LAW_FUNCTIONS,
    *BUILTIN_FLIGHT_FUNCTIONS,
)
