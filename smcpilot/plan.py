"""Timed set-point plans: a deterministic script of take-off, go-to and land in simulated time.

A plan is a TOML file of ``[[step]]`` tables, executed by the flight controller itself at the
given simulated times (so a lockstep run is reproducible bit for bit, whatever the wall clock
does)::

    [[step]]
    t_s = 0.0
    action = "takeoff"     # arm (if disarmed) and climb to alt_m over the current position
    alt_m = 3.0

    [[step]]
    t_s = 12.0
    action = "goto"        # fly to a position; yaw_deg optional (compass: 0 north, 90 east)
    north_m = 4.0
    east_m = -3.0
    alt_m = 3.0
    yaw_deg = 170.0

    [[step]]
    t_s = 30.0
    action = "land"        # descend, disarm on touchdown

Coordinates are the MAVLink local frame (north, east; altitude up from the start point);
the FC converts them to its internal frame with :mod:`smcpilot.frames`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from smcpilot.errors import ConfigError
from smcpilot.tomlfile import read_toml

ACTIONS = ("takeoff", "goto", "land", "disarm")
_KEYS = {
    "takeoff": ({"t_s", "action", "alt_m"}, {"yaw_deg"}),
    "goto": ({"t_s", "action", "north_m", "east_m", "alt_m"}, {"yaw_deg"}),
    "land": ({"t_s", "action"}, set()),
    "disarm": ({"t_s", "action"}, set()),
}


class PlanError(ConfigError):
    """A plan file is unreadable or a step is invalid (the message names the step and key)."""


@dataclass(frozen=True)
class PlanStep:
    """One timed action; positions in the MAVLink local frame (north, east, altitude up)."""

    t_s: float
    action: str
    north_m: float | None = None
    east_m: float | None = None
    alt_m: float | None = None
    yaw_deg: float | None = None


def parse_plan(doc: dict[str, Any], source: str = "plan") -> tuple[PlanStep, ...]:
    steps = doc.get("step")
    extra = sorted(set(doc) - {"step", "name", "description"})
    if extra:
        raise PlanError(f"{source}: unknown top-level key {extra[0]!r} (expected [[step]] tables)")
    if not isinstance(steps, list) or not steps:
        raise PlanError(f"{source}: no [[step]] tables")
    out: list[PlanStep] = []
    last_t = -math.inf
    for i, st in enumerate(steps, start=1):
        where = f"{source}: step {i}"
        if not isinstance(st, dict):
            raise PlanError(f"{where}: not a table")
        action = st.get("action")
        if action not in ACTIONS:
            raise PlanError(f"{where}: action must be one of {', '.join(ACTIONS)}, got {action!r}")
        required, optional = _KEYS[action]
        missing = sorted(required - set(st))
        if missing:
            raise PlanError(f"{where} ({action}): missing key {missing[0]!r}")
        unknown = sorted(set(st) - required - optional)
        if unknown:
            raise PlanError(f"{where} ({action}): unknown key {unknown[0]!r}")
        vals: dict[str, float] = {}
        for k, v in st.items():
            if k == "action":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise PlanError(f"{where}: {k} must be a finite number, got {v!r}")
            vals[k] = float(v)
        if vals["t_s"] < 0.0 or vals["t_s"] < last_t:
            raise PlanError(f"{where}: t_s must be >= 0 and not earlier than the previous step")
        if "alt_m" in vals and not 0.0 <= vals["alt_m"] <= 500.0:
            raise PlanError(f"{where}: alt_m must lie in [0, 500] m, got {vals['alt_m']}")
        last_t = vals["t_s"]
        out.append(PlanStep(action=action, **vals))
    return tuple(out)


def load_plan(path: str | Path) -> tuple[PlanStep, ...]:
    p = Path(path)
    return parse_plan(read_toml(p, PlanError, "plan"), str(p))


def plan_duration_s(steps: Iterable[PlanStep]) -> float:
    return max((s.t_s for s in steps), default=0.0)


class PlanRunner:
    """Hands out the plan's steps as simulated time reaches them."""

    def __init__(self, steps: Iterable[PlanStep]) -> None:
        self.steps = tuple(steps)
        self._i = 0

    def due(self, t_s: float) -> list[PlanStep]:
        out: list[PlanStep] = []
        steps = self.steps
        while self._i < len(steps) and steps[self._i].t_s <= t_s + 1e-9:
            out.append(steps[self._i])
            self._i += 1
        return out

    @property
    def finished(self) -> bool:
        return self._i >= len(self.steps)

    @property
    def next_t_s(self) -> float:
        """When the next step is due (s from the first tick; ``inf``: none left)."""
        return self.steps[self._i].t_s if self._i < len(self.steps) else math.inf
