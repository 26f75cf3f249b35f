"""Expectations: the ``[[expect]]`` kinds of a mission file and their evaluation on a
:class:`~ground.missions.record.FlightRecord` (see :mod:`ground.missions` for what each kind
checks). Times are mission time, simulated seconds since the mission started; positions
north/east/altitude-up metres from home; angles degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from ground.missions.record import _hold
from smcpilot.geo import Home

if TYPE_CHECKING:
    from ground.missions.record import FlightRecord
    from ground.missions.schema import Mission

__all__ = [
    "CHANNELS",
    "EXPECTATION_KINDS",
    "LANDED_MAX_ALT_M",
    "ChiHat",
    "Expectation",
    "ExpectationResult",
    "FinalPosition",
    "Landed",
    "MaxErrorAfter",
    "MaxTilt",
    "Reach",
    "evaluate",
]

#: "On the ground" for the ``landed`` expectation: altitude below this, m.
LANDED_MAX_ALT_M = 0.3
#: Channel names of χ̂, in the controller's order.
CHANNELS: tuple[str, ...] = ("phi", "theta", "psi", "z")


@dataclass(frozen=True)
class ExpectationResult:
    """The verdict on one expectation.

    ``measured`` / ``limit`` are the headline numbers in ``unit`` (None when there is nothing to
    measure), ``detail`` says what was measured and when, ``source`` where the data came from
    (``"log"``: the FC's .tlog; ``"telemetry"``: what the ground link received).
    """

    number: int
    kind: str
    description: str
    passed: bool
    measured: float | None
    limit: float | None
    unit: str
    detail: str
    source: str
    extra: dict[str, Any] = field(default_factory=dict)
    #: the measured value as printed, e.g. ``"23.27°"``, ``"range [0.500, 0.566]"``.
    measured_text: str = "n/a"
    #: the limit as printed, e.g. ``"<= 30°"``, ``"within 0.3 m by 15 s"``.
    limit_text: str = ""
    #: what was measured, e.g. ``"item 3"`` (may be empty).
    subject: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {
            "number": self.number,
            "kind": self.kind,
            "description": self.description,
            "passed": self.passed,
            "measured": _json_num(self.measured),
            "limit": _json_num(self.limit),
            "unit": self.unit,
            "measured_text": self.measured_text,
            "limit_text": self.limit_text,
            "detail": self.detail,
            "source": self.source,
            **{k: _json_value(v) for k, v in self.extra.items()},
        }


@dataclass(frozen=True)
class Expectation:
    """Base of the ``[[expect]]`` kinds; ``number`` is the 1-based place in the file."""

    number: int
    kind: ClassVar[str] = ""
    #: (required keys, optional keys) besides "kind".
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset(), frozenset())

    def describe(self) -> str:  # pragma: no cover - every kind overrides it
        return self.kind

    def limit_text(self) -> str:  # pragma: no cover - every kind overrides it
        return ""

    def subject(self) -> str:
        """What is measured, for the report line (empty when the kind says it all)."""
        return ""

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:  # pragma: no cover
        raise NotImplementedError

    def _result(self, rec: FlightRecord, passed: bool, measured: float | None, limit: float | None, unit: str, detail: str,
                *, measured_text: str | None = None, **extra: Any) -> ExpectationResult:  # fmt: skip
        if measured_text is None:
            measured_text = "n/a" if measured is None else _with_unit(measured, unit)
        return ExpectationResult(self.number, self.kind, self.describe(), passed, measured, limit, unit, detail, rec.source, extra,
                                 measured_text, self.limit_text(), self.subject())  # fmt: skip


def _with_unit(v: float, unit: str) -> str:
    if unit == "deg":
        return f"{v:.2f}°"
    if unit == "s":
        return f"{v:.2f} s"
    return f"{v:.3f}" + (f" {unit}" if unit else "")


@dataclass(frozen=True)
class Reach(Expectation):
    """Came within ``within_m`` of item ``item``'s target by mission time ``by_s``."""

    item: int = 0
    within_m: float = 0.0
    by_s: float = 0.0
    kind: ClassVar[str] = "reach"
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset({"item", "within_m", "by_s"}), frozenset())

    def describe(self) -> str:
        return f"reach item {self.item} within {self.within_m:g} m by {self.by_s:g} s"

    def limit_text(self) -> str:
        return f"within {self.within_m:g} m by {self.by_s:g} s"

    def subject(self) -> str:
        return f"item {self.item}"

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:
        it = mission.items[self.item - 1]
        t, n, e, alt = rec.pos_t, rec.north, rec.east, rec.alt
        ne = it.local_ne(home)
        if it.type == "takeoff":
            assert it.alt_m is not None
            dist, what = np.abs(alt - it.alt_m), f"altitude {it.alt_m:g} m (vertical distance)"
        elif it.type == "land":
            assert ne is not None
            dist, what = np.hypot(n - ne[0], e - ne[1]), f"N {ne[0]:.2f} E {ne[1]:.2f} (horizontal distance)"
        else:
            assert ne is not None and it.alt_m is not None
            dist = np.sqrt((n - ne[0]) ** 2 + (e - ne[1]) ** 2 + (alt - it.alt_m) ** 2)
            what = f"N {ne[0]:.2f} E {ne[1]:.2f} alt {it.alt_m:g} m (3-D distance)"
        start = rec.item_start_s.get(self.item)
        since = f"item current from {start:.2f} s" if start is not None else "item never became current: from mission start"
        t_from = start if start is not None else 0.0
        window = (t >= t_from) & (t <= self.by_s)
        if not window.any():
            return self._result(rec, False, None, self.within_m, "m", f"no position samples in [{t_from:.2f}, {self.by_s:g}] s ({since})",
                                item_start_s=start)  # fmt: skip
        k = int(np.argmin(np.where(window, dist, np.inf)))
        closest = float(dist[k])
        inside = np.flatnonzero(window & (dist <= self.within_m))
        after = np.flatnonzero((t >= t_from) & (dist <= self.within_m))
        if inside.size:
            first = float(t[inside[0]])
            detail = f"first within {self.within_m:g} m of {what} at {first:.2f} s ({since}); closest {closest:.3f} m at {t[k]:.2f} s"
        elif after.size:
            first = float(t[after[0]])
            detail = f"closest by {self.by_s:g} s was {closest:.3f} m at {t[k]:.2f} s; within {self.within_m:g} m only at {first:.2f} s ({since})"
        else:
            first = None
            detail = f"closest by {self.by_s:g} s was {closest:.3f} m at {t[k]:.2f} s (target {what}; {since}); never within {self.within_m:g} m"
        if inside.size:
            when = f", within at {first:.2f} s"
        elif first is not None:
            when = f" by {self.by_s:g} s (within only at {first:.2f} s)"
        else:
            when = ""
        return self._result(rec, bool(inside.size), closest, self.within_m, "m", detail, first_within_s=first, closest_at_s=float(t[k]),
                            item_start_s=start, measured_text=f"closest {closest:.3f} m{when}")  # fmt: skip


@dataclass(frozen=True)
class MaxTilt(Expectation):
    """The tilt stays at or below ``max_deg`` during armed flight."""

    max_deg: float = 0.0
    kind: ClassVar[str] = "max_tilt"
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset({"max_deg"}), frozenset())

    def describe(self) -> str:
        return f"tilt <= {self.max_deg:g}°"

    def limit_text(self) -> str:
        return f"<= {self.max_deg:g}°"

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:
        armed = rec.armed_at(rec.tilt_t)
        tilt = np.where(armed & np.isfinite(rec.tilt_deg), rec.tilt_deg, -np.inf)
        if not np.isfinite(tilt).any():
            return self._result(rec, False, None, self.max_deg, "deg", "no attitude samples during armed flight")
        k = int(np.argmax(tilt))
        worst = float(tilt[k])
        return self._result(rec, worst <= self.max_deg, worst, self.max_deg, "deg", f"largest tilt {worst:.2f}° at {rec.tilt_t[k]:.2f} s",
                            at_s=float(rec.tilt_t[k]))  # fmt: skip


@dataclass(frozen=True)
class ChiHat(Expectation):
    """Every χ̂ of ``channels`` stays within [``min``, ``max``] during armed flight."""

    max: float = 0.0
    min: float | None = None
    channels: tuple[str, ...] = CHANNELS
    kind: ClassVar[str] = "chi_hat"
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset({"max"}), frozenset({"min", "channels"}))

    def describe(self) -> str:
        lo = f"{self.min:g} <= " if self.min is not None else ""
        which = "" if self.channels == CHANNELS else f" ({', '.join(self.channels)})"
        return f"{lo}χ̂ <= {self.max:g}{which}"

    def limit_text(self) -> str:
        return f"within [{self.min:g}, {self.max:g}]" if self.min is not None else f"<= {self.max:g}"

    def subject(self) -> str:
        return "" if self.channels == CHANNELS else ", ".join(self.channels)

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:
        armed = rec.armed_at(rec.chi_t)
        ranges: dict[str, list[float]] = {}
        for c in self.channels:
            col = rec.chi[:, CHANNELS.index(c)] if rec.chi.size else np.zeros(0)
            v = col[armed & np.isfinite(col)] if col.size else col
            if v.size:
                ranges[c] = [float(v.min()), float(v.max())]
        if not ranges:
            return self._result(rec, False, None, self.max, "", "no χ̂ in the record (a controller without adaptive gains?)")
        hi = max(r[1] for r in ranges.values())
        lo = min(r[0] for r in ranges.values())
        ok = hi <= self.max and (self.min is None or lo >= self.min)
        missing = [c for c in self.channels if c not in ranges]
        detail = ", ".join(f"{c} [{r[0]:.3f}, {r[1]:.3f}]" for c, r in ranges.items())
        if missing:
            ok = False
            detail += f"; no χ̂ for {', '.join(missing)}"
        return self._result(rec, ok, hi, self.max, "", f"range per channel: {detail}", min_measured=lo, ranges=ranges,
                            measured_text=f"range [{lo:.3f}, {hi:.3f}]")  # fmt: skip


@dataclass(frozen=True)
class FinalPosition(Expectation):
    """The last position is within ``within_m`` of (north, east[, alt])."""

    north_m: float = 0.0
    east_m: float = 0.0
    within_m: float = 0.0
    alt_m: float | None = None
    kind: ClassVar[str] = "final_position"
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset({"north_m", "east_m", "within_m"}), frozenset({"alt_m"}))

    def describe(self) -> str:
        alt = f" alt {self.alt_m:g}" if self.alt_m is not None else ""
        return f"end within {self.within_m:g} m of N {self.north_m:g} E {self.east_m:g}{alt}"

    def limit_text(self) -> str:
        return f"<= {self.within_m:g} m"

    def subject(self) -> str:
        return f"from N {self.north_m:g} E {self.east_m:g}" + (f" alt {self.alt_m:g}" if self.alt_m is not None else "")

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:
        if not rec.pos_t.size:
            return self._result(rec, False, None, self.within_m, "m", "no position samples")
        n, e, a = float(rec.north[-1]), float(rec.east[-1]), float(rec.alt[-1])
        d = math.hypot(n - self.north_m, e - self.east_m)
        if self.alt_m is not None:
            d = math.hypot(d, a - self.alt_m)
        kind = "3-D" if self.alt_m is not None else "horizontal"
        return self._result(rec, d <= self.within_m, d, self.within_m, "m",
                            f"ended at N {n:.3f} E {e:.3f} alt {a:.3f} m ({rec.pos_t[-1]:.2f} s): {kind} distance {d:.3f} m",
                            final_ned_alt=[n, e, a])  # fmt: skip


@dataclass(frozen=True)
class Landed(Expectation):
    """Disarmed on the ground at the end (by mission time ``by_s`` if given)."""

    by_s: float | None = None
    kind: ClassVar[str] = "landed"
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset(), frozenset({"by_s"}))

    def describe(self) -> str:
        return "landed and disarmed" + (f" by {self.by_s:g} s" if self.by_s is not None else "")

    def limit_text(self) -> str:
        return f"disarmed on the ground by {self.by_s:g} s" if self.by_s is not None else "disarmed on the ground at the end"

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:
        if not rec.armed_t.size or not rec.pos_t.size:
            return self._result(rec, False, None, self.by_s, "s", "no armed/position record")
        alt = float(rec.alt[-1])
        disarmed = not bool(rec.armed[-1])
        armed_idx = np.flatnonzero(rec.armed)
        t_disarm = None
        if disarmed and armed_idx.size and armed_idx[-1] + 1 < rec.armed_t.size:
            t_disarm = float(rec.armed_t[armed_idx[-1] + 1])
        ok = disarmed and alt < LANDED_MAX_ALT_M
        if not disarmed:
            detail = f"still armed at the end ({rec.armed_t[-1]:.2f} s), altitude {alt:.2f} m"
        else:
            when = f"disarmed at {t_disarm:.2f} s" if t_disarm is not None else "never armed"
            detail = f"{when}, final altitude {alt:.3f} m" + ("" if alt < LANDED_MAX_ALT_M else f" (not < {LANDED_MAX_ALT_M:g} m)")
            if t_disarm is None:
                ok = False
        if ok and self.by_s is not None and (t_disarm is None or t_disarm > self.by_s):
            ok = False
            detail += f"; later than {self.by_s:g} s"
        measured = ("still armed" if not disarmed else f"disarmed at {t_disarm:.2f} s" if t_disarm is not None else "never armed")
        return self._result(rec, ok, t_disarm, self.by_s, "s", detail, final_alt_m=alt, measured_text=f"{measured}, altitude {alt:.2f} m")


@dataclass(frozen=True)
class MaxErrorAfter(Expectation):
    """Horizontal error to the set-point stays below ``max_m`` from ``t_s`` (to ``until_s``)."""

    t_s: float = 0.0
    max_m: float = 0.0
    until_s: float | None = None
    kind: ClassVar[str] = "max_error_after"
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset({"t_s", "max_m"}), frozenset({"until_s"}))

    def describe(self) -> str:
        until = f" to {self.until_s:g} s" if self.until_s is not None else ""
        return f"horizontal error < {self.max_m:g} m from {self.t_s:g} s{until}"

    def limit_text(self) -> str:
        return f"< {self.max_m:g} m"

    def subject(self) -> str:
        return f"{self.t_s:g}-{self.until_s:g} s" if self.until_s is not None else f"from {self.t_s:g} s"

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:
        t = rec.sp_t
        end = self.until_s if self.until_s is not None else math.inf
        if not t.size:
            return self._result(rec, False, None, self.max_m, "m", "no position set-point in the record")
        n = _hold(rec.pos_t, rec.north, t)
        e = _hold(rec.pos_t, rec.east, t)
        err = np.hypot(n - rec.sp_north, e - rec.sp_east)
        mask = (t >= self.t_s) & (t <= end) & rec.armed_at(t) & np.isfinite(err)
        if not mask.any():
            return self._result(rec, False, None, self.max_m, "m", f"no armed flight with a set-point in [{self.t_s:g}, {end:g}] s")
        k = int(np.argmax(np.where(mask, err, -np.inf)))
        worst = float(err[k])
        rms = float(np.sqrt(np.mean(err[mask] ** 2)))
        span = f"{t[mask][0]:.2f}-{t[mask][-1]:.2f} s"
        return self._result(rec, worst < self.max_m, worst, self.max_m, "m",
                            f"largest {worst:.3f} m at {t[k]:.2f} s, RMS {rms:.3f} m over {span} (set-point: {rec.sp_source})",
                            rms_m=rms, at_s=float(t[k]))  # fmt: skip


_EXPECTATIONS: dict[str, type[Expectation]] = {
    cls.kind: cls for cls in (Reach, MaxTilt, ChiHat, FinalPosition, Landed, MaxErrorAfter)
}
EXPECTATION_KINDS: tuple[str, ...] = tuple(_EXPECTATIONS)


def evaluate(mission: Mission, rec: FlightRecord, home: Home | None) -> list[ExpectationResult]:
    """Every expectation of ``mission`` on ``rec`` (``home`` converts lat/lon items)."""
    return [exp.evaluate(rec, mission, home) for exp in mission.expectations]


def _json_num(v: Any) -> Any:
    if v is None:
        return None
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    f = float(v)
    return f if math.isfinite(f) else None


def _json_value(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _json_value(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_json_value(x) for x in v]
    if isinstance(v, (str, type(None))):
        return v
    return _json_num(v)
