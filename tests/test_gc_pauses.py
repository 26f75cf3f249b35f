"""GcPauses times the collector's passes while installed, and only then."""

from __future__ import annotations

import gc

import pytest

from smcpilot.gc_pauses import GcPauses


def test_a_forced_collection_is_timed_and_kept_with_its_start() -> None:
    ticks = iter(range(1000))

    def clock() -> float:  # each read 1 ms later: every pass lasts exactly 1 ms
        return next(ticks) * 1e-3

    with GcPauses(clock, keep_s=0.0005) as p:
        gc.collect()
    assert p.counts[2] >= 1
    assert p.max_s == pytest.approx(1e-3)
    s = p.summary()
    assert len(s["long_s"]) == sum(p.counts) and s["long_s"][0] == pytest.approx(1e-3)
    assert s["long_at_s"][0] == 0.0
    n = sum(p.counts)
    gc.collect()  # uninstalled: not counted
    assert sum(p.counts) == n and p._callback not in gc.callbacks


def test_installing_twice_is_an_error() -> None:
    p = GcPauses()
    with p, pytest.raises(RuntimeError, match="installed already"), p:
        pass
    assert p._callback not in gc.callbacks
