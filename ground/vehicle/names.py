"""MAVLink enum numbers as names, for messages and errors (``MAV_RESULT``, ``MAV_CMD``, ...)."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = ["command_name", "enum_name", "mission_result_name", "result_name"]


def enum_name(enum: str, value: int) -> str:
    """The name of ``value`` in the MAVLink enum ``enum``, or ``"ENUM(value)"`` if it has none."""
    entry = mavlink.enums.get(enum, {}).get(value)
    return entry.name if entry is not None else f"{enum}({value})"


def result_name(result: int) -> str:
    """``MAV_RESULT`` number -> name, e.g. 2 -> ``"MAV_RESULT_DENIED"``."""
    return enum_name("MAV_RESULT", result)


def command_name(command: int) -> str:
    """``MAV_CMD`` number -> name, e.g. 22 -> ``"MAV_CMD_NAV_TAKEOFF"``."""
    return enum_name("MAV_CMD", command)


def mission_result_name(result: int) -> str:
    """``MAV_MISSION_RESULT`` number -> name."""
    return enum_name("MAV_MISSION_RESULT", result)
