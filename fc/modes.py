"""Flight modes, numbered as ArduCopter's custom modes so ground stations show them by name."""

from __future__ import annotations

from enum import IntEnum


class Mode(IntEnum):
    """The modes this FC flies (docs/gcs-protocol.md)."""

    ALT_HOLD = 2
    AUTO = 3
    GUIDED = 4
    LOITER = 5
    RTL = 6
    LAND = 9


#: ArduCopter's other mode numbers: known by name, refused here (they need RC sticks or hardware).
REFUSED_MODES: dict[int, str] = {
    0: "STABILIZE",
    1: "ACRO",
    7: "CIRCLE",
    11: "DRIFT",
    13: "SPORT",
    14: "FLIP",
    15: "AUTOTUNE",
    16: "POSHOLD",
    17: "BRAKE",
    18: "THROW",
    19: "AVOID_ADSB",
    20: "GUIDED_NOGPS",
    21: "SMART_RTL",
    22: "FLOWHOLD",
    23: "FOLLOW",
    24: "ZIGZAG",
    25: "SYSTEMID",
    26: "AUTOROTATE",
    27: "AUTO_RTL",
}

#: Modes one may arm in.
ARMABLE = frozenset({Mode.ALT_HOLD, Mode.AUTO, Mode.GUIDED, Mode.LOITER})


def mode_name(number: int) -> str:
    try:
        return Mode(number).name
    except ValueError:
        return REFUSED_MODES.get(number, f"MODE_{number}")


def mode_from_name(name: str) -> Mode:
    """A mode by name (case-insensitive); raises ValueError naming the valid ones."""
    key = name.strip().upper()
    if key in Mode.__members__:
        return Mode[key]
    valid = ", ".join(m.name for m in Mode)
    if key in REFUSED_MODES.values():
        raise ValueError(f"mode {key} is not supported by this flight controller (it needs RC input); use one of {valid}")
    raise ValueError(f"unknown mode {name!r}; use one of {valid}")
