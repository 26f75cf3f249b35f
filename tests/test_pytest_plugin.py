"""The smcpilot pytest plugin (entry point ``pytest11``), exercised the way a user meets it: pytest
runs (``pytester``, in a subprocess) of small user test files that fly lockstep SITL with the
``sitl`` fixture."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

pytest_plugins = ("pytester",)

#: end-to-end: the quick tier (`pytest -m "not slow"`) leaves this module to the full suite.
pytestmark = pytest.mark.slow

USER_TESTS = '''
import pytest
from ground.client import MissionItem
from smcpilot.geo import Home, ned_to_global


def test_mission_flies_and_lands(sitl):
    home = sitl.get_home()
    lat, lon, _ = ned_to_global(Home(home.lat_deg, home.lon_deg, home.alt_amsl_m), 3.0, 0.0, 0.0)
    sitl.upload_mission([MissionItem.takeoff(2.0), MissionItem.waypoint(lat, lon, 2.0), MissionItem.land()])
    sitl.arm()
    sitl.start_mission()
    sitl.wait_mode("AUTO", timeout_sim_s=3)
    sitl.wait_position_ned(3.0, 0.0, -2.0, tol_m=0.5, timeout_sim_s=30)
    sitl.wait_disarmed(timeout_sim_s=30)


def test_fails_after_a_hop(sitl):
    sitl.arm()
    sitl.takeoff(1.0)
    sitl.wait_altitude(1.0, tol_m=0.3, timeout_sim_s=15)
    assert sitl.altitude_m > 50, "deliberate failure"


@pytest.mark.sitl_options(controller="pid_smc", seed=7, wind_force_ned_n=[0.5, 0.0, 0.0])
def test_marker_options(sitl, sitl_process):
    o = sitl_process.options
    assert (o.controller, o.seed, o.wind_force_ned_n, o.lockstep) == ("pid_smc", 7, (0.5, 0.0, 0.0), True)
    assert sitl_process.tlog is not None and sitl_process.tlog.exists()
    assert sitl.mode == "GUIDED"


@pytest.mark.sitl_options(colour="red")
def test_bad_marker(sitl):
    pass
'''


def _tlogs(directory: Path) -> list[Path]:
    return sorted(directory.glob("*.tlog")) if directory.exists() else []


def test_plugin_is_registered_with_options_and_marker(pytester: pytest.Pytester) -> None:
    result = pytester.runpytest_subprocess("--help")
    for option in ("--sitl-vehicle=FILE", "--sitl-controller=NAME", "--sitl-seed=N", "--sitl-speed=FACTOR", "--sitl-log-dir=DIR", "--sitl-keep-logs"):
        assert option in result.stdout.str()
    result = pytester.runpytest_subprocess("--markers")
    result.stdout.fnmatch_lines(["@pytest.mark.sitl_options(**options): SITL settings for the sitl fixture*"])
    result = pytester.runpytest_subprocess("--fixtures")
    result.stdout.fnmatch_lines(["sitl -- *", "sitl_process -- *"])


def test_passing_test_deletes_its_log_failing_test_keeps_it_and_reports_the_path(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_user=USER_TESTS)
    logs = pytester.path / "logs"
    result = pytester.runpytest_subprocess("--sitl-log-dir", str(logs), "-p", "no:cacheprovider")
    result.assert_outcomes(passed=2, failed=1, errors=1)
    out = result.stdout.str()
    # The failure report names the kept log, in its own section, with the children's last output.
    assert re.search(r"-+ smcpilot sitl -+", out), out
    kept = re.findall(r"tlog kept: (\S+\.tlog)", out)
    assert len(kept) == 1, out
    kept_path = Path(kept[0])
    assert kept_path.parent == logs and "test_fails_after_a_hop" in kept_path.name
    assert kept_path.stat().st_size > 10_000
    assert "[fc] fc: Armed" in out
    # Only the failed test's log (and its parameter file) is left.
    assert _tlogs(logs) == [kept_path]
    scenario_file = kept_path.with_name(kept_path.stem + ".scenario.toml")  # what flew, re-runnable with `smcpilot run`
    assert scenario_file.is_file()
    assert {p.name for p in logs.iterdir()} <= {kept_path.name, kept_path.with_suffix(".parm").name, scenario_file.name}
    # A bad marker is a clear set-up error (no SITL was started, so no log).
    result.stdout.fnmatch_lines(
        ["*@pytest.mark.sitl_options: unknown option 'colour'; valid: *controller*", "*smcpilot sitl*", "no tlog: SITL did not start"]
    )


def test_keep_logs_and_command_line_options(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(
        test_opts='''
def test_options(sitl, sitl_process):
    o = sitl_process.options
    assert (o.controller, o.seed, o.speed) == ("cascade_pid", 3, 50.0)
    sitl.sleep_sim(0.5)
'''
    )
    result = pytester.runpytest_subprocess("--sitl-controller", "cascade_pid", "--sitl-seed", "3", "--sitl-speed", "50", "--sitl-keep-logs", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1)
    # Default log directory: sitl-logs in pytest's temporary directory.
    kept = list(pytester.path.rglob("sitl-logs/*.tlog"))
    assert len(kept) == 1 and kept[0].stat().st_size > 0


def test_missing_vehicle_file_is_a_setup_error(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_v="def test_v(sitl):\n    pass\n")
    result = pytester.runpytest_subprocess("--sitl-vehicle", "nope.toml", "-p", "no:cacheprovider")
    result.assert_outcomes(errors=1)
    result.stdout.fnmatch_lines(["*SITL vehicle file not found: nope.toml*"])


def test_marker_takes_a_whole_scenario_and_keywords_change_it(pytester: pytest.Pytester) -> None:
    scenario = Path(__file__).resolve().parents[1] / "examples" / "scenarios" / "gusty-hold.toml"
    pytester.makepyfile(
        test_sc=f'''
import pytest

@pytest.mark.sitl_options(scenario={str(scenario)!r}, seed=11)
def test_scenario(sitl, sitl_process):
    sc = sitl_process.options.scenario
    assert (sc.name, sc.seed, sc.environment.noise, sc.environment.gust_std_n) == ("gusty-hold", 11, True, 0.15)
    assert len(sc.plan) == 3  # the scenario's plan: the FC flies it in simulated time
    sitl.wait_altitude(3.0, tol_m=0.3, timeout_sim_s=15)
'''
    )
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=1)


SWARM_TESTS = '''
import pytest

@pytest.mark.sitl_options(count=2, speed=4.0)
def test_two_vehicles(sitl_swarm, sitl_swarm_process):
    assert sitl_swarm.sysids == (1, 2)
    sitl_swarm[2].arm()
    sitl_swarm[2].takeoff(2.0)
    sitl_swarm[2].wait_altitude(2.0, tol_m=0.3, timeout_sim_s=20)
    assert not sitl_swarm[1].armed
    assert len(sitl_swarm_process.tlogs) == 2

@pytest.mark.sitl_options(count=2)
def test_swarm_fails(sitl_swarm):
    sitl_swarm.arm_all()
    assert False, "on purpose"

@pytest.mark.sitl_options(count=0)
def test_bad_count(sitl_swarm):
    pass
'''


def test_swarm_fixture_flies_k_vehicles_and_keeps_every_log_of_a_failure(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_swarm_user=SWARM_TESTS)
    logs = pytester.path / "logs"
    result = pytester.runpytest_subprocess("--sitl-log-dir", str(logs), "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1, failed=1, errors=1)
    out = result.stdout.str()
    assert "test_bad_count" in out and "whole number >= 1" in out
    kept = sorted(p.name for p in logs.glob("*.tlog"))
    assert len(kept) == 2 and all("test_swarm_fails" in n for n in kept), kept  # the passing test's logs are gone
    assert "tlog kept: " in out and kept[0] in out
