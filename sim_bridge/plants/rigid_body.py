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
Rotor i gives thrust ``F_i = Kp w_i^2`` along body +z; with arm length d (``plus`` layout of
:mod:`smcpilot.model`)::

    T     = Kp (w1^2 + w2^2 + w3^2 + w4^2)
    tau_x = d Kp (w3^2 - w1^2)      tau_y = d Kp (w4^2 - w2^2)
    tau_z = Cd (w1^2 - w2^2 + w3^2 - w4^2)
    W     = w1 - w2 + w3 - w4       (net rotor speed, gyroscopic term)

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
accelerations means. psi is taken in [-pi, pi] there (from the quaternion).

Ground: z = 0 is flat, rigid ground (when ``ground_contact``). A step that ends below z = 0 puts
the vehicle on the ground: z = 0, velocity and body rates zero, attitude levelled keeping the
yaw; while it rests there, x, y and yaw do not change. So the vehicle rests on the ground while
the upward force is below its weight and lifts off when it is above. The ground has infinite
friction and no bounce; that is all it models.
"""

from __future__ import annotations

import math
from typing import Sequence

from sim_bridge.environment import Environment
from sim_bridge.disturbances import paper_disturbance
from sim_bridge.plants.base import PlantBase
from sim_bridge.sensors import VehicleObservation
from smcpilot.actuators import sanitize_command
from smcpilot.errors import ConfigError, DivergenceError
from smcpilot.frames import euler_from_quat, quat_from_euler, wrap_pi
from smcpilot.vehicle import VehicleParams

__all__ = ["RigidBodyPlant", "VehicleObservation", "STATE_NAMES", "DEFAULT_MAX_STEP_S"]

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


class RigidBodyPlant(PlantBase):
    """Full rigid-body quadrotor plant with the same step/observe API as the paper plant adapter.

    Args:
        vehicle: physical parameters.
        env: wind, gusts, paper disturbances and sensor noise; None is a clean environment.
        max_step_s: largest RK4 step [s]; :meth:`step` splits longer intervals.
        ground_contact: model the ground at z = 0 (see the module doc).
    """

    def __init__(
        self,
        vehicle: VehicleParams,
        env: Environment | None = None,
        *,
        max_step_s: float = DEFAULT_MAX_STEP_S,
        ground_contact: bool = True,
    ) -> None:
        super().__init__(vehicle, env, max_step_s=max_step_s, ground_contact=ground_contact)
        v = vehicle
        self._idle_sq = v.rotor_speed_idle_radps**2
        self._span_sq = v.rotor_speed_max_radps**2 - self._idle_sq
        self._w_max = v.rotor_speed_max_radps
        self._tau_m = v.motor_time_constant_s
        self._decay_h = -1.0
        self._e_half = 0.0
        self._e_full = 0.0
        self._s: list[float] = [0.0] * 17
        inv_m = 1.0 / v.mass_kg
        kp = v.thrust_coeff_n_s2
        #: per-step constants: Kp/m, d Kp/Ix, d Kp/Iy, Cd/Iz, 1/m, 1/Ix, 1/Iy, 1/Iz
        self._k = (
            kp * inv_m,
            v.arm_length_m * kp / v.ixx_kg_m2,
            v.arm_length_m * kp / v.iyy_kg_m2,
            v.drag_coeff_n_m_s2 / v.izz_kg_m2,
            inv_m,
            1.0 / v.ixx_kg_m2,
            1.0 / v.iyy_kg_m2,
            1.0 / v.izz_kg_m2,
        )
        self._deriv = self._make_deriv()
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
        self._s = [
            *(float(a) for a in position_m),
            *(float(a) for a in velocity_mps),
            qw, qx, qy, qz,
            *(float(a) for a in body_rates_radps),
            *rot,
        ]  # fmt: skip
        self._t_s = float(t_s)
        self._accel = (0.0, 0.0, 0.0)
        self._obs_cache = None
        self.env.reset()

    @property
    def state(self) -> tuple[float, ...]:
        """The 17 state floats in :data:`STATE_NAMES` order (a copy)."""
        return tuple(self._s)

    @property
    def on_ground(self) -> bool:
        """True when resting on the ground (z = 0 and not moving up)."""
        return self.ground_contact and self._s[2] <= 0.0 and self._s[5] <= 0.0

    # -- dynamics ---------------------------------------------------------------------------------
    def _make_deriv(self):  # noqa: ANN202 - returns the hot-path closure
        """Build the derivative function of the 10 dynamic states (v, q, body rates)."""
        v = self.vehicle
        env = self.env
        inv_m = 1.0 / v.mass_kg
        g = v.gravity_mps2
        kdx = v.lin_drag_x_n_s_m * inv_m
        kdy = v.lin_drag_y_n_s_m * inv_m
        kdz = v.lin_drag_z_n_s_m * inv_m
        ix, iy, iz = v.ixx_kg_m2, v.iyy_kg_m2, v.izz_kg_m2
        inv_ix, inv_iy, inv_iz = 1.0 / ix, 1.0 / iy, 1.0 / iz
        cx, cy, cz = (iy - iz) * inv_ix, (iz - ix) * inv_iy, (ix - iy) * inv_iz
        kax = v.rot_drag_x_n_m_s2 * inv_ix
        kay = v.rot_drag_y_n_m_s2 * inv_iy
        kaz = v.rot_drag_z_n_m_s2 * inv_iz
        jr_x = v.rotor_inertia_kg_m2 * inv_ix
        jr_y = v.rotor_inertia_kg_m2 * inv_iy
        paper_dist = env.paper_disturbance

        def deriv(
            s: Sequence[float], z: float, t: float, acc_t: float, ax_e: float, ay_e: float, az_e: float,
            alx: float, aly: float, alz: float, wbar: float,
        ) -> tuple[float, ...]:
            """d/dt of (vx, vy, vz, qw, qx, qy, qz, p, q, r).

            acc_t: thrust / m [m/s^2]; ax_e..az_e: external force / m, world [m/s^2];
            alx..alz: rotor + external torque / I, body [rad/s^2]; wbar: net rotor speed [rad/s].
            """
            vx, vy, vz, qw, qx, qy, qz, p, q, r = s
            ax = acc_t * 2.0 * (qx * qz + qw * qy) - kdx * vx + ax_e
            ay = acc_t * 2.0 * (qy * qz - qw * qx) - kdy * vy + ay_e
            az = acc_t * (1.0 - 2.0 * (qx * qx + qy * qy)) - kdz * vz + az_e - g
            dp = alx + cx * q * r - jr_x * wbar * q - kax * p * (p if p > 0.0 else -p)
            dq = aly + cy * p * r + jr_y * wbar * p - kay * q * (q if q > 0.0 else -q)
            dr = alz + cz * p * q - kaz * r * (r if r > 0.0 else -r)
            if paper_dist:
                phi = _atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy))
                st = 2.0 * (qw * qy - qz * qx)
                theta = _asin(1.0 if st > 1.0 else (-1.0 if st < -1.0 else st))
                psi = _atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
                d_phi, d_theta, d_psi, d_z = paper_disturbance(t, phi, theta, psi, z)
                sp, cp = _sin(phi), _cos(phi)
                sth, cth = _sin(theta), _cos(theta)
                dp += d_phi - sth * d_psi
                dq += cp * d_theta + sp * cth * d_psi
                dr += -sp * d_theta + cp * cth * d_psi
                az += d_z
            return (
                ax, ay, az,
                -0.5 * (qx * p + qy * q + qz * r),
                0.5 * (qw * p + qy * r - qz * q),
                0.5 * (qw * q + qz * p - qx * r),
                0.5 * (qw * r + qx * q - qy * p),
                dp, dq, dr,
            )  # fmt: skip

        return deriv

    def step(self, t_s: float, dt_s: float, motor_commands: Sequence[float], armed: bool) -> None:
        """Advance from time ``t_s`` by ``dt_s`` seconds with the motor commands held constant.

        ``motor_commands`` are 4 floats in [0, 1] (rotors 1..4; NaN -> 0, out of range clamped).
        ``armed`` False commands the rotors to stop. Raises :class:`DivergenceError` if the state
        becomes non-finite, :class:`ConfigError` for a non-positive or non-finite ``dt_s``.
        """
        if not (dt_s > 0.0 and _isfinite(dt_s)):
            raise ConfigError(f"step(): dt_s must be a positive finite number of seconds, got {dt_s!r}")
        n = _ceil(dt_s / self.max_step_s - 1e-9)
        if n < 1:
            n = 1
        h = dt_s / n
        c1, c2, c3, c4 = motor_commands
        if armed:
            idle_sq = self._idle_sq
            span = self._span_sq
            tg1 = _sqrt(idle_sq + sanitize_command(c1) * span)
            tg2 = _sqrt(idle_sq + sanitize_command(c2) * span)
            tg3 = _sqrt(idle_sq + sanitize_command(c3) * span)
            tg4 = _sqrt(idle_sq + sanitize_command(c4) * span)
        else:
            tg1 = tg2 = tg3 = tg4 = 0.0
        targets = (tg1, tg2, tg3, tg4)
        for i in range(n):
            self._substep(t_s + i * h, h, targets)
        self._t_s = t_s + dt_s
        self._obs_cache = None

    def _substep(self, t: float, h: float, targets: tuple[float, float, float, float]) -> None:
        """One RK4 step of size h from time t (hot path: plain floats, locals only)."""
        if h != self._decay_h:
            self._e_half = _exp(-0.5 * h / self._tau_m)
            self._e_full = self._e_half * self._e_half
            self._decay_h = h
        e_half = self._e_half
        e_full = self._e_full
        kp_m, dkp_x, dkp_y, cd_z, inv_m, inv_ix, inv_iy, inv_iz = self._k
        env = self.env
        env.advance(h)
        fx, fy, fz = env.force_world_n
        tqx, tqy, tqz = env.torque_body_n_m
        ax_e, ay_e, az_e = fx * inv_m, fy * inv_m, fz * inv_m
        tex, tey, tez = tqx * inv_ix, tqy * inv_iy, tqz * inv_iz

        s = self._s
        x, y, z, vx, vy, vz, qw, qx, qy, qz, p, q, r, w1, w2, w3, w4 = s
        tg1, tg2, tg3, tg4 = targets
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
        s1, s2, s3, s4 = w1 * w1, w2 * w2, w3 * w3, w4 * w4
        tA = kp_m * (s1 + s2 + s3 + s4)
        xA = dkp_x * (s3 - s1) + tex
        yA = dkp_y * (s4 - s2) + tey
        zA = cd_z * (s1 - s2 + s3 - s4) + tez
        bA = w1 - w2 + w3 - w4
        s1, s2, s3, s4 = m1 * m1, m2 * m2, m3 * m3, m4 * m4
        tB = kp_m * (s1 + s2 + s3 + s4)
        xB = dkp_x * (s3 - s1) + tex
        yB = dkp_y * (s4 - s2) + tey
        zB = cd_z * (s1 - s2 + s3 - s4) + tez
        bB = m1 - m2 + m3 - m4
        s1, s2, s3, s4 = n1 * n1, n2 * n2, n3 * n3, n4 * n4
        tC = kp_m * (s1 + s2 + s3 + s4)
        xC = dkp_x * (s3 - s1) + tex
        yC = dkp_y * (s4 - s2) + tey
        zC = cd_z * (s1 - s2 + s3 - s4) + tez
        bC = n1 - n2 + n3 - n4

        deriv = self._deriv
        hh = 0.5 * h
        y0 = (vx, vy, vz, qw, qx, qy, qz, p, q, r)
        k1 = deriv(y0, z, t, tA, ax_e, ay_e, az_e, xA, yA, zA, bA)
        y2 = [a + hh * b for a, b in zip(y0, k1)]
        k2 = deriv(y2, z + hh * vz, t + hh, tB, ax_e, ay_e, az_e, xB, yB, zB, bB)
        y3 = [a + hh * b for a, b in zip(y0, k2)]
        k3 = deriv(y3, z + hh * y2[2], t + hh, tB, ax_e, ay_e, az_e, xB, yB, zB, bB)
        y4 = [a + h * b for a, b in zip(y0, k3)]
        k4 = deriv(y4, z + h * y3[2], t + h, tC, ax_e, ay_e, az_e, xC, yC, zC, bC)
        h6 = h / 6.0
        vx1, vy1, vz1, qw1, qx1, qy1, qz1, p1, q1, r1 = [
            a + h6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(y0, k1, k2, k3, k4)
        ]
        x1 = x + h6 * (vx + 2.0 * (y2[0] + y3[0]) + y4[0])
        y1 = y + h6 * (vy + 2.0 * (y2[1] + y3[1]) + y4[1])
        z1 = z + h6 * (vz + 2.0 * (y2[2] + y3[2]) + y4[2])

        nq = qw1 * qw1 + qx1 * qx1 + qy1 * qy1 + qz1 * qz1
        if not (_isfinite(nq + x1 + y1 + z1 + vx1 + vy1 + vz1 + p1 + q1 + r1) and nq > 0.0):
            raise DivergenceError("rigid-body plant state became non-finite", t + h)
        inv = 1.0 / _sqrt(nq)
        qw1 *= inv
        qx1 *= inv
        qy1 *= inv
        qz1 *= inv

        w_max = self._w_max
        n1 = 0.0 if n1 < 0.0 else (w_max if n1 > w_max else n1)
        n2 = 0.0 if n2 < 0.0 else (w_max if n2 > w_max else n2)
        n3 = 0.0 if n3 < 0.0 else (w_max if n3 > w_max else n3)
        n4 = 0.0 if n4 < 0.0 else (w_max if n4 > w_max else n4)

        if z1 < 0.0 and self.ground_contact:
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
        self._accel = ((vx1 - vx) * inv_h, (vy1 - vy) * inv_h, (vz1 - vz) * inv_h)
        self._s = [x1, y1, z1, vx1, vy1, vz1, qw1, qx1, qy1, qz1, p1, q1, r1, n1, n2, n3, n4]

    # -- observation --------------------------------------------------------------------------------
    def truth(self) -> VehicleObservation:
        """The exact state as a :class:`VehicleObservation` (no sensor noise)."""
        x, y, z, vx, vy, vz, qw, qx, qy, qz, p, q, r, w1, w2, w3, w4 = self._s
        phi, theta, psi = euler_from_quat((qw, qx, qy, qz))
        return VehicleObservation(
            t_s=self._t_s,
            position_m=(x, y, z),
            velocity_mps=(vx, vy, vz),
            euler_rad=(wrap_pi(phi), theta, wrap_pi(psi)),
            body_rates_radps=(p, q, r),
            accel_mps2=self._accel,
            rotor_speed_radps=(w1, w2, w3, w4),
            quaternion=(qw, qx, qy, qz),
        )
