"""Build the simulated vehicle of a scenario: plant, environment, sensors, faults, seeded streams.

The simulator process (:mod:`sim_bridge.cli`) and the in-process runner (:mod:`lab.runner`) both
build their plant here, so the same :class:`smcpilot.scenario.Scenario` flies the same physics,
the same faults and the same random streams either way. Every plant built here has a
:class:`sim_bridge.faults.SimFaults` (``plant.faults``): the scenario's timed faults, and the live
``SIM_*`` parameters the simulator process takes over the sim link.
"""

from __future__ import annotations

import random
from collections.abc import Sequence

from sim_bridge.environment import Environment, EnvironmentParams
from sim_bridge.faults import SimFaults
from sim_bridge.plants.paper_vehicle import PaperVehiclePlant
from sim_bridge.plants.rigid_body import RigidBodyPlant
from sim_bridge.sensors import SensorNoiseParams
from smcpilot.errors import ConfigError
from smcpilot.faults import FaultSpec
from smcpilot.frames import ned_to_nwu
from smcpilot.scenario import PLANTS, EnvironmentSpec, Scenario
from smcpilot.vehicle import VehicleParams


def environment_params(spec: EnvironmentSpec) -> EnvironmentParams:
    """The simulator's environment settings (world NWU) of a scenario's environment (NED)."""
    att, rate, pos, vel = spec.noise_std
    wind = ned_to_nwu(spec.wind_force_ned_n)
    return EnvironmentParams(
        wind_force_n=(float(wind[0]), float(wind[1]), float(wind[2])),
        gust_force_std_xy_n=spec.gust_std_n,
        gust_time_constant_s=spec.gust_tau_s,
        paper_disturbance=spec.paper_disturbance,
        sensor_noise=SensorNoiseParams(att, rate, pos, vel),
    )


def make_plant(
    plant: str, vehicle: VehicleParams, environment: EnvironmentSpec, seed: int, faults: Sequence[FaultSpec] = ()
) -> RigidBodyPlant | PaperVehiclePlant:
    """A fresh plant at rest on the ground, its noise, gust and fault streams seeded with ``seed``,
    with the timed ``faults``."""
    if plant not in PLANTS:
        raise ConfigError(f"unknown plant {plant!r}; choose from: {', '.join(PLANTS)}")
    env = Environment(environment_params(environment), random.Random(seed))
    sim_faults = SimFaults(faults, seed)
    if plant == "paper":
        return PaperVehiclePlant(vehicle, env, faults=sim_faults)
    return RigidBodyPlant(vehicle, env, faults=sim_faults)


def plant_for(scenario: Scenario) -> RigidBodyPlant | PaperVehiclePlant:
    """The plant a scenario flies (its faults included)."""
    return make_plant(scenario.plant, scenario.vehicle, scenario.environment, scenario.seed, scenario.faults)
