"""LOITER: hold the position where the mode was entered (position and altitude)."""

from __future__ import annotations

from fc.modes.base import HoldHereMode
from smcpilot.protocol import Mode


class LoiterMode(HoldHereMode):
    number = Mode.LOITER
