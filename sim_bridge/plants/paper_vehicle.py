"""The paper's plant behind the rigid-body plant's step/observe API.

:class:`PaperVehiclePlant` wraps :class:`sim_bridge.plants.paper.PaperPlant` (the corrected
eq. (10) model: Euler-angle rates stand in for body rates, ideal actuators) so the simulator can
swap plants without changing anything else:

1. motor commands c in [0, 1] -> rotor speeds squared by the shared mapping of
   :mod:`smcpilot.actuators` (NaN -> 0, clamped to [0, 1]; disarmed -> 0). Ideal actuators: no
   lag, no limit beyond the command range;
2. rotor speeds squared -> paper inputs u = (u_phi, u_theta, u_psi, u_z) by
   :meth:`smcpilot.model.PaperModel.mix` (eq. 11);
3. classical RK4 of :meth:`PaperPlant.derivatives` with u held over the step.

Frames as everywhere in the project: world NWU (z up), body FLU, ZYX Euler angles. The
environment's force (world NWU, N) adds ``F/m`` to (x'', y'', z''); its torque (body FLU, N m)
adds ``tau/I`` to (phi'', theta'', psi'') (the paper model's small-angle identification of body
and Euler rates). The paper's disturbances are switched by the environment
(:attr:`EnvironmentParams.paper_disturbance`) or by a fault, not by this class.

Faults (:mod:`sim_bridge.faults`, evaluated at the start of every integration step): their force
and torque add to the environment's; they can switch the paper's disturbances on; a motor's
efficiency e_i scales its w_i^2 before the mixer (thrust and drag torque are both proportional to
w_i^2, so that is the same fault as on the rigid body; the reported rotor speed is unchanged).
Sensor faults act on the observation (:class:`sim_bridge.plants.base.PlantBase`).

Ground (``ground_contact``, default on): a step ending below z = 0 puts the vehicle on the
ground: z = 0, all velocities and angular rates zero, phi = theta = 0, psi kept; while it rests
there, x, y and psi do not change.

Observation: body rates are computed from the Euler rates with
:func:`smcpilot.frames.euler_rates_to_body_rates`; phi and psi are wrapped to [-pi, pi) (the state
keeps psi unwrapped); the acceleration is dv/dt averaged over the last integration step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from sim_bridge.environment import Environment
from sim_bridge.faults import SimFaults
from sim_bridge.plants.base import PlantBase
from sim_bridge.plants.paper import STATE_NAMES, PaperPlant
from sim_bridge.sensors import VehicleObservation
from smcpilot.actuators import commands_to_omega_sq
from smcpilot.errors import ConfigError, DivergenceError
from smcpilot.frames import body_rates_to_euler_rates, euler_rates_to_body_rates, quat_from_euler, wrap_pi
from smcpilot.integrate import rk4_step
from smcpilot.model import PaperModel
from smcpilot.vehicle import VehicleParams

__all__ = ["PaperVehiclePlant", "STATE_NAMES"]

_isfinite = math.isfinite
_sqrt = math.sqrt
_ceil = math.ceil
_ONES4 = (1.0, 1.0, 1.0, 1.0)


class PaperVehiclePlant(PlantBase):
    """The paper plant (ideal actuators, Euler-rate dynamics) with the rigid-body plant's API.

    Args:
        vehicle: physical parameters (motor lag and rotor limits are ignored: ideal actuators).
        env: forces, torques, paper disturbances and sensor noise; None is a clean environment.
        max_step_s: largest RK4 step [s]; :meth:`step` splits longer intervals.
        ground_contact: model the ground at z = 0.
        typos: model typos to reproduce (:mod:`smcpilot.typos`); default the corrected model.
        faults: timed faults and live SIM_* parameters (:mod:`sim_bridge.faults`); None: none.
    """

    def __init__(
        self,
        vehicle: VehicleParams,
        env: Environment | None = None,
        *,
        max_step_s: float = 0.001,
        ground_contact: bool = True,
        typos: frozenset[str] | str | None = None,
        faults: SimFaults | None = None,
    ) -> None:
        super().__init__(vehicle, env, max_step_s=max_step_s, ground_contact=ground_contact, faults=faults)
        self.model = PaperModel.from_vehicle(vehicle, typos)
        self.plant = PaperPlant(self.model, disturbance=self.env.paper_disturbance)
        self._y: list[float] = [0.0] * 12
        self._w_sq: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
        #: inputs (u_phi, u_theta, u_psi, u_z) held over the current step
        self._u: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
        #: environment accelerations (phi'', theta'', psi'', z'', x'', y'') held over the substep
        self._ext: tuple[float, ...] = (0.0,) * 6
        self.reset()

    def _f(self, t_s: float, y: Sequence[float]) -> tuple[float, ...]:
        """dy/dt of the 12 paper states with the held inputs and environment accelerations."""
        d = self.plant.derivatives(t_s, y, self._u)[0]
        ep, et, es, ez, ex, ey = self._ext
        return (
            d[0], d[1] + ep, d[2], d[3] + et, d[4], d[5] + es,
            d[6], d[7] + ez, d[8], d[9] + ex, d[10], d[11] + ey,
        )  # fmt: skip

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
        """Same arguments as :meth:`RigidBodyPlant.reset`.

        Body rates [rad/s, FLU] are converted to Euler-angle rates. ``rotor_speeds_radps`` only
        sets what :meth:`observe` reports before the first step (ideal actuators have no state).
        """
        vals = [*position_m, *velocity_mps, roll_rad, pitch_rad, yaw_rad, *body_rates_radps, *rotor_speeds_radps, t_s]
        if len(vals) != 17 or not all(isinstance(a, (int, float)) and _isfinite(a) for a in vals):
            raise ConfigError(
                "reset(): every value must be a finite number (3 position, 3 velocity, 3 rates, 4 rotors)"
            )
        p, q, r = (float(a) for a in body_rates_radps)
        phi_d, th_d, psi_d = body_rates_to_euler_rates(roll_rad, pitch_rad, p, q, r)
        x, y, z = (float(a) for a in position_m)
        vx, vy, vz = (float(a) for a in velocity_mps)
        self._y = [float(roll_rad), phi_d, float(pitch_rad), th_d, float(yaw_rad), psi_d, z, vz, x, vx, y, vy]
        w = [float(a) for a in rotor_speeds_radps]
        self._w_sq = (w[0] * w[0], w[1] * w[1], w[2] * w[2], w[3] * w[3])
        self._t_s = float(t_s)
        self._accel = (0.0, 0.0, 0.0)
        self._obs_cache = None
        self.env.reset()
        if self.faults is not None:
            self.faults.reset()

    @property
    def state(self) -> tuple[float, ...]:
        """The paper plant's 12 states in :data:`STATE_NAMES` order (a copy)."""
        return tuple(self._y)

    def step(self, t_s: float, dt_s: float, motor_commands: Sequence[float], armed: bool) -> None:
        """Advance from ``t_s`` by ``dt_s`` seconds with the motor commands held constant.

        Same contract as :meth:`RigidBodyPlant.step`.
        """
        if not (dt_s > 0.0 and _isfinite(dt_s)):
            raise ConfigError(f"step(): dt_s must be a positive finite number of seconds, got {dt_s!r}")
        n = max(1, _ceil(dt_s / self.max_step_s - 1e-9))
        h = dt_s / n
        w_sq = commands_to_omega_sq(motor_commands, self.vehicle, armed)
        mix = self.model.mix
        self._u = mix(*w_sq)
        self._w_sq = w_sq
        v = self.vehicle
        env = self.env
        faults = self.faults
        plant = self.plant
        eff = _ONES4
        f = self._f
        inv_m = 1.0 / v.mass_kg
        for i in range(n):
            env.advance(h)
            fx, fy, fz = env.force_world_n
            tx, ty, tz = env.torque_body_n_m
            if faults is not None:
                faults.advance(t_s + i * h, h)
                if faults.forces_on:
                    ff = faults.force_world_n
                    ft = faults.torque_body_n_m
                    fx, fy, fz = fx + ff[0], fy + ff[1], fz + ff[2]
                    tx, ty, tz = tx + ft[0], ty + ft[1], tz + ft[2]
                plant.disturbance = env.paper_disturbance or faults.paper_disturbance
                if faults.motor_eff != eff:
                    eff = faults.motor_eff
                    if eff == _ONES4:
                        self._u = mix(*w_sq)
                    else:
                        self._u = mix(w_sq[0] * eff[0], w_sq[1] * eff[1], w_sq[2] * eff[2], w_sq[3] * eff[3])
            self._ext = (tx / v.ixx_kg_m2, ty / v.iyy_kg_m2, tz / v.izz_kg_m2, fz * inv_m, fx * inv_m, fy * inv_m)
            y0 = self._y
            y1 = rk4_step(f, t_s + i * h, y0, h)
            if not _isfinite(sum(y1)):
                raise DivergenceError("paper plant state became non-finite", t_s + (i + 1) * h)
            if self.ground_contact and y1[6] < 0.0:
                src = y0 if y0[6] <= 0.0 else y1  # already resting: no sliding, no turning
                y1 = [0.0, 0.0, 0.0, 0.0, src[4], 0.0, 0.0, 0.0, src[8], 0.0, src[10], 0.0]
            self._accel = ((y1[9] - y0[9]) / h, (y1[11] - y0[11]) / h, (y1[7] - y0[7]) / h)
            self._y = y1
        self._t_s = t_s + dt_s
        self._obs_cache = None

    def truth(self) -> VehicleObservation:
        """The exact state as a :class:`VehicleObservation` (no sensor noise)."""
        phi, phi_d, th, th_d, psi, psi_d, z, z_d, x, x_d, y, y_d = self._y
        w1, w2, w3, w4 = self._w_sq
        phi_w = wrap_pi(phi)
        psi_w = wrap_pi(psi)
        return VehicleObservation(
            t_s=self._t_s,
            position_m=(x, y, z),
            velocity_mps=(x_d, y_d, z_d),
            euler_rad=(phi_w, th, psi_w),
            body_rates_radps=euler_rates_to_body_rates(phi, th, phi_d, th_d, psi_d),
            accel_mps2=self._accel,
            rotor_speed_radps=(
                _sqrt(w1 if w1 > 0.0 else 0.0),
                _sqrt(w2 if w2 > 0.0 else 0.0),
                _sqrt(w3 if w3 > 0.0 else 0.0),
                _sqrt(w4 if w4 > 0.0 else 0.0),
            ),
            quaternion=quat_from_euler(phi, th, psi),
        )
