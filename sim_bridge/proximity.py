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

import numpy as np


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
    _iu: tuple[np.ndarray, np.ndarray] | None = None

    def __post_init__(self) -> None:
        if not self.per_vehicle_min_m:
            self.per_vehicle_min_m = [math.inf] * self.count

    def check(self, t_s: float, positions_ned_m: Sequence[tuple[float, float, float]]) -> list[tuple[str, int, int, float]]:
        """Update with the vehicles' positions at ``t_s``; the new events: ("separation" or
        "contact", i, j, distance m), i < j, pair by pair in the order (0, 1), (0, 2) ... (1, 2) ....

        Every pair's distance at once with numpy: ``sqrt(dx * dx + dy * dy + dz * dz)``, the same IEEE
        operations in the same order as that expression in Python, so the same values (tested). A
        NaN distance (a position that is not a number) counts as no closer than any other."""
        n = len(positions_ned_m)
        if n < 2:
            return []
        pos = np.array(positions_ned_m, dtype=np.float64)
        x, y, z = pos[:, 0], pos[:, 1], pos[:, 2]
        dx, dy, dz = x[:, None] - x[None, :], y[:, None] - y[None, :], z[:, None] - z[None, :]
        d = np.sqrt(dx * dx + dy * dy + dz * dz)
        d[np.isnan(d)] = np.inf
        np.fill_diagonal(d, np.inf)
        per = self.per_vehicle_min_m
        for i, row_min in enumerate(d.min(axis=1).tolist()):
            if row_min < per[i]:
                per[i] = row_min
        iu = self._pairs(n)
        dist = d[iu]
        k = int(np.argmin(dist))  # (the first pair of the smallest distance, as a pair-by-pair scan finds it)
        if dist[k] < self.min_separation_m:
            self.min_separation_m = float(dist[k])
            self.min_at_s, self.min_pair = t_s, (int(iu[0][k]), int(iu[1][k]))
        sep, contact = self.separation_m, self.contact_m
        close = self._close
        for pair in [p for p in close if not d[p] < sep]:  # apart again: the next approach is a new event
            close.discard(pair)
        out: list[tuple[str, int, int, float]] = []
        for k in np.flatnonzero(dist < max(sep, contact)).tolist():
            i, j = int(iu[0][k]), int(iu[1][k])
            dk = float(dist[k])
            pair = (i, j)
            if dk < sep and pair not in close:
                close.add(pair)
                self.events.append((t_s, i, j, dk))
                out.append(("separation", i, j, dk))
            if dk < contact and pair not in self._touched:
                self._touched.add(pair)
                self.contacts.append((t_s, i, j, dk))
                out.append(("contact", i, j, dk))
        return out

    def _pairs(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The pairs i < j of ``n`` vehicles, row by row (kept: ``n`` is the swarm's)."""
        if self._iu is None or len(self._iu[0]) != n * (n - 1) // 2:
            self._iu = np.triu_indices(n, 1)
        return self._iu

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
