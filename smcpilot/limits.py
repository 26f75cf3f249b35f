"""Where a target may be: the one rule every target source passes, on the vehicle and the ground.

A target (a set-point, a take-off altitude, a mission item, a plan step) is flown only if it is

- **finite** (no NaN, no infinity);
- **not below ground**: altitude above home >= 0 m (a take-off: >= :data:`TAKEOFF_ALT_MIN_M`);
- **inside the geofence** when ``FENCE_ENABLE`` is 1 (ArduPilot's parameter names): within
  ``FENCE_RADIUS`` metres of home horizontally and at most ``FENCE_ALT_MAX`` metres above it (a
  cylinder around home). With the fence off the absolute limits :data:`HARD_LIMITS` still hold
  (the largest values the two parameters accept), so no finite absurdity (1e30 m) is ever flown.

The flight controller applies :func:`target_refusal` with its own fence parameters; mission files
(``ground/missions``) and the command line check against :data:`HARD_LIMITS` before anything is
sent (they cannot know the vehicle's fence), so ground and vehicle never disagree on what is
impossible, and the vehicle has the last word on its fence. Frame: metres north/east of home,
altitude up above home.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = [
    "Fence",
    "DEFAULT_FENCE",
    "HARD_LIMITS",
    "FENCE_RADIUS_RANGE_M",
    "FENCE_ALT_MAX_RANGE_M",
    "TAKEOFF_ALT_MIN_M",
    "target_refusal",
    "takeoff_refusal",
]

#: the range of ``FENCE_RADIUS`` (m) and ``FENCE_ALT_MAX`` (m) the parameters accept.
FENCE_RADIUS_RANGE_M = (10.0, 10_000.0)
FENCE_ALT_MAX_RANGE_M = (1.0, 500.0)
#: the lowest take-off altitude above home, m (lower is "stay on the ground").
TAKEOFF_ALT_MIN_M = 0.5


@dataclass(frozen=True)
class Fence:
    """A cylinder around home: ``radius_m`` horizontally, ``alt_max_m`` up (``FENCE_*``)."""

    #: ``FENCE_ENABLE``: 1 checks targets against this fence; 0 only against :data:`HARD_LIMITS`.
    enabled: bool = True
    #: ``FENCE_RADIUS``: largest horizontal distance from home, m (ArduPilot's default 300).
    radius_m: float = 300.0
    #: ``FENCE_ALT_MAX``: largest altitude above home, m (ArduPilot's default 100).
    alt_max_m: float = 100.0


#: the fence a vehicle starts with (on, ArduPilot's default radius and altitude).
DEFAULT_FENCE = Fence()
#: what holds with the fence off, and what the ground checks before sending.
HARD_LIMITS = Fence(True, FENCE_RADIUS_RANGE_M[1], FENCE_ALT_MAX_RANGE_M[1])


def _limits(fence: Fence) -> tuple[float, float, str, str]:
    if fence.enabled and fence != HARD_LIMITS:
        return fence.radius_m, fence.alt_max_m, "fence FENCE_RADIUS", "fence FENCE_ALT_MAX"
    return HARD_LIMITS.radius_m, HARD_LIMITS.alt_max_m, "the absolute limit", "the absolute limit"


def target_refusal(north_m: float, east_m: float, alt_m: float, fence: Fence = DEFAULT_FENCE) -> str | None:
    """Why a target at ``north_m``/``east_m`` of home, ``alt_m`` above home may not be flown, or
    None. The reason is one sentence for a ``STATUSTEXT`` (the caller prefixes the source)."""
    if not (math.isfinite(north_m) and math.isfinite(east_m) and math.isfinite(alt_m)):
        return "position is not a finite number"
    if alt_m < 0.0:
        return f"altitude {alt_m:.4g} m is below ground (home is 0 m)"
    radius, alt_max, r_name, a_name = _limits(fence)
    if alt_m > alt_max:
        return f"altitude {alt_m:.6g} m is above {a_name} {alt_max:g} m"
    dist = math.hypot(north_m, east_m)
    if dist > radius:
        return f"{dist:.6g} m from home is outside {r_name} {radius:g} m"
    return None


def takeoff_refusal(alt_m: float, fence: Fence = DEFAULT_FENCE) -> str | None:
    """Why a take-off to ``alt_m`` above home may not be flown, or None."""
    if not math.isfinite(alt_m):
        return "altitude is not a finite number"
    if alt_m < TAKEOFF_ALT_MIN_M:
        return f"altitude {alt_m:g} m is below the lowest take-off altitude {TAKEOFF_ALT_MIN_M:g} m"
    _, alt_max, _, a_name = _limits(fence)
    if alt_m > alt_max:
        return f"altitude {alt_m:.6g} m is above {a_name} {alt_max:g} m"
    return None
