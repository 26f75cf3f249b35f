"""Global (WGS-84 latitude/longitude) <-> local NED positions around a home point.

A flat-earth (equirectangular) approximation around home: good to centimetres within a few
kilometres, which is what a SITL field needs. The local frame is MAVLink's LOCAL_NED: x north,
y east, z down, metres, origin at home (altitude ``alt_m`` above mean sea level).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from smcpilot.errors import ConfigError

#: WGS-84 equatorial radius, m (the flat-earth scale factor).
EARTH_RADIUS_M = 6378137.0


@dataclass(frozen=True)
class Home:
    """The origin of the local frame: latitude/longitude in degrees, altitude AMSL in metres."""

    lat_deg: float = -35.363261
    lon_deg: float = 149.165230
    alt_m: float = 584.0

    def __post_init__(self) -> None:
        for name, lo, hi in (("lat_deg", -89.0, 89.0), ("lon_deg", -180.0, 180.0), ("alt_m", -500.0, 9000.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
                raise ConfigError(f"home {name} must be a number in [{lo:g}, {hi:g}], got {v!r}")

    @classmethod
    def parse(cls, text: str) -> Home:
        """``"LAT,LON,ALT"`` (degrees, degrees, metres AMSL)."""
        try:
            lat, lon, alt = (float(v) for v in text.split(","))
        except ValueError:
            raise ConfigError(f"home must be LAT,LON,ALT (degrees, degrees, metres), got {text!r}") from None
        return cls(lat, lon, alt)


def global_to_ned(home: Home, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> tuple[float, float, float]:
    """(north, east, down) m of a global point relative to home."""
    d_lat = math.radians(lat_deg - home.lat_deg)
    d_lon = math.radians(_wrap180(lon_deg - home.lon_deg))
    north = d_lat * EARTH_RADIUS_M
    east = d_lon * EARTH_RADIUS_M * math.cos(math.radians(home.lat_deg))
    return north, east, home.alt_m - alt_amsl_m


def ned_to_global(home: Home, north_m: float, east_m: float, down_m: float) -> tuple[float, float, float]:
    """(lat deg, lon deg, alt AMSL m) of a local NED point."""
    lat = home.lat_deg + math.degrees(north_m / EARTH_RADIUS_M)
    lon = home.lon_deg + math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(home.lat_deg))))
    return lat, _wrap180(lon), home.alt_m - down_m


def _wrap180(deg: float) -> float:
    return (deg + 180.0) % 360.0 - 180.0
