"""pytest plugin: fly smcpilot SITL from your own tests.

Installed with smcpilot (entry point ``pytest11`` ``smcpilot``), so it is active in any pytest
run once the package is installed. It provides:

- the ``sitl`` fixture: starts lockstep SITL (:class:`ground.sitl.Sitl`: the flight controller
  and the simulator bridge) on free loopback ports with the FC's ground link pointing at a
  :class:`ground.client.Vehicle` listening on a free port, and yields that connected vehicle.
  Everything stops when the test ends;
- ``sitl_process``: the running :class:`~ground.sitl.Sitl` of the test (its ``tlog`` path, the
  FC's ground address ``gcs_address``), for tests that need it;
- the ``sitl_swarm`` fixture: a lockstep swarm (``smcpilot sitl --count K``: K flight controllers,
  one simulator, one ground router) and a connected :class:`ground.vehicle.Swarm` of its vehicles
  (``swarm[2].arm()``, ``swarm.wait_all(...)``); K from the marker's ``count=`` (default 3), the
  rest of the marker as for ``sitl`` (a scenario with a ``[swarm]`` table sets its vehicles);
  ``sitl_swarm_process`` is its :class:`~ground.sitl.Sitl` (``tlogs``, ``sim_summary`` with the
  separation after the run);
- command-line options ``--sitl-vehicle FILE``, ``--sitl-controller NAME``, ``--sitl-seed N``,
  ``--sitl-speed FACTOR`` (lockstep speed cap; default: as fast as possible),
  ``--sitl-log-dir DIR`` (default: a ``sitl-logs`` folder in pytest's temporary directory),
  ``--sitl-keep-logs``, ``--sitl-signing-key FILE`` (the vehicle and the FC sign with this key;
  the marker's ``signing_key=`` does the same for one test);
- the marker ``@pytest.mark.sitl_options(...)``: per-test :class:`~ground.sitl.SitlOptions`
  fields, e.g. ``controller="pid_smc"``, ``wind_force_ned_n=(2, 0, 0)``, ``noise=True``,
  ``seed=3``, ``vehicle="heavy.toml"``, ``gust_std_n=0.5``, ``home="47.0,8.0,400"``,
  ``param_file="tuned.parm"`` (the FC loads it, and rewrites it on every PARAM_SET), or a whole
  scenario, ``scenario="examples/scenarios/gusty-hold.toml"`` (a path or a
  :class:`~smcpilot.scenario.Scenario`; the other keywords change it).

The telemetry log (``.tlog``) of a test is kept when the test fails — its path (and the last
lines the FC and simulator printed) appear in the failure report, section "smcpilot sitl" — and
deleted when it passes, unless ``--sitl-keep-logs``. Each test also gets its own FC parameter
file next to the log (kept and deleted with it), so a parameter one test sets never leaks into
another.

Example::

    from ground.client import MissionItem

    def test_square_mission(sitl):
        sitl.arm()
        sitl.takeoff(3.0)
        sitl.wait_altitude(3.0, tol_m=0.3, timeout_sim_s=20)
        sitl.goto_ned(5.0, 0.0, -3.0)
        sitl.wait_position_ned(5.0, 0.0, -3.0, tol_m=0.5, timeout_sim_s=20)
"""

from __future__ import annotations

import collections
import dataclasses
import itertools
import os
import re
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from ground.sitl import SCENARIO_KEYWORDS, Sitl, SitlOptions
from ground.vehicle import Swarm, Vehicle
from smcpilot.errors import ConfigError
from smcpilot.scenario import Scenario
from smcpilot.swarm import SwarmSpec

#: SitlOptions fields the marker may not set (the fixture owns them).
_RESERVED = frozenset({"gcs", "tlog", "log_dir", "lockstep"})
_MARKER = "sitl_options"
#: Wall seconds to wait for the FC's first HEARTBEAT after SITL reported ready.
CONNECT_TIMEOUT_S = 20.0
#: vehicles of the sitl_swarm fixture unless the marker says count=K.
DEFAULT_SWARM_COUNT = 3


@dataclass
class _SitlRun:
    """What the plugin knows about one test's SITL run."""

    tlog: Path
    param_file: Path
    output: collections.deque[str] = field(default_factory=lambda: collections.deque(maxlen=40))
    failed: bool = False
    sitl: Sitl | None = None


_RUN_KEY = pytest.StashKey[_SitlRun]()
_RUN_NUMBERS = itertools.count(1)


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("smcpilot", "smcpilot SITL (the sitl fixture)")
    group.addoption("--sitl-vehicle", type=Path, metavar="FILE", default=None, help="vehicle TOML for SITL (default: the spec's parameters)")
    group.addoption("--sitl-controller", metavar="NAME", default=None, help="control law of the FC (default adaptive_pid_smc)")
    group.addoption("--sitl-seed", type=int, metavar="N", default=None, help="seed of sensor noise and gusts (default 0)")
    group.addoption("--sitl-speed", type=float, metavar="FACTOR", default=None, help="cap lockstep SITL at FACTOR x real time (default: as fast as possible)")
    group.addoption("--sitl-log-dir", type=Path, metavar="DIR", default=None, help="where SITL .tlog files go (default: pytest's temporary directory)")
    group.addoption("--sitl-signing-key", type=Path, metavar="FILE", default=None,
                    help="MAVLink 2 signing between the fixture's vehicle and the FC (a key file: 64 hex digits or a passphrase)")
    group.addoption("--sitl-keep-logs", action="store_true", default=False, help="keep every SITL .tlog, not only those of failed tests")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        f"{_MARKER}(**options): SITL settings for the sitl fixture (ground.sitl.SitlOptions fields, e.g."
        " controller='pid_smc', wind_force_ned_n=(2, 0, 0), noise=True, seed=1)",
    )


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[Any]:
    outcome: Any = yield
    report: pytest.TestReport = outcome.get_result()
    run = item.stash.get(_RUN_KEY, None)
    if run is None or not report.failed:
        return
    run.failed = True
    started = run.sitl is not None and run.sitl.fc is not None
    tlogs = run.sitl.tlogs if run.sitl is not None and len(run.sitl.tlogs) > 1 else [run.tlog]
    lines = [f"tlog kept: {', '.join(map(str, tlogs))}" if started else "no tlog: SITL did not start"]
    if started and run.sitl is not None and run.sitl.scenario_file is not None:
        lines.append(f"its scenario: {run.sitl.scenario_file} (fly it again: smcpilot run FILE)")
    if run.output:
        lines.append("last output of the FC and the simulator:")
        lines.extend(f"  {line}" for line in run.output)
    report.sections.append(("smcpilot sitl", "\n".join(lines)))


def _options(request: pytest.FixtureRequest, log_dir: Path, tlog: Path, param_file: Path, gcs_url: str,
             count: bool = False) -> SitlOptions:  # fmt: skip
    cfg = request.config
    kw: dict[str, Any] = {}
    if cfg.getoption("sitl_vehicle") is not None:
        kw["vehicle"] = Path(cfg.getoption("sitl_vehicle"))
    if cfg.getoption("sitl_controller") is not None:
        kw["controller"] = cfg.getoption("sitl_controller")
    if cfg.getoption("sitl_seed") is not None:
        kw["seed"] = cfg.getoption("sitl_seed")
    if cfg.getoption("sitl_signing_key") is not None:
        kw["signing_key"] = Path(cfg.getoption("sitl_signing_key"))
    speed = cfg.getoption("sitl_speed")
    if speed is not None:
        if not speed > 0:
            raise pytest.UsageError(f"--sitl-speed must be > 0, got {speed}")
        kw["speed"] = speed
    valid = ({f.name for f in dataclasses.fields(SitlOptions)} | SCENARIO_KEYWORDS | ({"count"} if count else set())) - _RESERVED - {"timed"}
    # Markers closest to the test win (a test's marker over its class's over its module's).
    for marker in reversed(list(request.node.iter_markers(_MARKER))):
        if marker.args:
            pytest.fail(f"@pytest.mark.{_MARKER} takes keyword arguments only, got {marker.args!r}", pytrace=False)
        for key, value in marker.kwargs.items():
            if key not in valid:
                pytest.fail(
                    f"@pytest.mark.{_MARKER}: unknown option {key!r}; valid: {', '.join(sorted(valid))}", pytrace=False
                )
            if key == "scenario" and value is not None and not isinstance(value, Scenario):
                value = Scenario.from_toml(value)  # a path: the scenario file
            elif key in ("vehicle", "plan", "param_file", "signing_key") and value is not None:
                value = Path(value)
            elif key in ("wind_force_ned_n", "fc_args", "sim_args") and value is not None:
                value = tuple(value)
            kw[key] = value
    if kw.get("vehicle") is not None and not Path(kw["vehicle"]).is_file():
        pytest.fail(f"SITL vehicle file not found: {kw['vehicle']}", pytrace=False)
    if kw.get("param_file") is None:
        kw["param_file"] = param_file
    else:
        kw["param_file"] = Path(kw["param_file"])
    k = kw.pop("count", None)
    options = SitlOptions.of(lockstep=True, gcs=gcs_url, log_dir=log_dir, tlog=tlog, **kw)
    if count:
        sc = options.scenario
        if k is not None or sc.swarm is None:
            swarm = sc.swarm if sc.swarm is not None else SwarmSpec()
            try:
                sc = sc.with_changes(swarm=dataclasses.replace(swarm, count=int(k if k is not None else DEFAULT_SWARM_COUNT)))
                sc.fleet()
            except ConfigError as exc:
                pytest.fail(f"@pytest.mark.{_MARKER}: {exc}", pytrace=False)
            options = dataclasses.replace(options, scenario=sc)
    return options


def _log_dir(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    log_dir = request.config.getoption("sitl_log_dir")
    log_dir = Path(log_dir) if log_dir is not None else tmp_path_factory.getbasetemp() / "sitl-logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    return log_dir


def _remove(*paths: Path) -> None:
    """Delete a passed test's files (those that exist)."""
    for path in paths:
        path.unlink(missing_ok=True)


def _safe_name(nodeid: str) -> str:
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", nodeid.split("::", 1)[-1]).strip("_")
    return name[:80] or "test"


@pytest.fixture
def sitl(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Vehicle]:
    """A connected :class:`ground.client.Vehicle` flying in fresh lockstep SITL (see the module
    docstring); waits in the vehicle are in simulated seconds."""
    cfg = request.config
    log_dir = cfg.getoption("sitl_log_dir")
    log_dir = Path(log_dir) if log_dir is not None else tmp_path_factory.getbasetemp() / "sitl-logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    stem = f"{_safe_name(request.node.nodeid)}-{os.getpid()}-{time.strftime('%H%M%S')}-{next(_RUN_NUMBERS)}"
    run = _SitlRun(tlog=log_dir / f"{stem}.tlog", param_file=log_dir / f"{stem}.parm")
    request.node.stash[_RUN_KEY] = run

    marker = request.node.get_closest_marker(_MARKER)
    key_file = (marker.kwargs.get("signing_key") if marker is not None else None) or cfg.getoption("sitl_signing_key")
    vehicle = Vehicle("udpin:127.0.0.1:0", connect_timeout_s=CONNECT_TIMEOUT_S, signing_key=key_file)
    vehicle.open()
    sitl_proc: Sitl | None = None
    yielded = False
    try:
        options = _options(request, log_dir, run.tlog, run.param_file, f"udp:127.0.0.1:{vehicle.local_address[1]}")
        if options.speed is not None:  # a slow simulation needs more wall time per simulated second
            vehicle.wall_per_sim_s = max(vehicle.wall_per_sim_s, 3.0 / options.speed)
        sitl_proc = Sitl(options, echo=run.output.append)
        run.sitl = sitl_proc
        with sitl_proc:
            vehicle.wait_heartbeat()
            yielded = True
            yield vehicle
            vehicle.close()
    finally:
        vehicle.close()
        # A set-up failure (SITL did not start, no heartbeat) keeps the log too: the set-up
        # report, made after this, carries the section.
        if not (cfg.getoption("sitl_keep_logs") or run.failed or not yielded):  # a marker's own param_file is the user's: kept
            _remove(run.tlog, run.param_file, run.tlog.with_name(run.tlog.stem + ".scenario.toml"))


@pytest.fixture
def sitl_process(sitl: Vehicle, request: pytest.FixtureRequest) -> Sitl:
    """The running :class:`ground.sitl.Sitl` behind the ``sitl`` fixture (``.tlog``, ``.gcs_address``)."""
    run = request.node.stash[_RUN_KEY]
    assert run.sitl is not None
    return run.sitl


@pytest.fixture
def sitl_swarm(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Swarm]:
    """A connected :class:`ground.vehicle.Swarm` flying in a fresh lockstep swarm (see the module
    docstring); its vehicles' waits are in simulated seconds."""
    cfg = request.config
    log_dir = _log_dir(request, tmp_path_factory)
    stem = f"{_safe_name(request.node.nodeid)}-{os.getpid()}-{time.strftime('%H%M%S')}-{next(_RUN_NUMBERS)}"
    run = _SitlRun(tlog=log_dir / f"{stem}.tlog", param_file=log_dir / f"{stem}.parm")
    request.node.stash[_RUN_KEY] = run
    marker = request.node.get_closest_marker(_MARKER)
    key_file = (marker.kwargs.get("signing_key") if marker is not None else None) or cfg.getoption("sitl_signing_key")
    options = _options(request, log_dir, run.tlog, run.param_file, "udpin:127.0.0.1:0", count=True)
    sitl_proc = Sitl(options, echo=run.output.append)
    run.sitl = sitl_proc
    yielded = False
    try:
        with sitl_proc:
            assert sitl_proc.gcs_address is not None
            swarm = Swarm(f"udpout:{sitl_proc.gcs_address}", sitl_proc.sysids, connect_timeout_s=CONNECT_TIMEOUT_S,
                          signing_key=key_file)  # fmt: skip
            if options.speed is not None:
                for v in swarm:
                    v.wall_per_sim_s = max(v.wall_per_sim_s, 3.0 / options.speed)
            with swarm:
                yielded = True
                yield swarm
    finally:
        if not (cfg.getoption("sitl_keep_logs") or run.failed or not yielded):
            _remove(run.tlog.with_name(run.tlog.stem + ".scenario.toml"),
                    *(t.with_name(t.stem + suffix) for t in sitl_proc.tlogs for suffix in (".tlog", ".scenario.toml", ".parm")))  # fmt: skip


@pytest.fixture
def sitl_swarm_process(sitl_swarm: Swarm, request: pytest.FixtureRequest) -> Sitl:
    """The running :class:`ground.sitl.Sitl` behind the ``sitl_swarm`` fixture (``tlogs``, ``sysids``)."""
    run = request.node.stash[_RUN_KEY]
    assert run.sitl is not None
    return run.sitl
