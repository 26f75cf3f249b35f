"""What the simulator reports about the vehicle, and the sensor noise added to it.

:class:`VehicleObservation` is the one observation type of every plant (rigid body and the
paper plant adapter), in the paper's frames: world NWU (x north, y west, z up), body FLU
(x forward, y left, z up), ZYX Euler angles. Conversion to MAVLink's NED/FRD happens at the wire
(:mod:`smcpilot.frames`).

Sensor noise is white Gaussian, independent per axis and per sample, with standard deviations
in :class:`SensorNoiseParams` (all zero by default: a clean, deterministic observation). The
random numbers come from a ``random.Random`` passed in, never from the global generator.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, fields
from typing import NamedTuple

from smcpilot.errors import ConfigError
from smcpilot.frames import flu_to_frd, quat_from_euler, quat_rotate_inverse, rates_flu_to_frd, wrap_pi

Vec3 = tuple[float, float, float]


class VehicleObservation(NamedTuple):
    """The vehicle's state as the simulator reports it (paper frames, SI units).

    Attributes:
        t_s: simulation time [s].
        position_m: (x, y, z) world NWU [m]; z is height above the ground.
        velocity_mps: (x', y', z') world NWU [m/s].
        euler_rad: (phi, theta, psi) ZYX of FLU body in NWU [rad]; phi and psi in [-pi, pi).
        body_rates_radps: (p, q, r) about body FLU axes [rad/s].
        accel_mps2: world NWU kinematic acceleration [m/s^2] (dv/dt averaged over the last
            step; gravity is not included, so it is 0 at rest or in hover).
        rotor_speed_radps: (w1, w2, w3, w4) [rad/s], rotors 1 right, 2 front, 3 left, 4 rear.
        quaternion: (w, x, y, z), FLU body -> NWU world, consistent with ``euler_rad``.
    """

    t_s: float
    position_m: tuple[float, float, float]
    velocity_mps: tuple[float, float, float]
    euler_rad: tuple[float, float, float]
    body_rates_radps: tuple[float, float, float]
    accel_mps2: tuple[float, float, float]
    rotor_speed_radps: tuple[float, float, float, float]
    quaternion: tuple[float, float, float, float]


@dataclass(frozen=True)
class SensorNoiseParams:
    """Standard deviations of white Gaussian sensor noise, per axis. Zero means no noise."""

    #: Noise on each Euler angle phi, theta, psi [rad].
    attitude_std_rad: float = 0.0
    #: Noise on each body rate p, q, r [rad/s].
    body_rate_std_radps: float = 0.0
    #: Noise on each world position coordinate [m].
    position_std_m: float = 0.0
    #: Noise on each world velocity coordinate [m/s].
    velocity_std_mps: float = 0.0
    #: Noise on each world acceleration coordinate [m/s^2].
    accel_std_mps2: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"sensor noise {f.name!r} must be a finite number, got {value!r}")
            if value < 0.0:
                raise ConfigError(f"sensor noise {f.name!r} must be >= 0, got {value!r}")

    @property
    def enabled(self) -> bool:
        """True when any standard deviation is non-zero."""
        return any(getattr(self, f.name) > 0.0 for f in fields(self))


class SensorNoise:
    """Adds :class:`SensorNoiseParams` noise to observations, drawing from ``rng``.

    ``rng`` may be None only when the parameters have no noise.
    """

    def __init__(self, params: SensorNoiseParams = SensorNoiseParams(), rng: random.Random | None = None) -> None:
        if params.enabled and rng is None:
            raise ConfigError("sensor noise is enabled but no random.Random was given (pass rng=)")
        self.params = params
        self.enabled = params.enabled
        self._rng = rng

    def apply(self, obs: VehicleObservation) -> VehicleObservation:
        """A noisy copy of ``obs`` (``obs`` itself when noise is disabled).

        Rotor speeds and time are not perturbed. Attitude noise is added to the Euler angles;
        the quaternion is recomputed from the noisy angles so both stay consistent.
        """
        if not self.enabled:
            return obs
        p = self.params
        g = self._rng.gauss  # type: ignore[union-attr]

        def noisy3(v: tuple[float, float, float], std: float) -> tuple[float, float, float]:
            if std <= 0.0:
                return v
            return (v[0] + g(0.0, std), v[1] + g(0.0, std), v[2] + g(0.0, std))

        euler = obs.euler_rad
        quat = obs.quaternion
        if p.attitude_std_rad > 0.0:
            s = p.attitude_std_rad
            euler = (wrap_pi(euler[0] + g(0.0, s)), euler[1] + g(0.0, s), wrap_pi(euler[2] + g(0.0, s)))
            quat = quat_from_euler(*euler)
        return obs._replace(
            position_m=noisy3(obs.position_m, p.position_std_m),
            velocity_mps=noisy3(obs.velocity_mps, p.velocity_std_mps),
            euler_rad=euler,
            body_rates_radps=noisy3(obs.body_rates_radps, p.body_rate_std_radps),
            accel_mps2=noisy3(obs.accel_mps2, p.accel_std_mps2),
            quaternion=quat,
        )


def specific_force_frd(accel_nwu: Vec3, quat_flu_nwu: tuple[float, float, float, float], g: float) -> Vec3:
    """What an accelerometer reads, body FRD, m/s^2: the kinematic acceleration (world NWU) minus
    gravity, rotated into the body: (0, 0, -g) level at rest. NaN in (a dropout) is NaN out."""
    f_world = (accel_nwu[0], accel_nwu[1], accel_nwu[2] + g)
    return flu_to_frd(quat_rotate_inverse(quat_flu_nwu, f_world))


def imu_frd(obs: VehicleObservation, truth: VehicleObservation, g: float) -> tuple[Vec3, Vec3]:
    """(gyro rad/s, specific force m/s^2), body FRD, as the sensors report them: the observation's
    rates and acceleration, with the environment's sensor noise and the gyro and accelerometer
    faults (stuck, bias, noise, delay; a dropout is NaN), converted to specific force with the true
    attitude (the accelerometer sits on the real body, whatever an attitude fault says)."""
    return rates_flu_to_frd(*obs.body_rates_radps), specific_force_frd(obs.accel_mps2, truth.quaternion, g)
