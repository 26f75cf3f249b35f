"""The realistic plant: a 6-DOF rigid-body quadrotor with motor lag, rotor limits and ground.

Frames (the paper's, see :mod:`smcpilot.frames`): world NWU (x north, y west, z up, z = 0 is
the ground), body FLU (x forward, y left, z up). Attitude is a unit quaternion (w, x, y, z)
mapping body to world, renormalised after every step.

State (17 plain floats, :data:`STATE_NAMES`)::

    x, y, z [m], vx, vy, vz [m/s]        world NWU position and velocity
    qw, qx, qy, qz                       attitude, FLU body -> NWU world
    p, q, r [rad/s]                      body rates about FLU axes
    w1, w2, w3, w4 [rad/s]               rotor speeds (1 right, 2 front, 3 left, 4 rear)

Dynamics
--------
Rotor i gives thrust ``F_i = Kp e_i w_i^2`` along body +z, where e_i in [0, 1] is the rotor's
efficiency (1 unless a motor fault acts, :mod:`sim_bridge.faults`); with arm length d (``plus``
layout of :mod:`smcpilot.model`) and ``S_i = e_i w_i^2``::

    T     = Kp (S1 + S2 + S3 + S4)
    tau_x = d Kp (S3 - S1)          tau_y = d Kp (S4 - S2)
    tau_z = Cd (S1 - S2 + S3 - S4)
    W     = w1 - w2 + w3 - w4       (net rotor speed, gyroscopic term; the efficiency scales
                                     thrust and drag torque, not the rotor speed)

    m dv/dt   = R e_z T - m g e_z - Kfd * v + F_ext              (world NWU; drag per world axis
                                                                 on the ground velocity, as in
                                                                 the paper's eq. 10)
    I dw/dt   = tau - w x (I w) - w x (Jr W e_z) - Kfa * w|w| + tau_ext   (body FLU, I diagonal)
    dq/dt     = 1/2 q * (0, p, q, r)
    dw_i/dt   = (w_cmd_i - w_i) / tau_m

The gyroscopic term ``-w x (Jr W e_z) = (-Jr W q, Jr W p, 0)`` reproduces the paper's
``a3 W theta'`` and ``a6 W phi'`` terms (the project's binding convention). Physically, rotors
whose drag reacts on the body with +z torque (1 and 3) spin about -z, which would give the
opposite sign, ``+w x (Jr W e_z)``; the term is small (W is about 0 in hover) and the paper's sign
is kept so that both plants agree. The reaction torque of accelerating rotors (``Jr dW/dt``) is
left out, as in the paper.

Motors: the command c in [0, 1] maps to a commanded speed by :mod:`smcpilot.actuators`
(``w_cmd^2 = w_idle^2 + c (w_max^2 - w_idle^2)``; NaN -> 0, out of range clamped); disarmed
gives ``w_cmd = 0`` and the rotors spin down with the same lag. The commanded speed is therefore
always within [idle, max] while armed, and the rotor speed follows it with the first-order lag
(time constant :attr:`VehicleParams.motor_time_constant_s`): after arming the rotors spin up from
rest through the lag, and once at idle they stay within [idle, max]. Rotor speeds are always
clamped to [0, max].

Integration: classical RK4 in plain floats with a fixed step (at most ``max_step_s``, 1 ms by
default; :meth:`RigidBodyPlant.step` splits longer steps evenly). The motor commands are held
constant over a step (zero-order hold); the rotor-speed ODE is linear with a constant target, so
it is solved exactly and the RK4 stages use the exact rotor speeds at t, t + h/2 and t + h.

Environment (:mod:`sim_bridge.environment`): its wind/gust force (world NWU) and torque (body FLU)
are held constant over a step. The paper's disturbances are accelerations on the Euler angles
and z: ``z''`` gets d_z, and the Euler-angle accelerations (d_phi, d_theta, d_psi) enter the body
angular acceleration as ``E(phi, theta) (d_phi, d_theta, d_psi)`` (the matrix of
:func:`smcpilot.frames.euler_rates_to_body_rates`), which is what adding them to the Euler-angle
accelerations means. Their psi is the continuous heading (as the paper plant's state has it):
the quaternion's heading in (-pi, pi] plus the whole turns the plant has counted since the start
(:attr:`StepInput.psi_turns`), so the yaw term ``0.1 psi cos 2t`` does not flip sign when the
heading crosses +-180 deg. Whether they act is a per-step input (:class:`StepInput`): the
environment's switch or a fault's.

Ground: z = 0 is flat, rigid ground (when ``ground_contact``). A step that ends below z = 0 puts
the vehicle on the ground: z = 0, velocity and body rates zero, attitude levelled keeping the
yaw; while it rests there, x, y and yaw do not change. So the vehicle rests on the ground while
the upward force is below its weight and lifts off when it is above. The ground has infinite
friction and no bounce; that is all it models.

Pure form: one RK4 step is :func:`rigid_body_step` (state, motor commands, armed, the
environment's force and torque, time, step, :class:`RigidBodyParams`, :class:`StepInput`) ->
(state, acceleration, ok), a function of tuples and floats only; the environment's random draws
and the faults stay outside, in :class:`RigidBodyPlant`, which validates, splits steps, draws the
environment, evaluates the faults, counts heading turns and raises on divergence around it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

from sim_bridge.disturbances import paper_disturbance
from sim_bridge.environment import Environment
from sim_bridge.faults import SimFaults
from sim_bridge.plants.base import PlantBase
from sim_bridge.sensors import VehicleObservation
from smcpilot.actuators import sanitize_command
from smcpilot.errors import ConfigError, DivergenceError
from smcpilot.frames import euler_from_quat, quat_from_euler, wrap_pi
from smcpilot.vehicle import VehicleParams

#: a NamedTuple from its fields in order (what its ``__new__`` does, without the call's argument handling).
_tuple_new = tuple.__new__

__all__ = [
    "RigidBodyPlant", "RigidBodyParams", "StepInput", "NOMINAL_INPUT", "VehicleObservation", "STATE_NAMES",
    "DEFAULT_MAX_STEP_S", "rigid_body_params", "rigid_body_step", "rigid_body_substep", "rigid_body_substep_lag", "rotor_lag",
    "heading", "heading_turns",
    "rigid_body_targets",
]  # fmt: skip

STATE_NAMES: tuple[str, ...] = (
    "x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "p", "q", "r", "w1", "w2", "w3", "w4",
)  # fmt: skip

#: Default (and largest) integration step, s.
DEFAULT_MAX_STEP_S = 0.001

_sqrt = math.sqrt
_exp = math.exp
_sin = math.sin
_cos = math.cos
_atan2 = math.atan2
_asin = math.asin
_isfinite = math.isfinite
_ceil = math.ceil
_ONES4 = (1.0, 1.0, 1.0, 1.0)
_PI = math.pi
_TWO_PI = 2.0 * math.pi


class RigidBodyParams(NamedTuple):
    """The vehicle's constants as the pure step reads them (floats; ``deriv`` a plain tuple)."""

    #: Kp/m, d Kp/Ix, d Kp/Iy, Cd/Iz, 1/m, 1/Ix, 1/Iy, 1/Iz.
    kp_m: float
    dkp_x: float
    dkp_y: float
    cd_z: float
    inv_m: float
    inv_ix: float
    inv_iy: float
    inv_iz: float
    #: idle rotor speed squared and the span to the largest, (rad/s)^2; largest speed, rad/s.
    idle_sq: float
    span_sq: float
    w_max: float
    #: motor time constant, s.
    tau_m: float
    ground_contact: bool
    #: what the derivative reads, in this order (a plain tuple of floats: unpacked four times a
    #: step): g, drag/m (x, y, z), (Iy-Iz)/Ix, (Iz-Ix)/Iy, (Ix-Iy)/Iz, rotational drag/I (x, y, z),
    #: Jr/Ix, Jr/Iy.
    deriv: tuple[float, ...]


class StepInput(NamedTuple):
    """What a step holds besides the motors, force and torque (changes rarely; built outside)."""

    #: thrust (and drag-torque) factor of rotors 1..4, each in [0, 1]; 1.0 = a healthy rotor.
    motor_eff: tuple[float, float, float, float]
    #: whether the paper's disturbances act during the step.
    paper_disturbance: bool
    #: whole turns of the continuous heading at the step's start (a float holding an integer):
    #: continuous psi = the quaternion's heading + 2 pi psi_turns.
    psi_turns: float


#: healthy rotors, no paper disturbance, no turns.
NOMINAL_INPUT = StepInput(_ONES4, False, 0.0)


def rigid_body_params(vehicle: VehicleParams, *, ground_contact: bool = True) -> RigidBodyParams:
    """Flatten a vehicle (once)."""
    v = vehicle
    inv_m = 1.0 / v.mass_kg
    kp = v.thrust_coeff_n_s2
    ix, iy, iz = v.ixx_kg_m2, v.iyy_kg_m2, v.izz_kg_m2
    inv_ix, inv_iy, inv_iz = 1.0 / ix, 1.0 / iy, 1.0 / iz
    idle_sq = v.rotor_speed_idle_radps**2
    deriv = (
        float(v.gravity_mps2),
        v.lin_drag_x_n_s_m * inv_m,
        v.lin_drag_y_n_s_m * inv_m,
        v.lin_drag_z_n_s_m * inv_m,
        (iy - iz) * inv_ix,
        (iz - ix) * inv_iy,
        (ix - iy) * inv_iz,
        v.rot_drag_x_n_m_s2 * inv_ix,
        v.rot_drag_y_n_m_s2 * inv_iy,
        v.rot_drag_z_n_m_s2 * inv_iz,
        v.rotor_inertia_kg_m2 * inv_ix,
        v.rotor_inertia_kg_m2 * inv_iy,
    )
    return RigidBodyParams(
        kp * inv_m,
        v.arm_length_m * kp / v.ixx_kg_m2,
        v.arm_length_m * kp / v.iyy_kg_m2,
        v.drag_coeff_n_m_s2 / v.izz_kg_m2,
        inv_m,
        1.0 / v.ixx_kg_m2,
        1.0 / v.iyy_kg_m2,
        1.0 / v.izz_kg_m2,
        float(idle_sq),
        float(v.rotor_speed_max_radps**2 - idle_sq),
        float(v.rotor_speed_max_radps),
        float(v.motor_time_constant_s),
        bool(ground_contact),
        tuple(float(x) for x in deriv),
    )


def rigid_body_targets(motor_commands: Sequence[float], armed: bool, p: RigidBodyParams) -> tuple[float, float, float, float]:
    """Commanded rotor speeds [rad/s] of the motor commands (clamped, NaN -> 0); 0 when disarmed."""
    if not armed:
        return (0.0, 0.0, 0.0, 0.0)
    idle_sq = p.idle_sq
    span = p.span_sq
    return (
        _sqrt(idle_sq + sanitize_command(motor_commands[0]) * span),
        _sqrt(idle_sq + sanitize_command(motor_commands[1]) * span),
        _sqrt(idle_sq + sanitize_command(motor_commands[2]) * span),
        _sqrt(idle_sq + sanitize_command(motor_commands[3]) * span),
    )


def _deriv(
    k: tuple[float, ...],
    vx: float, vy: float, vz: float, qw: float, qx: float, qy: float, qz: float, p: float, q: float, r: float,
    acc_t: float, ax_e: float, ay_e: float, az_e: float, alx: float, aly: float, alz: float, wbar: float,
) -> tuple[float, ...]:  # fmt: skip
    """d/dt of (vx, vy, vz, qw, qx, qy, qz, p, q, r) without the paper's disturbances
    (:func:`_add_paper` adds them).

    acc_t: thrust / m [m/s^2]; ax_e..az_e: external force / m, world [m/s^2];
    alx..alz: rotor + external torque / I, body [rad/s^2]; wbar: net rotor speed [rad/s].
    Small and without calls, so that compiled it is inlined into the RK4 step.
    """
    g, kdx, kdy, kdz, cx, cy, cz, kax, kay, kaz, jr_x, jr_y = k
    ax = acc_t * 2.0 * (qx * qz + qw * qy) - kdx * vx + ax_e
    ay = acc_t * 2.0 * (qy * qz - qw * qx) - kdy * vy + ay_e
    az = acc_t * (1.0 - 2.0 * (qx * qx + qy * qy)) - kdz * vz + az_e - g
    dp = alx + cx * q * r - jr_x * wbar * q - kax * p * (p if p > 0.0 else -p)
    dq = aly + cy * p * r + jr_y * wbar * p - kay * q * (q if q > 0.0 else -q)
    dr = alz + cz * p * q - kaz * r * (r if r > 0.0 else -r)
    return (
        ax, ay, az,
        -0.5 * (qx * p + qy * q + qz * r),
        0.5 * (qw * p + qy * r - qz * q),
        0.5 * (qw * q + qz * p - qx * r),
        0.5 * (qw * r + qx * q - qy * p),
        dp, dq, dr,
    )  # fmt: skip


def _add_paper(
    d: tuple[float, ...], qw: float, qx: float, qy: float, qz: float, z: float, t: float, psi0: float, turns: float
) -> tuple[float, ...]:
    """:func:`_deriv`'s ``d`` with the paper's disturbances at time ``t``, height ``z`` and this
    attitude added, with the continuous heading: the quaternion's heading unwrapped against psi0
    (the heading in (-pi, pi] at the step's start, whose whole turns are ``turns``)."""
    e_p, e_q, e_r, d_z = _paper_accel(qw, qx, qy, qz, z, t, psi0, turns)
    return (d[0], d[1], d[2] + d_z, d[3], d[4], d[5], d[6], d[7] + e_p, d[8] + e_q, d[9] + e_r)


def _paper_accel(qw: float, qx: float, qy: float, qz: float, z: float, t: float, psi0: float, turns: float) -> tuple[float, float, float, float]:
    """The paper's disturbances as :func:`_add_paper` adds them: (body angular accelerations p',
    q', r' [rad/s^2], z'' [m/s^2]), with the continuous heading (see there)."""
    phi = _atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy))
    st = 2.0 * (qw * qy - qz * qx)
    theta = _asin(1.0 if st > 1.0 else (-1.0 if st < -1.0 else st))
    psi = _atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    n = turns
    if psi - psi0 > _PI:  # crossed -pi -> +pi within the step
        n = turns - 1.0
    elif psi - psi0 < -_PI:
        n = turns + 1.0
    if n != 0.0:
        psi = psi + _TWO_PI * n
    d_phi, d_theta, d_psi, d_z = paper_disturbance(t, phi, theta, psi, z)
    sp, cp = _sin(phi), _cos(phi)
    sth, cth = _sin(theta), _cos(theta)
    return d_phi - sth * d_psi, cp * d_theta + sp * cth * d_psi, -sp * d_theta + cp * cth * d_psi, d_z


def rigid_body_step(
    s: Sequence[float],
    motor_commands: Sequence[float],
    armed: bool,
    force_world_n: Sequence[float],
    torque_body_n_m: Sequence[float],
    t: float,
    h: float,
    p: RigidBodyParams,
    u: StepInput,
) -> tuple[tuple[float, ...], tuple[float, float, float], bool]:
    """One RK4 step of ``h`` seconds from time ``t`` (``h`` at most the plant's largest step).

    ``s``: the 17 states (:data:`STATE_NAMES`); the motor commands are held over the step, and so
    are the environment's force (world NWU, N) and torque (body FLU, N m) and ``u`` (rotor
    efficiencies, paper disturbance, heading turns; :data:`NOMINAL_INPUT` for none). Returns (new
    state, acceleration (world, m/s^2), ok); ok False: the state became non-finite (``s`` is
    returned).
    """
    return rigid_body_substep(s, rigid_body_targets(motor_commands, armed, p), force_world_n, torque_body_n_m, t, h, p, u)


def rigid_body_substep(
    s: Sequence[float],
    targets: tuple[float, float, float, float],
    force_world_n: Sequence[float],
    torque_body_n_m: Sequence[float],
    t: float,
    h: float,
    p: RigidBodyParams,
    u: StepInput,
) -> tuple[tuple[float, ...], tuple[float, float, float], bool]:
    """:func:`rigid_body_step` with the commanded rotor speeds (:func:`rigid_body_targets`) given."""
    return rigid_body_substep_lag(s, targets, force_world_n, torque_body_n_m, t, h, p, u, rotor_lag(h, p), heading(s) if u.paper_disturbance else 0.0)


def heading(s: Sequence[float]) -> float:
    """The heading in (-pi, pi] of the state's attitude quaternion (not normalised)."""
    return _atan2(2.0 * (s[6] * s[9] + s[7] * s[8]), 1.0 - 2.0 * (s[8] * s[8] + s[9] * s[9]))


def heading_turns(s: Sequence[float], psi0: float, turns: float) -> tuple[float, float]:
    """After a step from heading ``psi0`` (in (-pi, pi]) to the state ``s``: the new heading
    (:func:`heading`) and the whole turns counted, ``turns`` one less when it crossed from -pi to
    +pi, one more when from +pi to -pi (the continuous psi of the paper's disturbances)."""
    psi1 = heading(s)
    if psi1 - psi0 > _PI:
        turns = turns - 1.0
    elif psi1 - psi0 < -_PI:
        turns = turns + 1.0
    return psi1, turns


def rotor_lag(h: float, p: RigidBodyParams) -> float:
    """exp(-h / (2 tau_m)): how much of a rotor's distance to its target speed is left after half a
    step of ``h`` seconds (what :func:`rigid_body_substep_lag` takes; the same for every step of ``h``)."""
    return _exp(-0.5 * h / p.tau_m)


def rigid_body_substep_lag(
    s: Sequence[float],
    targets: tuple[float, float, float, float],
    force_world_n: Sequence[float],
    torque_body_n_m: Sequence[float],
    t: float,
    h: float,
    p: RigidBodyParams,
    u: StepInput,
    e_half: float,
    psi0: float,
) -> tuple[tuple[float, ...], tuple[float, float, float], bool]:
    """:func:`rigid_body_substep` with the rotors' lag over half the step, ``rotor_lag(h, p)``,
    given (computed once by a caller that takes many steps of ``h``), and, when the paper's
    disturbances act, the heading of ``s`` (:func:`heading`; a caller that counts the heading's
    turns has it: read only then)."""
    (kp_m, dkp_x, dkp_y, cd_z, inv_m, inv_ix, inv_iy, inv_iz, _idle_sq, _span_sq, w_max, _tau_m,
     ground_contact, k) = p  # fmt: skip
    e_full = e_half * e_half
    fx, fy, fz = force_world_n[0], force_world_n[1], force_world_n[2]
    tqx, tqy, tqz = torque_body_n_m[0], torque_body_n_m[1], torque_body_n_m[2]
    ax_e, ay_e, az_e = fx * inv_m, fy * inv_m, fz * inv_m
    tex, tey, tez = tqx * inv_ix, tqy * inv_iy, tqz * inv_iz

    x, y, z, vx, vy, vz, qw, qx, qy, qz, p_, q, r, w1, w2, w3, w4 = s
    tg1, tg2, tg3, tg4 = targets
    (e1, e2, e3, e4), pd, turns = u
    # exact rotor speeds at t + h/2 (m*) and t + h (n*)
    m1 = tg1 + (w1 - tg1) * e_half
    m2 = tg2 + (w2 - tg2) * e_half
    m3 = tg3 + (w3 - tg3) * e_half
    m4 = tg4 + (w4 - tg4) * e_half
    n1 = tg1 + (w1 - tg1) * e_full
    n2 = tg2 + (w2 - tg2) * e_full
    n3 = tg3 + (w3 - tg3) * e_full
    n4 = tg4 + (w4 - tg4) * e_full
    # thrust/m, torques/I and net rotor speed at t (A), t + h/2 (B), t + h (C)
    s1, s2, s3, s4 = w1 * w1 * e1, w2 * w2 * e2, w3 * w3 * e3, w4 * w4 * e4
    tA = kp_m * (s1 + s2 + s3 + s4)
    xA = dkp_x * (s3 - s1) + tex
    yA = dkp_y * (s4 - s2) + tey
    zA = cd_z * (s1 - s2 + s3 - s4) + tez
    bA = w1 - w2 + w3 - w4
    s1, s2, s3, s4 = m1 * m1 * e1, m2 * m2 * e2, m3 * m3 * e3, m4 * m4 * e4
    tB = kp_m * (s1 + s2 + s3 + s4)
    xB = dkp_x * (s3 - s1) + tex
    yB = dkp_y * (s4 - s2) + tey
    zB = cd_z * (s1 - s2 + s3 - s4) + tez
    bB = m1 - m2 + m3 - m4
    s1, s2, s3, s4 = n1 * n1 * e1, n2 * n2 * e2, n3 * n3 * e3, n4 * n4 * e4
    tC = kp_m * (s1 + s2 + s3 + s4)
    xC = dkp_x * (s3 - s1) + tex
    yC = dkp_y * (s4 - s2) + tey
    zC = cd_z * (s1 - s2 + s3 - s4) + tez
    bC = n1 - n2 + n3 - n4

    hh = 0.5 * h
    dA = _deriv(k, vx, vy, vz, qw, qx, qy, qz, p_, q, r, tA, ax_e, ay_e, az_e, xA, yA, zA, bA)
    if pd:
        dA = _add_paper(dA, qw, qx, qy, qz, z, t, psi0, turns)
    a1, a2, a3, a4, a5, a6, a7, a8, a9, a10 = dA
    b1, b2, b3, b4, b5, b6, b7, b8, b9, b10 = (
        vx + hh * a1, vy + hh * a2, vz + hh * a3, qw + hh * a4, qx + hh * a5,
        qy + hh * a6, qz + hh * a7, p_ + hh * a8, q + hh * a9, r + hh * a10,
    )  # fmt: skip
    dB = _deriv(k, b1, b2, b3, b4, b5, b6, b7, b8, b9, b10, tB, ax_e, ay_e, az_e, xB, yB, zB, bB)
    if pd:
        dB = _add_paper(dB, b4, b5, b6, b7, z + hh * vz, t + hh, psi0, turns)
    c1, c2, c3, c4, c5, c6, c7, c8, c9, c10 = dB
    d1, d2, d3, d4, d5, d6, d7, d8, d9, d10 = (
        vx + hh * c1, vy + hh * c2, vz + hh * c3, qw + hh * c4, qx + hh * c5,
        qy + hh * c6, qz + hh * c7, p_ + hh * c8, q + hh * c9, r + hh * c10,
    )  # fmt: skip
    dC = _deriv(k, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, tB, ax_e, ay_e, az_e, xB, yB, zB, bB)
    if pd:
        dC = _add_paper(dC, d4, d5, d6, d7, z + hh * b3, t + hh, psi0, turns)
    e1, e2, e3, e4, e5, e6, e7, e8, e9, e10 = dC
    f1, f2, f3, f4, f5, f6, f7, f8, f9, f10 = (
        vx + h * e1, vy + h * e2, vz + h * e3, qw + h * e4, qx + h * e5,
        qy + h * e6, qz + h * e7, p_ + h * e8, q + h * e9, r + h * e10,
    )  # fmt: skip
    dD = _deriv(k, f1, f2, f3, f4, f5, f6, f7, f8, f9, f10, tC, ax_e, ay_e, az_e, xC, yC, zC, bC)
    if pd:
        dD = _add_paper(dD, f4, f5, f6, f7, z + h * d3, t + h, psi0, turns)
    g1, g2, g3, g4, g5, g6, g7, g8, g9, g10 = dD
    h6 = h / 6.0
    vx1 = vx + h6 * (a1 + 2.0 * (c1 + e1) + g1)
    vy1 = vy + h6 * (a2 + 2.0 * (c2 + e2) + g2)
    vz1 = vz + h6 * (a3 + 2.0 * (c3 + e3) + g3)
    qw1 = qw + h6 * (a4 + 2.0 * (c4 + e4) + g4)
    qx1 = qx + h6 * (a5 + 2.0 * (c5 + e5) + g5)
    qy1 = qy + h6 * (a6 + 2.0 * (c6 + e6) + g6)
    qz1 = qz + h6 * (a7 + 2.0 * (c7 + e7) + g7)
    p1 = p_ + h6 * (a8 + 2.0 * (c8 + e8) + g8)
    q1 = q + h6 * (a9 + 2.0 * (c9 + e9) + g9)
    r1 = r + h6 * (a10 + 2.0 * (c10 + e10) + g10)
    x1 = x + h6 * (vx + 2.0 * (b1 + d1) + f1)
    y1 = y + h6 * (vy + 2.0 * (b2 + d2) + f2)
    z1 = z + h6 * (vz + 2.0 * (b3 + d3) + f3)

    nq = qw1 * qw1 + qx1 * qx1 + qy1 * qy1 + qz1 * qz1
    if not (_isfinite(nq + x1 + y1 + z1 + vx1 + vy1 + vz1 + p1 + q1 + r1) and nq > 0.0):
        return (x, y, z, vx, vy, vz, qw, qx, qy, qz, p_, q, r, w1, w2, w3, w4), (0.0, 0.0, 0.0), False
    inv = 1.0 / _sqrt(nq)
    qw1 *= inv
    qx1 *= inv
    qy1 *= inv
    qz1 *= inv

    n1 = 0.0 if n1 < 0.0 else (w_max if n1 > w_max else n1)
    n2 = 0.0 if n2 < 0.0 else (w_max if n2 > w_max else n2)
    n3 = 0.0 if n3 < 0.0 else (w_max if n3 > w_max else n3)
    n4 = 0.0 if n4 < 0.0 else (w_max if n4 > w_max else n4)

    if z1 < 0.0 and ground_contact:
        # On the ground: stop, level, keep the yaw (the one before the step if it was
        # already resting: the ground does not let it slide or turn).
        if z <= 0.0:
            x1 = x
            y1 = y
            qw1, qx1, qy1, qz1 = qw, qx, qy, qz
        yaw = _atan2(2.0 * (qw1 * qz1 + qx1 * qy1), 1.0 - 2.0 * (qy1 * qy1 + qz1 * qz1))
        qw1, qx1, qy1, qz1 = _cos(0.5 * yaw), 0.0, 0.0, _sin(0.5 * yaw)
        z1 = vx1 = vy1 = vz1 = p1 = q1 = r1 = 0.0

    inv_h = 1.0 / h
    return (
        (x1, y1, z1, vx1, vy1, vz1, qw1, qx1, qy1, qz1, p1, q1, r1, n1, n2, n3, n4),
        ((vx1 - vx) * inv_h, (vy1 - vy) * inv_h, (vz1 - vz) * inv_h),
        True,
    )


class RigidBodyPlant(PlantBase):
    """Full rigid-body quadrotor plant with the same step/observe API as the paper plant adapter.

    The stateful, validated wrapper of :func:`rigid_body_step` (it draws the environment).

    Args:
        vehicle: physical parameters.
        env: wind, gusts, paper disturbances and sensor noise; None is a clean environment.
        max_step_s: largest RK4 step [s]; :meth:`step` splits longer intervals.
        ground_contact: model the ground at z = 0 (see the module doc).
        faults: timed faults and live SIM_* parameters (:mod:`sim_bridge.faults`); None: none.
    """

    def __init__(
        self,
        vehicle: VehicleParams,
        env: Environment | None = None,
        *,
        max_step_s: float = DEFAULT_MAX_STEP_S,
        ground_contact: bool = True,
        faults: SimFaults | None = None,
    ) -> None:
        super().__init__(vehicle, env, max_step_s=max_step_s, ground_contact=ground_contact, faults=faults)
        #: the vehicle's constants flattened for :func:`rigid_body_step`.
        self.params = rigid_body_params(vehicle, ground_contact=self.ground_contact)
        self._w_max = self.params.w_max
        self._s: tuple[float, ...] = (0.0,) * 17
        self._input = NOMINAL_INPUT._replace(paper_disturbance=self.env.paper_disturbance)
        self.reset()

    # -- state ------------------------------------------------------------------------------------
    def reset(
        self,
        position_m: Sequence[float] = (0.0, 0.0, 0.0),
        yaw_rad: float = 0.0,
        *,
        roll_rad: float = 0.0,
        pitch_rad: float = 0.0,
        velocity_mps: Sequence[float] = (0.0, 0.0, 0.0),
        body_rates_radps: Sequence[float] = (0.0, 0.0, 0.0),
        rotor_speeds_radps: Sequence[float] = (0.0, 0.0, 0.0, 0.0),
        t_s: float = 0.0,
    ) -> None:
        """Put the vehicle at ``position_m`` (world NWU, m) with the given attitude (ZYX, rad).

        By default it is at rest with the rotors stopped. Also restarts the environment's gusts.
        """
        vals = [*position_m, *velocity_mps, roll_rad, pitch_rad, yaw_rad, *body_rates_radps, *rotor_speeds_radps, t_s]
        if len(vals) != 17 or not all(isinstance(a, (int, float)) and _isfinite(a) for a in vals):
            raise ConfigError(
                "reset(): every value must be a finite number (3 position, 3 velocity, 3 rates, 4 rotors)"
            )
        qw, qx, qy, qz = quat_from_euler(roll_rad, pitch_rad, yaw_rad)
        w_max = self._w_max
        rot = [min(max(float(w), 0.0), w_max) for w in rotor_speeds_radps]
        self._s = (
            *(float(a) for a in position_m),
            *(float(a) for a in velocity_mps),
            qw, qx, qy, qz,
            *(float(a) for a in body_rates_radps),
            *rot,
        )  # fmt: skip
        self._t_s = float(t_s)
        self._accel = (0.0, 0.0, 0.0)
        self._obs_cache = None
        #: the last :meth:`truth` and what it was made of (the state tuple, its time, the acceleration)
        self._truth_memo: tuple[tuple[float, ...], float, tuple[float, float, float], VehicleObservation] | None = None
        #: the heading in (-pi, pi] at the end of the last step, and the whole turns it has made.
        self._psi = heading(self._s)
        self._input = self._input._replace(psi_turns=0.0)
        self.env.reset()
        if self.faults is not None:
            self.faults.reset()

    @property
    def heading_turns(self) -> int:
        """Whole turns the heading has made since :meth:`reset` (+1 per crossing of +-180 deg
        turning left, FLU: psi increasing)."""
        return int(self._input.psi_turns)

    @property
    def state(self) -> tuple[float, ...]:
        """The 17 state floats in :data:`STATE_NAMES` order (a copy)."""
        return tuple(self._s)

    @property
    def on_ground(self) -> bool:
        """True when resting on the ground (z = 0 and not moving up)."""
        return self.ground_contact and self._s[2] <= 0.0 and self._s[5] <= 0.0

    # -- dynamics ---------------------------------------------------------------------------------
    def step(self, t_s: float, dt_s: float, motor_commands: Sequence[float], armed: bool) -> None:
        """Advance from time ``t_s`` by ``dt_s`` seconds with the motor commands held constant.

        ``motor_commands`` are 4 floats in [0, 1] (rotors 1..4; NaN -> 0, out of range clamped).
        ``armed`` False commands the rotors to stop. The faults (if any) are evaluated at the
        start of every integration step. Raises :class:`DivergenceError` if the state becomes
        non-finite, :class:`ConfigError` for a non-positive or non-finite ``dt_s``.
        """
        if not (dt_s > 0.0 and _isfinite(dt_s)):
            raise ConfigError(f"step(): dt_s must be a positive finite number of seconds, got {dt_s!r}")
        n = _ceil(dt_s / self.max_step_s - 1e-9)
        if n < 1:
            n = 1
        h = dt_s / n
        p = self.params
        targets = rigid_body_targets(motor_commands, armed, p)
        env = self.env
        faults = self.faults
        s = self._s
        u = self._input
        psi0 = self._psi
        e_half = rotor_lag(h, p)
        for i in range(n):
            t = t_s + i * h
            env.advance(h)
            if faults is not None:
                faults.advance(t, h)
            u, force, torque = self.held_input(u)
            # (psi0 is the heading of s: every writer of the state writes its heading with it)
            s, accel, ok = rigid_body_substep_lag(s, targets, force, torque, t, h, p, u, e_half, psi0 if u.paper_disturbance else 0.0)
            if not ok:
                self._s = s
                self._input = u
                raise DivergenceError("rigid-body plant state became non-finite", t + h)
            psi0, turns = heading_turns(s, psi0, u.psi_turns)
            if turns != u.psi_turns:
                u = u._replace(psi_turns=turns)
            self._s = s
            self._accel = accel
        self._psi = psi0
        self._input = u
        self._t_s = t_s + dt_s
        self._obs_cache = None

    def held_input(self, u: StepInput) -> tuple[StepInput, tuple[float, float, float], tuple[float, float, float]]:
        """What an integration step holds, from the environment and the faults as they stand (both
        advanced to the step): (the step input, ``u`` itself when nothing in it changed; the force,
        world NWU, N; the torque, body FLU, N m)."""
        env = self.env
        faults = self.faults
        force = env.force_world_n
        torque = env.torque_body_n_m
        if faults is not None:
            env_paper = env.paper_disturbance
            if faults.physics_on:
                if faults.forces_on:
                    ff = faults.force_world_n
                    ft = faults.torque_body_n_m
                    force = (force[0] + ff[0], force[1] + ff[1], force[2] + ff[2])
                    torque = (torque[0] + ft[0], torque[1] + ft[1], torque[2] + ft[2])
                paper = env_paper or faults.paper_disturbance
                if faults.motor_eff is not u.motor_eff or paper != u.paper_disturbance:
                    u = StepInput(faults.motor_eff, paper, u.psi_turns)
            elif u.motor_eff is not _ONES4 or u.paper_disturbance != env_paper:
                u = StepInput(_ONES4, env_paper, u.psi_turns)
        return u, force, torque

    # -- observation --------------------------------------------------------------------------------
    def truth(self) -> VehicleObservation:
        """The exact state as a :class:`VehicleObservation` (no sensor noise). Made once per state:
        every change of the state replaces the state tuple (by a step, a compiled span or a reset),
        so the same tuple, time and acceleration give the same (immutable) observation back."""
        s, t_s, accel = self._s, self._t_s, self._accel
        memo = self._truth_memo
        if memo is not None and memo[0] is s and memo[1] == t_s and memo[2] is accel:
            return memo[3]
        phi, theta, psi = euler_from_quat((s[6], s[7], s[8], s[9]))
        return self.remember_truth((wrap_pi(phi), theta, wrap_pi(psi)))

    def remember_truth(self, euler_rad: tuple[float, float, float]) -> VehicleObservation:
        """The truth of the current state given its Euler angles (ZYX of the FLU body in NWU, rad,
        roll and yaw wrapped to [-pi, pi): :meth:`truth`'s, or the compiled span's,
        :mod:`sim_bridge.fused_state`), kept as :meth:`truth`'s memo."""
        s, t_s, accel = self._s, self._t_s, self._accel
        obs: VehicleObservation = _tuple_new(VehicleObservation, (
            t_s, (s[0], s[1], s[2]), (s[3], s[4], s[5]), euler_rad, (s[10], s[11], s[12]), accel, (s[13], s[14], s[15], s[16]),
            (s[6], s[7], s[8], s[9]),
        ))  # fmt: skip
        self._truth_memo = (s, t_s, accel, obs)
        return obs


#: the pure step and everything it calls (checked and compiled by ``tests/test_compilable.py``).
PURE_FUNCTIONS = (
    rigid_body_step, rigid_body_substep, rigid_body_substep_lag, rotor_lag, heading, heading_turns, rigid_body_targets, _deriv,
    _add_paper,
    _paper_accel, sanitize_command, paper_disturbance,
)  # fmt: skip
