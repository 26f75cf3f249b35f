"""The soak, short: ``smcpilot bench soak`` end to end (lockstep SITL processes) and its pieces."""

from __future__ import annotations

import math
import random
import subprocess
import sys
from pathlib import Path

import pytest

from lab.soak import SoakConfig, random_scenario, run_soak, slope_per_hour
from smcpilot.errors import ConfigError
from smcpilot.scenario import Scenario


def test_random_segments_are_seeded_valid_scenarios(tmp_path: Path) -> None:
    a = [random_scenario(random.Random(5), i, 120.0) for i in range(3)]
    b = [random_scenario(random.Random(5), i, 120.0) for i in range(3)]
    assert a == b
    assert random_scenario(random.Random(6), 0, 120.0) != a[0]
    for sc in a:
        assert sc.plan[0].action == "takeoff" and sc.plan[-1].action == "land"
        assert 1 <= len(sc.faults) <= 4 and sc.sim_link.active and sc.environment.noise
        assert all(f.stop_s <= sc.duration_s for f in sc.faults)
        assert Scenario.from_toml(sc.save(tmp_path / f"{sc.name}.toml")) == sc  # launchable as a file


def test_segments_and_trend_helpers() -> None:
    assert SoakConfig(sim_hours=1.0).segments == [600.0] * 6
    assert SoakConfig(sim_hours=0.1, segment_s=200).segments == [200.0, 160.0]
    for bad in (dict(sim_hours=0), dict(sim_hours=math.inf), dict(segment_s=1.0), dict(sample_s=0)):
        with pytest.raises(ConfigError):
            SoakConfig(**bad)  # type: ignore[arg-type]
    assert slope_per_hour([(0.0, 10), (1800.0, 20), (3600.0, 30)]) == pytest.approx(20.0)
    assert math.isnan(slope_per_hour([(0.0, 1), (1.0, 2)]))


@pytest.mark.slow
def test_short_soak_flies_every_segment_and_checks_its_log(tmp_path: Path) -> None:
    cfg = SoakConfig(sim_hours=24.0 / 3600.0, segment_s=12.0, seed=3, sample_s=0.2, keep_logs=tmp_path / "logs")
    lines: list[str] = []
    results = run_soak(cfg, out=lines.append)
    assert len(results) == 2 and all(r.ok for r in results), [r.problem for r in results]
    for r in results:
        assert r.ticks == r.scenario.n_ticks
        assert r.records > 3 * r.ticks  # state pair + answer + law record per tick, at least
        assert r.rss["fc"] and r.rss["sim"] and all(kb > 1000 for _, kb in r.rss["fc"])
    assert sum(r.datagrams_lost for r in results) > 0, "the sim link lost nothing: the impairment is not on"
    assert len(list((tmp_path / "logs").glob("*.tlog"))) == 2
    assert len(lines) == 2 and all(" ok " in ln for ln in lines), lines


@pytest.mark.slow
def test_soak_command_line(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "lab.cli", "bench", "soak", "--sim-hours", str(8.0 / 3600.0), "--segment-s", "8", "--seed", "1"],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "segment 1/1 ok" in proc.stdout and "0 failed" in proc.stdout and "memory  fc: RSS" in proc.stdout, proc.stdout
    bad = subprocess.run([sys.executable, "-m", "lab.cli", "bench", "soak", "--sim-hours", "0"], capture_output=True, text=True,
                         timeout=60, cwd=tmp_path)  # fmt: skip
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr
