"""ArduCopter flight modes: names <-> custom-mode numbers (the table is
:data:`smcpilot.protocol.COPTER_MODES`, shared with the flight controller)."""

from __future__ import annotations

from ground.vehicle.errors import UnknownModeError
from smcpilot.protocol import COPTER_MODE_NAMES, COPTER_MODES

__all__ = ["COPTER_MODES", "mode_name", "mode_number"]


def mode_number(name: str | int) -> int:
    """ArduCopter custom-mode number of a mode name (case-insensitive) or number.

    Raises :class:`UnknownModeError` listing the valid names.
    """
    if isinstance(name, int) and not isinstance(name, bool):
        if name < 0:
            raise UnknownModeError(f"mode number must be >= 0, got {name}")
        return name
    key = str(name).strip().upper()
    if key.isdigit():
        return int(key)
    try:
        return COPTER_MODES[key]
    except KeyError:
        valid = ", ".join(COPTER_MODES)
        raise UnknownModeError(f"unknown flight mode {name!r}; ArduCopter modes: {valid}") from None


def mode_name(number: int | None) -> str | None:
    """ArduCopter mode name of a custom-mode number (``"MODE_<n>"`` if unknown, None for None)."""
    if number is None:
        return None
    return COPTER_MODE_NAMES.get(number, f"MODE_{number}")
