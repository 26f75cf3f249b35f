"""GUIDED: hold the position set-point a ground station (or the timed plan) gives.

Set-points arrive through the commander's entry points (``takeoff``, ``goto_local``,
``reposition``); the mode itself only holds where it was entered.
"""

from __future__ import annotations

from fc.modes.base import HoldHereMode
from smcpilot.protocol import Mode


class GuidedMode(HoldHereMode):
    number = Mode.GUIDED
