"""Ground-station input: what the FC accepts from the ground link.

So far: ``SET_POSITION_TARGET_LOCAL_NED`` (MAV_FRAME_LOCAL_NED) as a position set-point, with the
yaw when the type mask does not ignore it. Messages addressed to another system are dropped and
counted; so are set-points with non-finite values. (The full GCS protocol — modes, commands,
parameters, missions — is built on this handler.)
"""

from __future__ import annotations

import math
from collections import Counter
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot.frames import euler_frd_to_flu, ned_to_nwu

if TYPE_CHECKING:  # pragma: no cover
    from fc.app import FlightControllerApp

# POSITION_TARGET_TYPEMASK bits
_IGNORE_POS = 0x7
_IGNORE_YAW = 0x400


class GcsHandler:
    """Dispatches ground-link messages to the flight controller."""

    def __init__(self, app: "FlightControllerApp") -> None:
        self.app = app
        #: reason -> count of dropped messages
        self.rejected: Counter[str] = Counter()
        self.gcs_heartbeats = 0

    def _for_us(self, target_system: int) -> bool:
        if target_system in (0, self.app.cfg.system_id):
            return True
        self.rejected["other_system"] += 1
        return False

    def handle(self, msg: mavlink.MAVLink_message, addr: tuple[str, int]) -> None:
        mid = msg.id
        if mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            self.gcs_heartbeats += 1
        elif mid == mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED:
            if self._for_us(msg.target_system):
                self._position_target(msg)

    def _position_target(self, msg: mavlink.MAVLink_set_position_target_local_ned_message) -> None:
        if msg.coordinate_frame != mavlink.MAV_FRAME_LOCAL_NED:
            self.rejected["unsupported_frame"] += 1
            return
        if msg.type_mask & _IGNORE_POS:
            self.rejected["no_position"] += 1
            return
        vals = (msg.x, msg.y, msg.z)
        if not all(math.isfinite(v) for v in vals):
            self.rejected["non_finite"] += 1
            return
        yaw = None
        if not msg.type_mask & _IGNORE_YAW:
            if not math.isfinite(msg.yaw):
                self.rejected["non_finite"] += 1
                return
            yaw = euler_frd_to_flu(0.0, 0.0, msg.yaw)[2]
        flight = self.app.flight
        if not flight.armed:
            self.rejected["not_armed"] += 1
            return
        x, y, z = ned_to_nwu(vals)
        flight.set_target(x, y, z, yaw)

    def on_tick(self, t_us: int) -> None:
        """Called once per control tick (time-based protocol work hooks in here)."""
