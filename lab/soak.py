"""The soak: random missions with random faults and link impairments, seeded, in lockstep SITL.

``smcpilot bench soak [--sim-hours H]`` flies ``H`` simulated hours (default 1) as segments of
``--segment-s`` simulated seconds (default 600), each a fresh pair of SITL processes flying a
random :class:`~smcpilot.scenario.Scenario` drawn from one seeded stream: a take-off, way-points
every 10-30 s inside a 12 m box, a landing at the end; 1-4 mild faults (:mod:`smcpilot.faults`:
motor efficiency, sensor noise, bias and dropout, gusts, step forces); sensor noise; a lossy,
duplicating, reordering sim link (:mod:`smcpilot.impair`).

Checked per segment: both processes end with 0 (no crash, no watchdog), the FC flew every tick,
and its tlog is complete (every record readable; one simulator state per tick, the last at the
segment's end). The resident memory (RSS, from ``/proc``) of both processes is sampled every
``--sample-s`` wall seconds and reported as a trend: the least-squares slope over the second half
of each segment (after warm-up), in MB per simulated hour, and the RSS at each segment's end.
Logs are deleted once checked unless ``--keep-logs DIR`` is given (about 15 MB per simulated
minute).
"""

from __future__ import annotations

import math
import os
import random
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from ground.sitl import Sitl, SitlError, SitlOptions
from smcpilot.errors import ConfigError, TlogError
from smcpilot.faults import FaultSpec
from smcpilot.impair import LinkImpairment
from smcpilot.plan import PlanStep
from smcpilot.scenario import EnvironmentSpec, Scenario
from smcpilot.tlog import read_tlog

#: fewest samples (second half of a segment) a trend is computed from.
MIN_TREND_SAMPLES = 10

__all__ = ["SoakConfig", "SegmentResult", "random_scenario", "run_soak", "rss_kb", "slope_per_hour"]


@dataclass(frozen=True)
class SoakConfig:
    """What to soak: simulated hours, in segments of ``segment_s`` simulated seconds."""

    sim_hours: float = 1.0
    segment_s: float = 600.0
    seed: int = 0
    #: wall seconds between memory samples.
    sample_s: float = 1.0
    #: keep the logs here (None: delete each once checked).
    keep_logs: Path | None = None
    #: the simulator's pacing (None: as fast as possible).
    speed: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.sim_hours) and self.sim_hours > 0):
            raise ConfigError(f"--sim-hours must be > 0, got {self.sim_hours!r}")
        if not (math.isfinite(self.segment_s) and self.segment_s >= 5.0):
            raise ConfigError(f"--segment-s must be >= 5 simulated seconds, got {self.segment_s!r}")
        if not (math.isfinite(self.sample_s) and self.sample_s > 0):
            raise ConfigError(f"--sample-s must be > 0, got {self.sample_s!r}")

    @property
    def segments(self) -> list[float]:
        """The segments' lengths, simulated s (the last one shorter if need be, at least 5 s)."""
        total = self.sim_hours * 3600.0
        n = max(1, math.ceil(total / self.segment_s - 1e-9))
        out = [self.segment_s] * (n - 1)
        out.append(max(5.0, total - self.segment_s * (n - 1)))
        return out


@dataclass
class SegmentResult:
    index: int
    scenario: Scenario
    ok: bool = False
    problem: str = ""
    wall_s: float = 0.0
    ticks: int = 0
    records: int = 0
    resends: int = 0
    datagrams_lost: int = 0
    faults: int = 0
    #: (wall s since start, RSS kB) per process name ("fc", "sim").
    rss: dict[str, list[tuple[float, int]]] = field(default_factory=dict)

    @property
    def speed(self) -> float:
        return self.scenario.duration_s / self.wall_s if self.wall_s > 0 else math.nan

    def slope_mb_per_sim_hour(self, name: str) -> float:
        """RSS trend over the second half of the segment, MB per simulated hour (nan: too few samples)."""
        samples = self.rss.get(name, [])
        half = samples[len(samples) // 2 :]
        if len(half) < MIN_TREND_SAMPLES:  # a few samples of a page-quantised RSS say nothing
            return math.nan
        per_wall_s = slope_per_hour(half) / 3600.0  # kB per wall second
        return per_wall_s * 3600.0 / self.speed / 1024.0 if math.isfinite(per_wall_s) else math.nan


def rss_kb(pid: int) -> int | None:
    """Resident set size of ``pid`` in kB (Linux ``/proc``), None if unknown."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


def slope_per_hour(samples: list[tuple[float, int]]) -> float:
    """Least-squares slope of (seconds, value) samples, in value units per hour (nan if < 3 samples)."""
    if len(samples) < 3:
        return math.nan
    n = len(samples)
    mt = sum(t for t, _ in samples) / n
    mv = sum(v for _, v in samples) / n
    var = sum((t - mt) ** 2 for t, _ in samples)
    if var <= 0:
        return math.nan
    return sum((t - mt) * (v - mv) for t, v in samples) / var * 3600.0


def random_scenario(rng: random.Random, index: int, duration_s: float) -> Scenario:
    """One segment's flight: take-off, way-points, landing; mild faults; a lossy sim link."""
    alt = rng.uniform(2.0, 4.0)
    plan = [PlanStep(0.0, "takeoff", alt_m=alt)]
    t = rng.uniform(6.0, 12.0)
    land_at = max(duration_s - 15.0, duration_s * 0.7)
    while t < land_at:
        plan.append(PlanStep(round(t, 3), "goto", north_m=round(rng.uniform(-6, 6), 2), east_m=round(rng.uniform(-6, 6), 2),
                             alt_m=round(rng.uniform(1.5, 5.0), 2), yaw_deg=round(rng.uniform(-180, 180), 1)))  # fmt: skip
        t += rng.uniform(10.0, 30.0)
    if duration_s >= 20.0:
        plan.append(PlanStep(round(land_at, 3), "land"))
    faults = []
    for _ in range(rng.randint(1, 4)):
        start = round(rng.uniform(3.0, max(3.5, duration_s - 5.0)), 3)
        length = rng.uniform(0.5, 8.0)
        stop = round(min(start + length, duration_s), 3)
        kind = rng.choice(("motor", "noise", "bias", "dropout", "gust", "force"))
        if kind == "motor":
            faults.append(FaultSpec("motor", start, stop, motor=rng.randint(1, 4), efficiency=round(rng.uniform(0.8, 0.95), 3)))
        elif kind == "noise":
            faults.append(FaultSpec("sensor", start, stop, sensor="position", mode="noise", value=(0.03, 0.03, 0.03)))
        elif kind == "bias":
            faults.append(FaultSpec("sensor", start, stop, sensor="gyro", mode="bias", value=(0.01, -0.01, 0.0)))
        elif kind == "dropout":
            faults.append(FaultSpec("sensor", start, round(start + rng.uniform(0.05, 0.3), 3), sensor="position", mode="dropout"))
        elif kind == "gust":
            faults.append(FaultSpec("gust", start, stop, force_std_n=round(rng.uniform(0.1, 0.5), 3), torque_std_n_m=0.002, tau_s=1.0))
        else:
            f = (round(rng.uniform(-0.4, 0.4), 3), round(rng.uniform(-0.4, 0.4), 3), 0.0)
            faults.append(FaultSpec("force", start, stop, force_ned_n=f))
    link = LinkImpairment(loss=round(rng.uniform(0.0, 0.05), 4), duplicate=round(rng.uniform(0.0, 0.02), 4),
                          reorder=round(rng.uniform(0.0, 0.02), 4), reorder_ms=1.0)  # fmt: skip
    return Scenario(
        name=f"soak-{index:03d}", description="smcpilot bench soak segment", duration_s=duration_s,
        seed=rng.randrange(2**31), environment=EnvironmentSpec(noise=True), plan=tuple(plan),
        faults=tuple(sorted(faults, key=lambda f: f.start_s)), sim_link=link,
    )  # fmt: skip


def _check_log(path: Path, sc: Scenario) -> tuple[int, str]:
    """(records, problem or ""): every record readable, one state per tick, the last at the end."""
    records = 0
    states = 0
    last_ms = -1
    try:
        for _, msg in read_tlog(path):
            records += 1
            if msg.get_type() == "LOCAL_POSITION_NED" and msg.get_srcComponent() == 200:
                states += 1
                last_ms = msg.time_boot_ms
    except TlogError as exc:
        return records, f"log unreadable after {records} records: {exc}"
    if states != sc.n_ticks:
        return records, f"log holds {states} simulator states, expected {sc.n_ticks}"
    if abs(last_ms * 1e-3 - sc.duration_s) > 1e-6:
        return records, f"log ends at {last_ms * 1e-3:.3f} s, expected {sc.duration_s:g} s"
    return records, ""


def run_segment(sc: Scenario, index: int, log_dir: Path, cfg: SoakConfig) -> SegmentResult:
    res = SegmentResult(index, sc, faults=len(sc.faults))
    tlog = log_dir / f"{sc.name}.tlog"
    opts = SitlOptions(scenario=sc, timed=True, lockstep=True, speed=cfg.speed, gcs=None, log_dir=log_dir, tlog=tlog,
                       param_file=log_dir / f"{sc.name}.parm")  # fmt: skip
    sitl = Sitl(opts)
    t0 = time.monotonic()
    try:
        with sitl:
            assert sitl.fc is not None and sitl.sim is not None
            pids = {"fc": sitl.fc.proc.pid, "sim": sitl.sim.proc.pid}
            res.rss = {k: [] for k in pids}
            while sitl.poll() == (None, None):
                now = time.monotonic() - t0
                for name, pid in pids.items():
                    kb = rss_kb(pid)
                    if kb is not None:
                        res.rss[name].append((now, kb))
                time.sleep(cfg.sample_s)
            sitl.wait(timeout_s=60.0)
    except SitlError as exc:
        res.problem = str(exc).splitlines()[0]
    res.wall_s = time.monotonic() - t0
    fcs = sitl.fc_summary or {}
    sims = sitl.sim_summary or {}
    res.ticks = int(fcs.get("ticks", 0))
    res.resends = int(sims.get("resends", 0))
    imp = (fcs.get("impairment") or {}).get("sim") or {}
    res.datagrams_lost = sum(int(d.get("lost", 0)) for d in imp.values())
    if not res.problem and res.ticks != sc.n_ticks:
        res.problem = f"the FC flew {res.ticks} ticks, expected {sc.n_ticks}"
    res.records, log_problem = _check_log(tlog, sc) if tlog.exists() else (0, "no log")
    res.problem = res.problem or log_problem
    res.ok = not res.problem
    if cfg.keep_logs is None:
        for p in log_dir.glob(f"{sc.name}*"):
            p.unlink(missing_ok=True)
    return res


def run_soak(cfg: SoakConfig, out: Callable[[str], None] = print) -> list[SegmentResult]:
    """Fly every segment, printing one line per segment; the results."""
    rng = random.Random(cfg.seed)
    results: list[SegmentResult] = []
    with tempfile.TemporaryDirectory(prefix="smcpilot-soak-") as tmp:
        log_dir = cfg.keep_logs if cfg.keep_logs is not None else Path(tmp)
        log_dir.mkdir(parents=True, exist_ok=True)
        done_s = 0.0
        total_s = sum(cfg.segments)
        for i, seg_s in enumerate(cfg.segments):
            sc = random_scenario(rng, i, seg_s)
            r = run_segment(sc, i, log_dir, cfg)
            results.append(r)
            done_s += seg_s
            fc_end = r.rss.get("fc", [(0, 0)])[-1][1] / 1024 if r.rss.get("fc") else math.nan
            sim_end = r.rss.get("sim", [(0, 0)])[-1][1] / 1024 if r.rss.get("sim") else math.nan
            out(f"  segment {i + 1}/{len(cfg.segments)} {'ok  ' if r.ok else 'FAIL'} {seg_s:6.0f} sim s in {r.wall_s:6.1f} wall s"
                f" ({r.speed:5.1f}x), {r.faults} faults, link {sc.sim_link.to_text()}: {r.datagrams_lost} datagrams lost,"
                f" {r.resends} re-sends; RSS fc {fc_end:.1f} MB ({_fmt(r.slope_mb_per_sim_hour('fc'))} MB/sim h),"
                f" sim {sim_end:.1f} MB ({_fmt(r.slope_mb_per_sim_hour('sim'))} MB/sim h)"
                f"{'' if r.ok else ': ' + r.problem}  [{done_s / total_s:4.0%}]")  # fmt: skip
    return results


def _fmt(v: float) -> str:
    return "n/a" if not math.isfinite(v) else f"{v:+.2f}"


def report(cfg: SoakConfig, results: list[SegmentResult], out: Callable[[str], None] = print) -> int:
    """The summary lines; 0 if every segment passed, 1 otherwise."""
    failed = [r for r in results if not r.ok]
    sim_s = sum(r.scenario.duration_s for r in results)
    wall_s = sum(r.wall_s for r in results)
    out(f"\nsoak: {sim_s / 3600:.3f} simulated h in {wall_s / 60:.1f} wall min, {len(results)} segments,"
        f" {sum(r.faults for r in results)} faults, {sum(r.datagrams_lost for r in results)} datagrams lost,"
        f" {sum(r.records for r in results)} log records checked; {len(failed)} failed")  # fmt: skip
    for name in ("fc", "sim"):
        ends = [r.rss[name][-1][1] / 1024 for r in results if r.rss.get(name)]
        slopes = [s for r in results if math.isfinite(s := r.slope_mb_per_sim_hour(name))]
        if ends:
            out(f"  memory {name:>3}: RSS at segment ends {min(ends):.1f}..{max(ends):.1f} MB;"
                f" trend over each segment's second half {min(slopes) if slopes else math.nan:+.2f}..{max(slopes) if slopes else math.nan:+.2f}"
                " MB per simulated hour")  # fmt: skip
    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    out(f"  machine load (1/5/15 min) at the end: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores")
    for r in failed:
        out(f"  FAILED segment {r.index + 1} (seed {r.scenario.seed}): {r.problem}")
    return 0 if not failed else 1
