"""The simulated environment: wind, gusts, the paper's disturbances and sensor noise.

Everything is off by default (:class:`EnvironmentParams` defaults are zero / False), so a default
run is deterministic and clean.

Frames and units
----------------
- Wind and gust **forces** act on the centre of mass, world NWU (x north, y west, z up), N.
- Gust **torques** act about the body FLU axes (x forward, y left, z up), N m.
- The paper's disturbances (:func:`sim_bridge.disturbances.paper_disturbance`) are extra
  accelerations on phi, theta, psi [rad/s^2] and z [m/s^2]; a plant adds them to its own
  dynamics (see the plants' docs for how the rigid body maps Euler-angle accelerations).

Gusts
-----
Each gust component is an independent first-order Gauss-Markov process
(``dF = -F/T dt + std sqrt(2/T) dW``) with stationary standard deviation ``std`` and correlation
time ``T`` (:attr:`EnvironmentParams.gust_time_constant_s`). It is discretised exactly,
``F_{k+1} = a F_k + std sqrt(1 - a^2) n_k`` with ``a = exp(-dt/T)``, so any step size gives the
same statistics; the force is held constant over a step. The initial value is drawn from the
stationary distribution.

Randomness
----------
All random numbers come from the ``random.Random`` passed in. Two independent streams are split
off it at construction (one for gusts, one for sensor noise), so how often a caller reads noisy
observations does not change the gust sequence. The same seed and the same calls give the same
run.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field

from sim_bridge.sensors import SensorNoise, SensorNoiseParams, VehicleObservation
from smcpilot.errors import ConfigError

_exp = math.exp
_sqrt = math.sqrt


def _check_number(name: str, value: object, *, positive: bool = False) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"environment {name!r} must be a finite number, got {value!r}")
    if value < 0.0 or (positive and value == 0.0):
        raise ConfigError(f"environment {name!r} must be {'> 0' if positive else '>= 0'}, got {value!r}")


@dataclass(frozen=True)
class EnvironmentParams:
    """Environment settings; the defaults are no wind, no gusts, no disturbance, no noise."""

    #: Constant wind force on the vehicle, world NWU (x north, y west, z up), N.
    wind_force_n: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: Stationary std of the gust force along world x and y (each), N.
    gust_force_std_xy_n: float = 0.0
    #: Stationary std of the gust force along world z, N.
    gust_force_std_z_n: float = 0.0
    #: Stationary std of the gust torque about each body FLU axis, N m.
    gust_torque_std_n_m: float = 0.0
    #: Correlation time of the gust processes, s.
    gust_time_constant_s: float = 1.0
    #: Add the paper's "sensor failure" disturbances (spec section 1) to the dynamics.
    paper_disturbance: bool = False
    #: Sensor noise on the observations.
    sensor_noise: SensorNoiseParams = field(default_factory=SensorNoiseParams)

    def __post_init__(self) -> None:
        w = self.wind_force_n
        if not isinstance(w, tuple) or len(w) != 3:
            raise ConfigError(f"environment 'wind_force_n' must be a tuple of 3 numbers, got {w!r}")
        for i, v in enumerate(w):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"environment 'wind_force_n'[{i}] must be a finite number, got {v!r}")
        _check_number("gust_force_std_xy_n", self.gust_force_std_xy_n)
        _check_number("gust_force_std_z_n", self.gust_force_std_z_n)
        _check_number("gust_torque_std_n_m", self.gust_torque_std_n_m)
        _check_number("gust_time_constant_s", self.gust_time_constant_s, positive=True)
        if not isinstance(self.paper_disturbance, bool):
            raise ConfigError(f"environment 'paper_disturbance' must be true or false, got {self.paper_disturbance!r}")
        if not isinstance(self.sensor_noise, SensorNoiseParams):
            raise ConfigError("environment 'sensor_noise' must be a SensorNoiseParams")

    @property
    def gusts_enabled(self) -> bool:
        """True when any gust standard deviation is non-zero."""
        return self.gust_force_std_xy_n > 0.0 or self.gust_force_std_z_n > 0.0 or self.gust_torque_std_n_m > 0.0

    @property
    def needs_rng(self) -> bool:
        """True when the environment needs random numbers (gusts or sensor noise)."""
        return self.gusts_enabled or self.sensor_noise.enabled


class Environment:
    """Stateful environment a plant queries once per integration step.

    A plant calls :meth:`advance` once per step, then reads :attr:`force_world_n` and
    :attr:`torque_body_n_m` (held constant over the step), adds the paper disturbance when
    :attr:`paper_disturbance` is set, and passes its observations through :meth:`measure`.

    Args:
        params: the settings.
        rng: the random source; required when ``params`` has gusts or sensor noise.
    """

    def __init__(self, params: EnvironmentParams = EnvironmentParams(), rng: random.Random | None = None) -> None:
        if params.needs_rng and rng is None:
            raise ConfigError("the environment has gusts or sensor noise but no random.Random was given (pass rng=)")
        self.params = params
        self.paper_disturbance: bool = params.paper_disturbance
        self.gusts_enabled: bool = params.gusts_enabled
        if rng is not None:
            self._gust_rng: random.Random | None = random.Random(rng.getrandbits(64))
            noise_rng: random.Random | None = random.Random(rng.getrandbits(64))
        else:
            self._gust_rng = None
            noise_rng = None
        self.sensors = SensorNoise(params.sensor_noise, noise_rng)
        #: Current gust state: force (x, y, z) world NWU [N], torque (x, y, z) body FLU [N m].
        self._gust = [0.0] * 6
        self._std = (
            params.gust_force_std_xy_n,
            params.gust_force_std_xy_n,
            params.gust_force_std_z_n,
            params.gust_torque_std_n_m,
            params.gust_torque_std_n_m,
            params.gust_torque_std_n_m,
        )
        self._last_dt_s = -1.0
        self._a = 0.0
        self._b = 0.0
        #: Total external force, world NWU [N], valid for the current step.
        self.force_world_n: tuple[float, float, float] = params.wind_force_n
        #: Total external torque, body FLU [N m], valid for the current step.
        self.torque_body_n_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.reset()

    def reset(self) -> None:
        """Restart the gust processes from a fresh stationary draw (the random streams continue)."""
        if self.gusts_enabled:
            g = self._gust_rng.gauss  # type: ignore[union-attr]
            self._gust = [g(0.0, s) if s > 0.0 else 0.0 for s in self._std]
        else:
            self._gust = [0.0] * 6
        self._publish()

    def advance(self, dt_s: float) -> None:
        """Advance the gust processes by ``dt_s`` seconds (call once per plant step)."""
        if not self.gusts_enabled:
            return
        if dt_s != self._last_dt_s:
            a = _exp(-dt_s / self.params.gust_time_constant_s)
            self._a = a
            self._b = _sqrt(max(0.0, 1.0 - a * a))
            self._last_dt_s = dt_s
        a = self._a
        b = self._b
        g = self._gust_rng.gauss  # type: ignore[union-attr]
        gust = self._gust
        std = self._std
        for i in range(6):
            s = std[i]
            if s > 0.0:
                gust[i] = a * gust[i] + b * g(0.0, s)
        self._publish()

    def _publish(self) -> None:
        w = self.params.wind_force_n
        gu = self._gust
        self.force_world_n = (w[0] + gu[0], w[1] + gu[1], w[2] + gu[2])
        self.torque_body_n_m = (gu[3], gu[4], gu[5])

    def measure(self, obs: VehicleObservation) -> VehicleObservation:
        """The observation with sensor noise added (unchanged when noise is off)."""
        return self.sensors.apply(obs)
