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
from typing import Any

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
    #: :func:`pair_distances` compiled (:func:`compiled_pair_distances`; None: numpy does it).
    kernel: Any = None
    _d: np.ndarray | None = None
    _row_min: np.ndarray | None = None

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
        per = self.per_vehicle_min_m
        sep, contact = self.separation_m, self.contact_m
        close = self._close
        kernel = self.kernel
        if kernel is not None:  # compiled: the same distances, mins and first smallest pair, one call
            d, row_min = self._d_rows(n)
            best, bi, bj, below = kernel(pos, d, row_min, max(sep, contact))
            for i, m in enumerate(row_min.tolist()):
                if m < per[i]:
                    per[i] = m
            if best < self.min_separation_m:
                self.min_separation_m = best
                self.min_at_s, self.min_pair = t_s, (bi, bj)
            if not below and not close:
                return []
            iu = self._pairs(n)
            dist = d[iu]
        else:
            x, y, z = pos[:, 0], pos[:, 1], pos[:, 2]
            dx, dy, dz = x[:, None] - x[None, :], y[:, None] - y[None, :], z[:, None] - z[None, :]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            d[np.isnan(d)] = np.inf
            np.fill_diagonal(d, np.inf)
            for i, row_min_i in enumerate(d.min(axis=1).tolist()):
                if row_min_i < per[i]:
                    per[i] = row_min_i
            iu = self._pairs(n)
            dist = d[iu]
            k = int(np.argmin(dist))  # (the first pair of the smallest distance, as a pair-by-pair scan finds it)
            if dist[k] < self.min_separation_m:
                self.min_separation_m = float(dist[k])
                self.min_at_s, self.min_pair = t_s, (int(iu[0][k]), int(iu[1][k]))
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

    def _d_rows(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The compiled kernel's distance matrix and row minimums (kept: ``n`` is the swarm's)."""
        if self._d is None or self._d.shape[0] != n:
            self._d = np.empty((n, n))
            self._row_min = np.empty(n)
        assert self._row_min is not None
        return self._d, self._row_min

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


def pair_distances(pos, d, row_min, thr):  # type: ignore[no-untyped-def]
    """Every pair's distance of the positions ``pos`` (n x 3) into ``d`` (n x n; inf on the diagonal
    and for a NaN distance), each vehicle's smallest into ``row_min``: ``sqrt(dx * dx + dy * dy + dz *
    dz)`` as :meth:`Proximity.check`'s numpy computes it, the same values. Returns (the smallest
    distance, the first pair (i, j), i < j, in the order (0, 1), (0, 2) ... (1, 2) ... that has it,
    how many pairs are closer than ``thr``)."""
    n = pos.shape[0]
    best = math.inf
    bi = 0
    bj = 1
    below = 0
    for i in range(n):
        row_min[i] = math.inf
    for i in range(n):
        d[i, i] = math.inf
        for j in range(i + 1, n):
            dx = pos[i, 0] - pos[j, 0]
            dy = pos[i, 1] - pos[j, 1]
            dz = pos[i, 2] - pos[j, 2]
            v = math.sqrt(dx * dx + dy * dy + dz * dz)
            if v != v:
                v = math.inf
            d[i, j] = v
            d[j, i] = v
            if v < row_min[i]:
                row_min[i] = v
            if v < row_min[j]:
                row_min[j] = v
            if v < best:
                best = v
                bi = i
                bj = j
            if v < thr:
                below += 1
    return best, bi, bj, below


def compiled_pair_distances(*, compile_new: bool) -> Any:
    """:func:`pair_distances` compiled (loaded from numba's on-disk cache, or compiled first when
    ``compile_new``), its entry point; None when it cannot be had (no numba, JIT off, not cached)."""
    from smcpilot.jit import cached_entry, compile_pure, jit_unavailable_reason, numba_module

    if jit_unavailable_reason() is not None:
        return None
    if not _TWINS:
        _TWINS.update(compile_pure((pair_distances,)))
    t = numba_module().types
    return cached_entry(_TWINS[pair_distances], (t.float64[:, ::1], t.float64[:, ::1], t.float64[::1], t.float64), compile_new=compile_new)


_TWINS: dict[Any, Any] = {}
