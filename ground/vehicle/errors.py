"""The errors of the ground-station client (all :class:`~smcpilot.errors.SmcpilotError`).

Hierarchy::

    SmcpilotError
    ├── VehicleError                 something the vehicle did (or did not do); the CLI exits 1
    │   ├── VehicleTimeout (also TimeoutError)
    │   │   ├── ConnectTimeout       no HEARTBEAT
    │   │   └── CommandTimeout       no COMMAND_ACK
    │   ├── CommandDenied            a MAV_RESULT other than ACCEPTED
    │   ├── SetpointRefused          a position target the vehicle did not take
    │   ├── ParamExchangeError (also importable as ParamError)
    │   │   └── ParamRejected        the vehicle kept another value
    │   └── MissionError
    └── ConfigError
        └── UnknownModeError         not an ArduCopter mode name
"""

from __future__ import annotations

from ground.vehicle.names import command_name, mission_result_name, result_name
from smcpilot.errors import ConfigError, SmcpilotError

__all__ = [
    "CommandDenied",
    "CommandTimeout",
    "ConnectTimeout",
    "MissionError",
    "ParamError",
    "ParamExchangeError",
    "ParamRejected",
    "SetpointRefused",
    "UnknownModeError",
    "VehicleError",
    "VehicleTimeout",
]


class VehicleError(SmcpilotError):
    """Something the vehicle did (or did not do) over the link; the CLI exits 1 on these."""


class VehicleTimeout(VehicleError, TimeoutError):
    """A wait or a protocol exchange ran out of time.

    ``what`` is what was awaited, ``last_value`` the last value seen (None if none),
    ``sim_time_s`` the vehicle's simulated time when we gave up (None if it never reported one).
    """

    def __init__(self, message: str, *, what: str, last_value: object = None, sim_time_s: float | None = None) -> None:
        super().__init__(message)
        self.what = what
        self.last_value = last_value
        self.sim_time_s = sim_time_s


class ConnectTimeout(VehicleTimeout):
    """No vehicle HEARTBEAT arrived in time."""


class CommandTimeout(VehicleTimeout):
    """No COMMAND_ACK arrived for a command after every retry."""


class CommandDenied(VehicleError):
    """The vehicle answered a command with a result other than MAV_RESULT_ACCEPTED.

    ``command`` is the MAV_CMD number, ``command_name`` its name, ``result`` the MAV_RESULT number,
    ``result_name`` its name (e.g. ``"MAV_RESULT_DENIED"``), ``reason`` the vehicle's STATUSTEXT
    that came with the refusal (None if none came).
    """

    def __init__(self, command: int, result: int, reason: str | None) -> None:
        self.command = command
        self.command_name = command_name(command)
        self.result = result
        self.result_name = result_name(result)
        self.reason = reason
        why = f": {reason}" if reason else ""
        super().__init__(f"{self.command_name} refused with {self.result_name}{why}")


class SetpointRefused(VehicleError):
    """The vehicle did not take a position target (``SET_POSITION_TARGET_*`` has no ack: its
    refusal STATUSTEXT came, or its echoed target stayed elsewhere). ``reason`` says why."""

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(f"set-point refused: {reason}")


class UnknownModeError(ConfigError):
    """A flight-mode name is not an ArduCopter mode (the message lists the valid names)."""


class ParamExchangeError(VehicleError):
    """A parameter exchange with the vehicle failed (unknown name, no echo, incomplete list)."""


#: The earlier name of :class:`ParamExchangeError` (``except ParamError`` keeps working).
ParamError = ParamExchangeError


class ParamRejected(ParamExchangeError):
    """The vehicle kept another value than the one set (out of range, not finite, read-only).

    ``name``, ``requested`` and ``value`` (now in force) are attributes; ``reason`` is the
    vehicle's STATUSTEXT, if one came.
    """

    def __init__(self, name: str, requested: float, value: float, reason: str | None) -> None:
        self.name = name
        self.requested = requested
        self.value = value
        self.reason = reason
        why = f": {reason}" if reason else ""
        super().__init__(f"parameter {name}: {requested:g} refused, value stays {value:g}{why}")


class MissionError(VehicleError):
    """A mission transaction failed; ``result_name`` is the MAV_MISSION_RESULT name when the
    vehicle sent one (None on a timeout), ``reason`` its STATUSTEXT if any."""

    def __init__(self, message: str, *, result: int | None = None, reason: str | None = None) -> None:
        self.result = result
        self.result_name = mission_result_name(result) if result is not None else None
        self.reason = reason
        super().__init__(message + (f": {reason}" if reason else ""))
