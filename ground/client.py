"""The ground-station client, under its first name: it lives in :mod:`ground.vehicle` now
(:class:`~ground.vehicle.Vehicle` with its ``commands``, ``params`` and ``mission`` parts; see that
package's docstring for the protocol, the clocks and the errors). This module re-exports the
public names (``__all__`` as before, and ``GCS_SYSTEM_ID``, ``GCS_COMPONENT_ID``,
``command_name``, ``mission_result_name``, ``json_safe``), so ``from ground.client import Vehicle``
keeps working.
"""

from __future__ import annotations

from ground.vehicle.errors import (
    CommandDenied,
    CommandTimeout,
    ConnectTimeout,
    MissionError,
    ParamError,
    ParamExchangeError,
    ParamRejected,
    UnknownModeError,
    VehicleError,
    VehicleTimeout,
)
from ground.vehicle.items import MissionItem
from ground.vehicle.link import GCS_COMPONENT_ID as GCS_COMPONENT_ID
from ground.vehicle.link import GCS_SYSTEM_ID as GCS_SYSTEM_ID
from ground.vehicle.modes import COPTER_MODES, mode_name, mode_number
from ground.vehicle.names import command_name as command_name
from ground.vehicle.names import mission_result_name as mission_result_name
from ground.vehicle.names import result_name
from ground.vehicle.subscription import Subscription
from ground.vehicle.telemetry import HomePosition, StatusText, Telemetry
from ground.vehicle.telemetry import json_safe as json_safe
from ground.vehicle.vehicle import Vehicle

__all__ = [
    "COPTER_MODES",
    "CommandDenied",
    "CommandTimeout",
    "ConnectTimeout",
    "HomePosition",
    "MissionError",
    "MissionItem",
    "ParamError",
    "ParamExchangeError",
    "ParamRejected",
    "StatusText",
    "Subscription",
    "Telemetry",
    "UnknownModeError",
    "Vehicle",
    "VehicleError",
    "VehicleTimeout",
    "mode_number",
    "mode_name",
    "result_name",
]
