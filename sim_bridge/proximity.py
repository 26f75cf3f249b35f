"""How close the vehicles of a swarm come to each other: the minimum separation, events, contacts.

Checked once per control period on the plants' true positions (NED, m, in the swarm's frame:
each vehicle's local position plus its spawn offset). Two vehicles whose centres come closer than
``separation_m`` make one event (said again only after they have been apart again); closer than
``contact_m`` they touch: a contact, once per pair (the simulator crashes both: their motors stop).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field


@dataclass
class Proximity:
    """Separation bookkeeping for ``count`` vehicles (see the module docstring)."""

    count: int
    separation_m: float
    contact_m: float
    #: the smallest separation seen (m), when (simulated s) and between which vehicles (indices).
    min_separation_m: float = math.inf
    min_at_s: float | None = None
    min_pair: tuple[int, int] | None = None
    #: each vehicle's smallest separation from any other (m).
    per_vehicle_min_m: list[float] = field(default_factory=list)
    #: (t_s, i, j, distance_m) of every separation event and every contact.
    events: list[tuple[float, int, int, float]] = field(default_factory=list)
    contacts: list[tuple[float, int, int, float]] = field(default_factory=list)
    _close: set[tuple[int, int]] = field(default_factory=set)
    _touched: set[tuple[int, int]] = field(default_factory=set)

    def __post_init__(self) -> None:
        if not self.per_vehicle_min_m:
            self.per_vehicle_min_m = [math.inf] * self.count

    def check(self, t_s: float, positions_ned_m: Sequence[tuple[float, float, float]]) -> list[tuple[str, int, int, float]]:
        """Update with the vehicles' positions at ``t_s``; the new events: ("separation" or
        "contact", i, j, distance m), i < j."""
        out: list[tuple[str, int, int, float]] = []
        n = len(positions_ned_m)
        per = self.per_vehicle_min_m
        sep, contact = self.separation_m, self.contact_m
        best = self.min_separation_m
        for i in range(n):
            xi, yi, zi = positions_ned_m[i]
            for j in range(i + 1, n):
                xj, yj, zj = positions_ned_m[j]
                d = math.sqrt((xi - xj) ** 2 + (yi - yj) ** 2 + (zi - zj) ** 2)
                if d < per[i]:
                    per[i] = d
                if d < per[j]:
                    per[j] = d
                if d < best:
                    best = d
                    self.min_at_s, self.min_pair = t_s, (i, j)
                pair = (i, j)
                if d < sep:
                    if pair not in self._close:
                        self._close.add(pair)
                        self.events.append((t_s, i, j, d))
                        out.append(("separation", i, j, d))
                elif pair in self._close:
                    self._close.discard(pair)
                if d < contact and pair not in self._touched:
                    self._touched.add(pair)
                    self.contacts.append((t_s, i, j, d))
                    out.append(("contact", i, j, d))
        self.min_separation_m = best
        return out

    def summary(self, sysids: Sequence[int]) -> dict:
        """For SIM_SUMMARY: the minimum separation, per vehicle (by system id), events and contacts."""

        def finite(v: float) -> float | None:
            return v if math.isfinite(v) else None

        def rows(items: list[tuple[float, int, int, float]]) -> list[dict]:
            return [{"t_s": t, "vehicles": [sysids[i], sysids[j]], "distance_m": d} for t, i, j, d in items]

        return {
            "separation_m": self.separation_m,
            "contact_m": self.contact_m,
            "min_separation_m": finite(self.min_separation_m),
            "min_at_s": self.min_at_s,
            "min_pair": None if self.min_pair is None else [sysids[self.min_pair[0]], sysids[self.min_pair[1]]],
            "per_vehicle_min_m": {str(s): finite(v) for s, v in zip(sysids, self.per_vehicle_min_m)},
            "events": rows(self.events),
            "contacts": rows(self.contacts),
        }
