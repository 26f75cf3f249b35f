"""Mission items: :class:`MissionItem`, one item as the MISSION_ITEM_INT protocol carries it.

Positions are WGS-84 latitude/longitude in degrees (sent as ×1e7 integers, about 1 cm); altitudes
metres in the item's frame (by default above home, ``MAV_FRAME_GLOBAL_RELATIVE_ALT``); times
seconds; speeds m/s; headings degrees (0 north, 90 east).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.vehicle.names import command_name
from ground.vehicle.telemetry import HomePosition

__all__ = ["MissionItem"]

_NAN = float("nan")


def _finite_or_nan(v: float | None) -> float:
    return _NAN if v is None else float(v)


@dataclass(frozen=True)
class MissionItem:
    """One mission item as the MISSION_ITEM_INT protocol carries it.

    ``command`` is the MAV_CMD number, ``frame`` the MAV_FRAME (default
    ``MAV_FRAME_GLOBAL_RELATIVE_ALT``: altitude above home), ``param1``–``param4`` as the command
    defines them, ``lat_deg``/``lon_deg`` in degrees (sent as ×1e7 integers, so 1e-7° ≈ 1 cm
    resolution; 0, 0 means "here" for take-off, loiter and land), ``alt_m`` in metres in the
    frame's reference. Build items with the class methods.
    """

    command: int
    frame: int = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    lat_deg: float = 0.0
    lon_deg: float = 0.0
    alt_m: float = 0.0
    autocontinue: bool = True

    @classmethod
    def takeoff(cls, alt_m: float) -> MissionItem:
        """NAV_TAKEOFF to ``alt_m`` above home, over the current position."""
        return cls(mavlink.MAV_CMD_NAV_TAKEOFF, alt_m=float(alt_m))

    @classmethod
    def waypoint(
        cls,
        lat_deg: float,
        lon_deg: float,
        alt_m: float,
        *,
        hold_s: float = 0.0,
        acceptance_radius_m: float = 0.0,
        yaw_deg: float | None = None,
    ) -> MissionItem:
        """NAV_WAYPOINT at ``alt_m`` above home; hold ``hold_s`` s there; radius 0 = WP_RADIUS;
        ``yaw_deg`` None (NaN on the wire) keeps the heading."""
        return cls(
            mavlink.MAV_CMD_NAV_WAYPOINT,
            param1=float(hold_s),
            param2=float(acceptance_radius_m),
            param4=_finite_or_nan(yaw_deg),
            lat_deg=float(lat_deg),
            lon_deg=float(lon_deg),
            alt_m=float(alt_m),
        )

    @classmethod
    def loiter_time(
        cls, hold_s: float, lat_deg: float = 0.0, lon_deg: float = 0.0, alt_m: float = 0.0
    ) -> MissionItem:
        """NAV_LOITER_TIME: hold ``hold_s`` s at the position (0, 0 = here) and ``alt_m`` above home."""
        return cls(
            mavlink.MAV_CMD_NAV_LOITER_TIME, param1=float(hold_s), lat_deg=float(lat_deg), lon_deg=float(lon_deg), alt_m=float(alt_m)
        )

    @classmethod
    def land(cls, lat_deg: float = 0.0, lon_deg: float = 0.0) -> MissionItem:
        """NAV_LAND at the position (0, 0 = where the vehicle is)."""
        return cls(mavlink.MAV_CMD_NAV_LAND, lat_deg=float(lat_deg), lon_deg=float(lon_deg))

    @classmethod
    def rtl(cls) -> MissionItem:
        """NAV_RETURN_TO_LAUNCH."""
        return cls(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH)

    @classmethod
    def change_speed(cls, speed_mps: float) -> MissionItem:
        """DO_CHANGE_SPEED: horizontal speed ``speed_mps`` (ground speed; -1 = no change)."""
        return cls(
            mavlink.MAV_CMD_DO_CHANGE_SPEED, frame=mavlink.MAV_FRAME_MISSION, param1=1.0, param2=float(speed_mps), param3=-1.0
        )

    @classmethod
    def home(cls, home: HomePosition | None) -> MissionItem:
        """Item 0 (home): a NAV_WAYPOINT in MAV_FRAME_GLOBAL (altitude AMSL); zeros if unknown."""
        if home is None:
            return cls(mavlink.MAV_CMD_NAV_WAYPOINT, frame=mavlink.MAV_FRAME_GLOBAL)
        return cls(
            mavlink.MAV_CMD_NAV_WAYPOINT,
            frame=mavlink.MAV_FRAME_GLOBAL,
            lat_deg=home.lat_deg,
            lon_deg=home.lon_deg,
            alt_m=home.alt_amsl_m,
        )

    @property
    def command_name(self) -> str:
        return command_name(self.command)

    def to_message(self, mav: mavlink.MAVLink, seq: int, target_system: int, target_component: int) -> mavlink.MAVLink_message:
        """The MISSION_ITEM_INT for sequence number ``seq``."""
        return mav.mission_item_int_encode(
            target_system,
            target_component,
            seq,
            self.frame,
            self.command,
            0,
            1 if self.autocontinue else 0,
            self.param1,
            self.param2,
            self.param3,
            self.param4,
            int(round(self.lat_deg * 1e7)),
            int(round(self.lon_deg * 1e7)),
            float(self.alt_m),
            mavlink.MAV_MISSION_TYPE_MISSION,
        )

    @classmethod
    def from_message(cls, msg: mavlink.MAVLink_message) -> MissionItem:
        """From MISSION_ITEM_INT (lat/lon ×1e7) or MISSION_ITEM (float degrees)."""
        if msg.get_type() == "MISSION_ITEM_INT":
            lat, lon = msg.x * 1e-7, msg.y * 1e-7
        else:
            lat, lon = float(msg.x), float(msg.y)
        return cls(
            command=msg.command,
            frame=msg.frame,
            param1=float(msg.param1),
            param2=float(msg.param2),
            param3=float(msg.param3),
            param4=float(msg.param4),
            lat_deg=lat,
            lon_deg=lon,
            alt_m=float(msg.z),
            autocontinue=bool(msg.autocontinue),
        )

    def close_to(self, other: MissionItem, *, pos_tol_deg: float = 2e-7, tol: float = 1e-4) -> bool:
        """Same command, frame and autocontinue, and numbers equal within the wire's resolution
        (lat/lon to ``pos_tol_deg``, the rest to ``tol`` relative; NaN equals NaN)."""

        def same(a: float, b: float, t: float) -> bool:
            if math.isnan(a) or math.isnan(b):
                return math.isnan(a) and math.isnan(b)
            return abs(a - b) <= t * max(1.0, abs(a), abs(b))

        return (
            self.command == other.command
            and _same_frame(self.frame, other.frame)
            and self.autocontinue == other.autocontinue
            and all(same(getattr(self, f), getattr(other, f), tol) for f in ("param1", "param2", "param3", "param4", "alt_m"))
            and abs(self.lat_deg - other.lat_deg) <= pos_tol_deg
            and abs(self.lon_deg - other.lon_deg) <= pos_tol_deg
        )


_INT_FRAMES = {
    mavlink.MAV_FRAME_GLOBAL_INT: mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT: mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
}


def _same_frame(a: int, b: int) -> bool:
    """Frames equal, counting ``*_INT`` frames as their plain twins (the same meaning)."""
    return _INT_FRAMES.get(a, a) == _INT_FRAMES.get(b, b)

