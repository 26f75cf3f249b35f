"""ALT_HOLD: the paper's control: level attitude, altitude and heading held, no horizontal
position hold (the vehicle drifts with the wind; the horizontal references follow it)."""

from __future__ import annotations

from fc.modes.base import HoldHereMode
from smcpilot.protocol import Mode


class AltHoldMode(HoldHereMode):
    number = Mode.ALT_HOLD
    position_hold = False
