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
from fc.control.base import integrators_anti_windup
from fc.control.cascade_pid import (
    CascadePid,
    CascadePidConsts,
    cascade_pid_anti_windup,
    cascade_pid_consts,
    cascade_pid_step,
)
from fc.control.observer import observer_estimate, observer_reset, observer_update
from fc.control.pid_smc import (
    PidSmc,
    PidSmcConsts,
    PidSmcParams,
    pid_smc_anti_windup,
    pid_smc_consts,
    pid_smc_initial_state,
    pid_smc_integrate,
    pid_smc_law,
)
from fc.control.sign_smc import SignSmc, SignSmcConsts, SignSmcParams, sign_smc_consts, sign_smc_output
from fc.mixer import MixerParams, mix, mixer_params
from fc.position import PositionLoopParams, position_step
from fc.prefilter import prefilter_step
from smcpilot.frames import wrap_pi
from smcpilot.model import PaperModel, tilt_cos
from smcpilot.vehicle import VehicleParams

_INF = math.inf
_NAN = math.nan
_ZERO2 = (0.0, 0.0)
_ZERO4 = (0.0, 0.0, 0.0, 0.0)
_ZERO8 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

#: :attr:`PipelineParams.law_kind` values.
LAW_PID_SMC = 0
LAW_CASCADE_PID = 1
LAW_SIGN_SMC = 2


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
    #: which law runs: :data:`LAW_PID_SMC`, :data:`LAW_CASCADE_PID` or :data:`LAW_SIGN_SMC`.
    law_kind: int
    #: length of that law's state (12, 10 or 4).
    law_n: int
    #: the constants of each law (only ``law_kind``'s are used; the others are defaults).
    smc: PidSmcConsts
    cpid: CascadePidConsts
    ssmc: SignSmcConsts


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
    #: the law's state, padded with zeros to 12 floats.
    law: tuple[float, ...]
    #: how many entries of ``law`` are the law's (12, 10 or 4); 0: none yet (initialised on the next step).
    law_n: int
    #: time spent settled on the ground while landing, s.
    landed_s: float
    #: the disturbance observer's state (:mod:`fc.control.observer`; 8 floats, zeros when unused).
    dob: tuple[float, ...] = _ZERO8


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
def law_kind_of(law: object) -> int:
    """The :data:`LAW_PID_SMC` / :data:`LAW_CASCADE_PID` / :data:`LAW_SIGN_SMC` of a law object."""
    if isinstance(law, PidSmc):
        return LAW_PID_SMC
    if isinstance(law, CascadePid):
        return LAW_CASCADE_PID
    if isinstance(law, SignSmc):
        return LAW_SIGN_SMC
    raise TypeError(f"the flight pipeline has no pure form of {type(law).__name__}")


def pipeline_params(config: FcConfig, vehicle: VehicleParams, law: PidSmc | CascadePid | SignSmc) -> PipelineParams:
    """Flatten a validated configuration, a vehicle and the law built for them (once, not per tick)."""
    kind = law_kind_of(law)
    model: PaperModel = law.model
    smc = law.consts if isinstance(law, PidSmc) else pid_smc_consts(model, PidSmcParams())
    cpid = law.consts if isinstance(law, CascadePid) else cascade_pid_consts(model, config.cascade)
    ssmc = law.consts if isinstance(law, SignSmc) else sign_smc_consts(model, SignSmcParams())
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
        law_kind=kind,
        law_n=len(law.state_names),
        smc=smc,
        cpid=cpid,
        ssmc=ssmc,
    )


# -- the pure functions -------------------------------------------------------------------------------
def law_initial_state(meas: tuple[float, ...], p: PipelineParams) -> tuple[float, ...]:
    """The law's initial state for ``meas``, padded to 12 floats."""
    if p.law_kind == LAW_PID_SMC:
        return pid_smc_initial_state(meas, p.smc)
    return (0.0, 0.0, 0.0, 0.0) + _ZERO8


def pipeline_reset(st: VehicleState, p: PipelineParams) -> PipelineState:
    """The state on arming at ``st``: references start where the vehicle is, the law at hover trim."""
    law = law_initial_state((0.0, 0.0, 0.0, 0.0, st.psi_rad, 0.0, st.z_m, 0.0), p)
    meas = (st.phi_rad, st.phi_dot_radps, st.theta_rad, st.theta_dot_radps, st.psi_rad, st.psi_dot_radps, st.z_m, st.vz_mps)
    dob = observer_reset(meas, (law[4], law[5], law[6], law[7]), p.smc.dob_w) if p.law_kind == LAW_PID_SMC else _ZERO8
    return PipelineState(
        st.x_m, st.vx_mps, 0.0, st.y_m, st.vy_mps, 0.0, st.z_m, st.vz_mps, 0.0,
        st.phi_rad, 0.0, 0.0, st.theta_rad, 0.0, 0.0, st.psi_rad, 0.0, 0.0,
        0.0, 0.0, law, p.law_n, 0.0, dob,
    )  # fmt: skip


Vec4 = tuple[float, float, float, float]
#: the outputs of :func:`pipeline_step`, in order (see there).
PipelineOutputs = tuple[Vec4, Vec4, tuple[bool, bool, bool, bool], Vec4, Vec4, Vec4, Vec4, Vec4, Vec4, bool, Vec4]


def pipeline_off() -> PipelineOutputs:
    """The outputs when disarmed: motors stopped, nothing limited, references unknown."""
    return (_ZERO4, _ZERO4, (False, False, False, False), _ZERO4, _ZERO4, _ZERO4, _ZERO4, _ZERO4,
            (_NAN, _NAN, _NAN, _NAN), False, _ZERO4)  # fmt: skip


def pipeline_step(
    ps: PipelineState, st: VehicleState, cmd: PipelineInputs, p: PipelineParams, dt_s: float
) -> tuple[PipelineState, PipelineOutputs]:
    """One control tick of ``dt_s`` seconds: (new state, outputs). Disarmed: motors stopped, state unchanged.

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
     int_x, int_y, law, law_n, landed_s, dob) = ps  # fmt: skip
    (w, amax, _vxy_max, vz_max, land_speed, wa, wy, yaw_rate_max, land_h, land_s, g,
     pos, mixp, kind, n, smc, cpid, ssmc) = p  # fmt: skip
    if law_n == 0:
        law = law_initial_state((phi, 0.0, theta, 0.0, psi, 0.0, z_m, 0.0), p)
        law_n = n
        if kind == LAW_PID_SMC:
            dob = observer_reset((phi, phi_dot, theta, theta_dot, psi, psi_dot, z_m, vz_m), (law[4], law[5], law[6], law[7]), smc.dob_w)
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
    # 3. The law, on the wrapped yaw error.
    ref = (phi_r, phi_v, phi_a, phi_j, th_r, th_v, th_a, th_j, psi_r, psi_v, psi_a, psi_j, z_r, vz_r, az_r, jz_r)
    meas = (phi, phi_dot, theta, theta_dot, psi_r + wrap_pi(psi - psi_r), psi_dot, z_m, vz_m)
    dob_on = kind == LAW_PID_SMC and smc.dob_mode != 0
    d_hat = _ZERO4
    if dob_on and z_m >= land_h:  # on the ground the ground's reaction is no disturbance to cancel
        d_hat = observer_estimate(dob, meas, smc.dob_w, smc.dob_max)
    if kind == LAW_PID_SMC:
        s, sg, chi, ud, rate = pid_smc_law(meas, ref, law, smc, _ZERO4, False, d_hat)
        new = pid_smc_integrate(law, s, ud, rate, dt_s, smc)
        u = (new[4], new[5], new[6], new[7])
    elif kind == LAW_CASCADE_PID:
        u, cnew = cascade_pid_step(meas, ref, law, dt_s, cpid)
        new = cnew + _ZERO2
        s = sg = chi = ud = _ZERO4
    else:
        u, e, sg = sign_smc_output(meas, ref, law, ssmc)
        new = (law[0] + dt_s * e[0], law[1] + dt_s * e[1], law[2] + dt_s * e[2], law[3] + dt_s * e[3]) + _ZERO8
        s = chi = ud = _ZERO4
    # 4. Disturbance compensation at the input ("input" estimate: u_cmd = u - d_hat/g), then the
    #    mixer with priorities, and the realised inputs fed back (anti-windup).
    c0 = c1 = c2 = c3 = 0.0
    if dob_on and smc.dob_mode == 3:
        mm = smc.model
        c0 = d_hat[0] / mm[13]
        c1 = d_hat[1] / mm[14]
        c2 = d_hat[2] / mm[15]
        c3 = d_hat[3] / (tilt_cos(phi, theta, smc.tilt_min) * smc.inv_mass)
        u = (u[0] - c0, u[1] - c1, u[2] - c2, u[3] - c3)
    motors, realised, limited = mix(mixp, u[0], u[1], u[2], u[3])
    if landing and z_m < 3.0 * land_h:
        # Ground contact is not a disturbance to learn: freeze the z channel's integrators.
        limited = (limited[0], limited[1], limited[2], True)
    if limited[0] or limited[1] or limited[2] or limited[3]:
        if kind == LAW_PID_SMC:
            # the law's own share of what was realised (the compensation is not the law's state)
            law_realised = (realised[0] + c0, realised[1] + c1, realised[2] + c2, realised[3] + c3) if c0 or c1 or c2 or c3 else realised
            new = pid_smc_anti_windup(law, new, law_realised, limited)
        elif kind == LAW_CASCADE_PID:
            new = cascade_pid_anti_windup(law, new, limited) + _ZERO2
        else:
            new = integrators_anti_windup(law, new, limited) + _ZERO8
    if dob_on:
        tau = smc.dob_tau
        lag_a = lag_b = 0.0
        if tau > 0.0:
            lag_a = math.exp(-dt_s / tau)
            lag_b = tau * (1.0 - lag_a) / dt_s
        dob = observer_update(dob, meas, d_hat, realised, smc.model, smc.dob_w, smc.tilt_min, smc.inv_mass, lag_a, lag_b, dt_s)
    # 5. Touchdown while landing -> the caller disarms.
    touchdown = False
    if landing:
        if z_m < land_h and abs(vz_m) < 0.2:
            landed_s += dt_s
            if landed_s >= land_s:
                touchdown = True
        else:
            landed_s = 0.0
    state = PipelineState(
        x_r, vx_r, ax_r, y_r, vy_r, ay_r, z_r, vz_r, az_r, phi_r, phi_v, phi_a, th_r, th_v, th_a,
        psi_r, psi_v, psi_a, int_x, int_y, new, law_n, landed_s, dob,
    )  # fmt: skip
    return state, (motors, realised, limited, s, sg, chi, u, ud, (phi_r, th_r, psi_r, z_r), touchdown, d_hat)


#: every function the per-tick pipeline runs (the pure hot path): what ``tests/test_compilable.py``
#: checks against the rules above and compiles with numba's ``njit``, unchanged.
PURE_FUNCTIONS = (
    pipeline_step,
    pipeline_reset,
    pipeline_off,
    law_initial_state,
    prefilter_step,
    position_step,
    mix,
    wrap_pi,
    observer_reset,
    observer_estimate,
    observer_update,
    *LAW_FUNCTIONS,
)
