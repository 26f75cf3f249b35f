"""The inbound adapter: every target source, from its wire frame to the paper frame, in one place.

The flight controller flies in the paper frame (x north, y west, z up above home; FLU yaw, rad,
counter-clockwise seen from above). Targets arrive in other frames:

================================  ===========================================================
source                            frame on the wire
================================  ===========================================================
``SET_POSITION_TARGET_LOCAL_NED``  NED position (m from home), FRD yaw (rad, clockwise)
``SET_POSITION_TARGET_GLOBAL_INT`` latitude/longitude, altitude above home or AMSL, FRD yaw
``MAV_CMD_DO_REPOSITION``          latitude/longitude, altitude above home or AMSL, compass yaw (deg)
mission items                      latitude/longitude (1e7), altitude in the item's frame, compass yaw
timed-plan steps                   north/east/altitude (m), compass yaw (deg)
================================  ===========================================================

These functions take the wire values (already decoded from the message: degrees, metres) and
return paper-frame values, through :mod:`smcpilot.frames` (NED/FRD <-> NWU/FLU) and
:mod:`smcpilot.geo` (global <-> local around home). Validation that belongs to the protocol
(type masks, frames supported, ranges) stays with the caller.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from fc.mission import CMD_WAYPOINT, RELATIVE_FRAMES, MissionItem
from smcpilot.frames import euler_frd_to_flu, ned_to_nwu
from smcpilot.geo import Home, global_to_ned
from smcpilot.plan import PlanStep

_isfinite = math.isfinite


class Target(NamedTuple):
    """A set-point in the paper frame: position (m; z up above home) and heading (FLU yaw, rad;
    None: keep the heading)."""

    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float | None = None


# -- headings ------------------------------------------------------------------------------------
def yaw_of_frd(yaw_frd_rad: float) -> float:
    """FLU yaw (paper frame) of a MAVLink (NED/FRD) yaw, rad."""
    return euler_frd_to_flu(0.0, 0.0, yaw_frd_rad)[2]


def yaw_of_compass_deg(yaw_deg: float) -> float:
    """FLU yaw of a compass heading in degrees (0 north, 90 east), rad."""
    return euler_frd_to_flu(0.0, 0.0, math.radians(yaw_deg))[2]


# -- positions -----------------------------------------------------------------------------------
def altitude_above_home(home: Home, alt_m: float, relative: bool) -> float:
    """z (up, above home) of an altitude that is either above home (``relative``) or AMSL."""
    return alt_m if relative else alt_m - home.alt_m


def position_of_global(home: Home, lat_deg: float, lon_deg: float, alt_m: float, relative: bool) -> tuple[float, float, float]:
    """Paper-frame (x north, y west, z up above home) position of a global point; ``alt_m`` is
    above home when ``relative``, else AMSL."""
    alt_amsl = alt_m + home.alt_m if relative else alt_m
    n, e, d = global_to_ned(home, lat_deg, lon_deg, alt_amsl)
    return ned_to_nwu((n, e, d))


def position_of_local_ned(north_m: float, east_m: float, down_m: float) -> tuple[float, float, float]:
    """Paper-frame position of a MAVLink LOCAL_NED position (m from home)."""
    return ned_to_nwu((north_m, east_m, down_m))


# -- target sources ------------------------------------------------------------------------------
def local_ned_target(north_m: float, east_m: float, down_m: float, yaw_frd_rad: float | None) -> Target:
    """``SET_POSITION_TARGET_LOCAL_NED``: NED position, FRD yaw (None: keep the heading)."""
    x, y, z = position_of_local_ned(north_m, east_m, down_m)
    return Target(x, y, z, yaw_of_frd(yaw_frd_rad) if yaw_frd_rad is not None else None)


def global_target(home: Home, lat_deg: float, lon_deg: float, alt_m: float, relative: bool, yaw_frd_rad: float | None) -> Target:
    """``SET_POSITION_TARGET_GLOBAL_INT``: global position, FRD yaw (None or NaN: keep the heading)."""
    x, y, z = position_of_global(home, lat_deg, lon_deg, alt_m, relative)
    yaw = yaw_of_frd(yaw_frd_rad) if yaw_frd_rad is not None and _isfinite(yaw_frd_rad) else None
    return Target(x, y, z, yaw)


def reposition_target(home: Home, lat_deg: float, lon_deg: float, alt_m: float, relative: bool, yaw_deg: float) -> Target:
    """``MAV_CMD_DO_REPOSITION``: global position, compass heading in degrees (NaN: keep)."""
    x, y, z = position_of_global(home, lat_deg, lon_deg, alt_m, relative)
    return Target(x, y, z, yaw_of_compass_deg(yaw_deg) if _isfinite(yaw_deg) else None)


def plan_step_yaw(step: PlanStep) -> float | None:
    """FLU yaw of a plan step's compass heading (None: none given)."""
    return yaw_of_compass_deg(step.yaw_deg) if step.yaw_deg is not None else None


def plan_step_target(step: PlanStep) -> Target:
    """A ``goto`` plan step: north/east/altitude (m; missing values 0) and compass heading."""
    x, y, z = ned_to_nwu((float(step.north_m or 0.0), float(step.east_m or 0.0), -float(step.alt_m or 0.0)))
    return Target(x, y, z, plan_step_yaw(step))


def mission_item_relative(item: MissionItem) -> bool:
    """The item's altitude is above home (else AMSL)."""
    return item.frame in RELATIVE_FRAMES


def mission_item_yaw(item: MissionItem) -> float | None:
    """FLU yaw of a ``NAV_WAYPOINT``'s param4 compass heading (None: NaN, or another command)."""
    return yaw_of_compass_deg(item.param4) if _isfinite(item.param4) and item.command == CMD_WAYPOINT else None


def mission_item_altitude(home: Home, item: MissionItem) -> float:
    """z (up, above home) of the item's altitude, in its frame."""
    return altitude_above_home(home, item.z, mission_item_relative(item))


def mission_item_position(home: Home, item: MissionItem) -> tuple[float, float, float]:
    """Paper-frame position of the item's latitude/longitude/altitude."""
    return position_of_global(home, item.lat_deg, item.lon_deg, item.z, mission_item_relative(item))
