"""What every simulator plant shares: the environment, the faults, the step limit, time, and the
cached noisy (and faulty) observation. Plants implement ``reset``, ``step`` and ``truth``."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

from sim_bridge.environment import Environment
from sim_bridge.faults import SimFaults
from sim_bridge.sensors import VehicleObservation
from smcpilot.errors import ConfigError
from smcpilot.vehicle import VehicleParams


class Plant(Protocol):
    """A simulated vehicle as every runner steps it (the simulator process, the in-process runner):
    ``step`` advances ``dt_s`` seconds holding the motor commands (c1..c4 in [0, 1]; not armed:
    rotors stop), ``observe`` gives the state the sensors report (noisy, faulty, paper frame);
    ``faults`` are its active faults (None: the plant takes none, not even live parameters)."""

    faults: SimFaults | None

    def step(self, t_s: float, dt_s: float, motor_commands: Sequence[float], armed: bool) -> None: ...

    def observe(self) -> VehicleObservation: ...


class PlantBase:
    """Common state and :meth:`observe` of the plants (see :mod:`sim_bridge.plants.rigid_body`).

    Args:
        vehicle: physical parameters.
        env: wind, gusts, paper disturbances and sensor noise; None is a clean environment.
        max_step_s: largest integration step [s]; ``step`` splits longer intervals.
        ground_contact: model the ground at z = 0.
        faults: the timed faults and live SIM_* parameters (:mod:`sim_bridge.faults`); None: none.
    """

    def __init__(
        self,
        vehicle: VehicleParams,
        env: Environment | None,
        *,
        max_step_s: float,
        ground_contact: bool,
        faults: SimFaults | None = None,
    ) -> None:
        if not (isinstance(max_step_s, (int, float)) and math.isfinite(max_step_s) and max_step_s > 0.0):
            raise ConfigError(f"max_step_s must be a positive number of seconds, got {max_step_s!r}")
        self.vehicle = vehicle
        self.env = env if env is not None else Environment()
        self.max_step_s = float(max_step_s)
        self.ground_contact = bool(ground_contact)
        self.faults = faults
        self._t_s = 0.0
        self._accel = (0.0, 0.0, 0.0)
        self._obs_cache: VehicleObservation | None = None

    @property
    def t_s(self) -> float:
        """Simulation time [s] at the end of the last step."""
        return self._t_s

    def truth(self) -> VehicleObservation:  # pragma: no cover - implemented by each plant
        raise NotImplementedError

    def observe(self) -> VehicleObservation:
        """The observation with the environment's sensor noise (if any) and the sensor faults.

        Drawn once per step: calling this again before the next step returns the same object.
        """
        obs = self._obs_cache
        if obs is None:
            obs = self.env.measure(self.truth())
            faults = self.faults
            if faults is not None:
                obs = faults.observe(obs)
            self._obs_cache = obs
        return obs
