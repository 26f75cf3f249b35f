"""The swarm's separation bookkeeping (sim_bridge.proximity) against a pair-by-pair scan."""

from __future__ import annotations

import math
import random

import pytest
from bits_helpers import needs_jit

from sim_bridge.proximity import Proximity, compiled_pair_distances, pair_distances


def scan(p: Proximity, t_s: float, positions: list[tuple[float, float, float]]) -> list[tuple[str, int, int, float]]:
    """The oracle: every pair in turn, in plain Python (``math.sqrt`` of the squared differences,
    each a product: ``x ** 2`` calls the C library's ``pow``, which can differ from ``x * x`` by an ulp)."""
    out = []
    n = len(positions)
    for i in range(n):
        xi, yi, zi = positions[i]
        for j in range(i + 1, n):
            xj, yj, zj = positions[j]
            dx, dy, dz = xi - xj, yi - yj, zi - zj
            d = math.sqrt(dx * dx + dy * dy + dz * dz)
            if d < p.per_vehicle_min_m[i]:
                p.per_vehicle_min_m[i] = d
            if d < p.per_vehicle_min_m[j]:
                p.per_vehicle_min_m[j] = d
            if d < p.min_separation_m:
                p.min_separation_m, p.min_at_s, p.min_pair = d, t_s, (i, j)
            pair = (i, j)
            if d < p.separation_m:
                if pair not in p._close:
                    p._close.add(pair)
                    p.events.append((t_s, i, j, d))
                    out.append(("separation", i, j, d))
            elif pair in p._close:
                p._close.discard(pair)
            if d < p.contact_m and pair not in p._touched:
                p._touched.add(pair)
                p.contacts.append((t_s, i, j, d))
                out.append(("contact", i, j, d))
    return out


@pytest.mark.parametrize("way", ["numpy", pytest.param("compiled", marks=needs_jit)])
@pytest.mark.parametrize("seed", range(12))
def test_every_pair_at_once_matches_the_pair_by_pair_scan(seed: int, way: str) -> None:
    """numpy's matrix, and the compiled kernel the simulator loads with its compiled physics
    (sim_bridge.proximity.pair_distances): the same events, distances and minimums as the scan."""
    rng = random.Random(seed)
    n = rng.choice([2, 3, 5, 16])
    sep, contact = rng.choice([(2.0, 0.5), (1.0, 1.5), (3.0, 0.0)])
    fast, slow = Proximity(n, sep, contact), Proximity(n, sep, contact)
    if way == "compiled":
        fast.kernel = compiled_pair_distances(compile_new=True)
        assert fast.kernel is not None
    pos = [(rng.uniform(-4, 4), rng.uniform(-4, 4), rng.uniform(-3, 0)) for _ in range(n)]
    for step in range(200):
        t_s = step * 0.002
        pos = [(x + rng.gauss(0, 0.3), y + rng.gauss(0, 0.3), z + rng.gauss(0, 0.1)) for x, y, z in pos]
        if rng.random() < 0.05:  # a position that is not a number (a diverged plant), and ties
            pos[rng.randrange(n)] = (math.nan, 0.0, 0.0)
        if rng.random() < 0.05:
            pos[-1] = pos[0]
        assert fast.check(t_s, pos) == scan(slow, t_s, pos)
        pos = [(0.0, 0.0, 0.0) if math.isnan(x) else (x, y, z) for x, y, z in pos]
    for name in ("min_separation_m", "min_at_s", "min_pair", "per_vehicle_min_m", "events", "contacts", "_close", "_touched"):
        assert getattr(fast, name) == getattr(slow, name), name
    assert fast.events or fast.contacts  # (the walk does bring vehicles together)


def test_the_kernels_pure_function_in_cpython_gives_the_same() -> None:
    """One source: the function numba compiles, run by CPython, gives the scan's values."""
    rng = random.Random(5)
    fast, slow = Proximity(6, 2.0, 0.5), Proximity(6, 2.0, 0.5)
    fast.kernel = pair_distances
    pos = [(rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(-1, 0)) for _ in range(6)]
    pos[3] = (math.nan, 0.0, 0.0)
    pos[5] = pos[1]
    assert fast.check(0.0, pos) == scan(slow, 0.0, pos)
    assert (fast.min_separation_m, fast.min_pair, fast.per_vehicle_min_m) == (slow.min_separation_m, slow.min_pair, slow.per_vehicle_min_m)
