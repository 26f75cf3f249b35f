"""One class per flight mode (after ArduCopter's mode.h): the small interface in :mod:`.base`,
then GUIDED, LOITER, ALT_HOLD, LAND, RTL and AUTO. :func:`build_modes` makes the set a vehicle
flies, one object per mode (AUTO flies its RTL items with the RTL object)."""

from __future__ import annotations

from fc.modes.alt_hold import AltHoldMode
from fc.modes.auto import AutoMode, AutoPhase
from fc.modes.base import FlightMode, HoldHereMode, ModeHost, Refusal
from fc.modes.guided import GuidedMode
from fc.modes.land import LandMode
from fc.modes.loiter import LoiterMode
from fc.modes.rtl import RtlMode, RtlPhase
from smcpilot.protocol import Mode


def build_modes(host: ModeHost) -> dict[Mode, FlightMode]:
    """Every mode this FC flies, by number, for one vehicle."""
    rtl = RtlMode(host)
    modes: list[FlightMode] = [
        AltHoldMode(host), AutoMode(host, rtl), GuidedMode(host), LoiterMode(host), rtl, LandMode(host),
    ]  # fmt: skip
    return {m.number: m for m in modes}


__all__ = [
    "AltHoldMode", "AutoMode", "AutoPhase", "FlightMode", "GuidedMode", "HoldHereMode", "LandMode", "LoiterMode",
    "ModeHost", "Refusal", "RtlMode", "RtlPhase", "build_modes",
]  # fmt: skip
