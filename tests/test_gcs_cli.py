"""``smcpilot gcs`` as a user runs it: ``python -m lab.cli gcs ...`` subprocesses against the real
flight controller (lockstep SITL, FC ground port on 127.0.0.1), plus pure tests of the mission-file
reader and the ``watch`` rendering."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from ground.client import StatusText, Telemetry
from ground.gcs_cmd import render_frame, render_line, render_status
from ground.missions import load_mission
from ground.sitl import Sitl, SitlOptions
from lab.cli import build_parser

LOOPBACK = "127.0.0.1"
#: Wall-clock limit of one CLI run (only to turn a hang into a failure).
RUN_TIMEOUT_S = 60.0

MISSION_TOML = """
[[item]]
type = "takeoff"
alt_m = 2.0

[[item]]
type = "speed"
speed_mps = 2.5

[[item]]
type = "waypoint"
north_m = 3.0
east_m = -1.0
alt_m = 2.5
hold_s = 0.5
yaw_deg = 45.0

[[item]]
type = "loiter_time"
hold_s = 0.5
alt_m = 2.5

[[item]]
type = "land"
"""


def gcs(*args: str, connect: str | None = None, cwd: Path | None = None, timeout_s: float = RUN_TIMEOUT_S) -> subprocess.CompletedProcess[str]:
    """Run ``python -m lab.cli gcs [--connect URL] ARGS``."""
    cmd = [sys.executable, "-m", "lab.cli", "gcs"]
    if connect is not None:
        cmd += ["--connect", connect]
    return subprocess.run([*cmd, *args], capture_output=True, text=True, timeout=timeout_s, cwd=cwd, stdin=subprocess.DEVNULL)


def _sitl(tmp_path: Path, speed: float | None = None, param_file: Path | None = None) -> Sitl:
    return Sitl(SitlOptions.of(lockstep=True, speed=speed, gcs=f"udpin:{LOOPBACK}:0", log_dir=tmp_path, tlog=tmp_path / "sitl.tlog",
                               param_file=param_file))


@pytest.fixture(scope="module")
def fc_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """One SITL for the read-mostly tests: the URL to reach the FC's ground port."""
    with _sitl(tmp_path_factory.mktemp("gcs-cli")) as sitl:
        assert sitl.gcs_address
        yield f"udpout:{sitl.gcs_address}"


@pytest.fixture
def fresh_fc_url(tmp_path: Path) -> Iterator[str]:
    """A SITL of this test's own (flights change the state), paced at 4x real time, with the FC's
    disarm delay (10 s by default, tested in test_commander) at its 127 s maximum, as a parameter
    file sets it: unpaced, the lockstep runs so far ahead between two CLI invocations (each a
    process start) that 10 s pass between `gcs arm` and `gcs takeoff`, and at 4x a loaded CI
    machine took more than 2.5 s to start one (the vehicle had disarmed itself: "arm first")."""
    params = tmp_path / "fc.parm"
    params.write_text("DISARM_DELAY 127\n", encoding="utf-8")
    with _sitl(tmp_path, speed=4.0, param_file=params) as sitl:
        assert sitl.gcs_address
        yield f"udpout:{sitl.gcs_address}"


# --------------------------------------------------------------------------------- usage
@pytest.mark.parametrize(
    "args",
    [
        (),
        ("status",),
        ("arm",),
        ("disarm",),
        ("takeoff",),
        ("goto",),
        ("land",),
        ("rtl",),
        ("mode",),
        ("param",),
        ("param", "get"),
        ("param", "set"),
        ("param", "list"),
        ("mission",),
        ("mission", "upload"),
        ("mission", "download"),
        ("mission", "start"),
        ("mission", "clear"),
        ("watch",),
    ],
)
def test_every_action_has_a_true_help(args: tuple[str, ...], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        build_parser().parse_args(["gcs", *args, "--help"])
    assert info.value.code == 0
    out, err = capsys.readouterr()
    assert out.startswith("usage: smcpilot gcs") and err == ""
    assert "options:" in out and len(out.splitlines()) > 4


def test_top_help_lists_the_actions_and_the_mission_format() -> None:
    r = gcs("--help")
    for word in ("status", "arm", "takeoff", "goto", "land", "rtl", "mode", "param", "mission", "watch", "--connect", "udpin:127.0.0.1:14550"):
        assert word in r.stdout
    assert "[[item]]" in r.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("goto", "1", "2"), "the following arguments are required: D"),
        (("takeoff", "high"), "invalid float value: 'high'"),
        (("takeoff", "--", "-1"), "takeoff altitude must be > 0 m"),
        (("mode", "HOVER"), "unknown flight mode 'HOVER'"),
        (("--connect", "bogus", "status"), "endpoint 'bogus': unknown form"),
        (("watch", "--rate-hz", "0"), "--rate-hz must lie in (0, 50]"),
        (("param", "set", "X", "nan"), "parameter value must be finite"),
        (("frobnicate",), "invalid choice: 'frobnicate'"),
    ],
)
def test_usage_errors_exit_2_with_one_line_and_no_vehicle_needed(args: tuple[str, ...], message: str, tmp_path: Path) -> None:
    # Port 9 (discard) on loopback: nothing answers there; usage errors must come before any wait.
    r = gcs(*args, connect=None if "--connect" in args else f"udpout:{LOOPBACK}:9", cwd=tmp_path, timeout_s=10.0)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert message in r.stderr
    assert "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith(("smcpilot gcs", "usage:", "smcpilot: error", "smcpilot gcs:"))


def test_bad_mission_file_is_a_usage_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('[[item]]\ntype = "waypoint"\nnorth_m = 1.0\neast_m = 2.0\n', encoding="utf-8")
    r = gcs("mission", "upload", str(bad), connect=f"udpout:{LOOPBACK}:9", timeout_s=10.0)
    assert r.returncode == 2
    assert r.stderr.startswith(f"smcpilot gcs: error: {bad}: item 1 (waypoint): missing key 'alt_m'")
    assert len(r.stderr.strip().splitlines()) == 1
    r = gcs("mission", "upload", str(tmp_path / "missing.toml"), connect=f"udpout:{LOOPBACK}:9", timeout_s=10.0)
    assert r.returncode == 2 and "mission file not found" in r.stderr


def test_no_vehicle_exits_1_naming_where_it_listened(tmp_path: Path) -> None:
    r = gcs("--timeout", "0.5", "status", connect=f"udpin:{LOOPBACK}:0", cwd=tmp_path, timeout_s=20.0)
    assert r.returncode == 1
    assert r.stderr.startswith("smcpilot gcs: error: no HEARTBEAT from a vehicle within 0.5 s wall, listening on 127.0.0.1:")
    assert len(r.stderr.strip().splitlines()) == 1


# ----------------------------------------------------------------------- against the FC
def test_status_json(fc_url: str) -> None:
    r = gcs("status", "--json", connect=fc_url)
    assert r.returncode == 0, r.stderr
    st = json.loads(r.stdout, parse_constant=lambda c: pytest.fail(f"not strict JSON: {c}"))
    assert st["mode"] == "GUIDED" and st["armed"] is False and st["system_id"] == 1
    assert st["landed_state"] == "ON_GROUND"
    assert st["home"]["lat_deg"] == pytest.approx(-35.363261, abs=1e-6)
    assert len(st["position_ned_m"]) == 3 and st["sim_time_s"] > 0
    assert set(st["chi"]) == {"PHI", "THETA", "PSI", "Z"}
    assert st["chi"]["PHI"] is None  # disarmed: no chi_hat (NaN on the wire), null in JSON


def test_status_text(fc_url: str) -> None:
    r = gcs("status", connect=fc_url)
    assert r.returncode == 0, r.stderr
    assert "mode GUIDED" in r.stdout and "disarmed" in r.stdout and "home" in r.stdout


@pytest.mark.slow
def test_param_get_set_list(fc_url: str) -> None:
    r = gcs("param", "get", "WP_RADIUS_M", "--json", connect=fc_url)
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    assert got["name"] == "WP_RADIUS_M" and isinstance(got["value"], float)
    r = gcs("param", "set", "wp_radius_m", "0.8", connect=fc_url)
    assert (r.returncode, r.stdout) == (0, "WP_RADIUS_M 0.800000012\n"), r.stderr
    r = gcs("param", "get", "WP_RADIUS_M", connect=fc_url)
    assert r.stdout == "WP_RADIUS_M 0.800000012\n"
    r = gcs("param", "set", "WP_RADIUS_M", "-3", connect=fc_url)
    assert r.returncode == 1
    assert r.stderr.startswith("smcpilot gcs: error: parameter WP_RADIUS_M: -3 refused, value stays 0.8: ")
    r = gcs("param", "list", "--json", connect=fc_url)
    params = json.loads(r.stdout)
    assert params["WP_RADIUS_M"] == pytest.approx(0.8) and isinstance(params["ARMING_CHECK"], int)
    r = gcs("param", "list", "--parm", connect=fc_url)
    lines = r.stdout.splitlines()
    assert len(lines) == len(params) and "ARMING_CHECK 1" in lines


@pytest.mark.slow
def test_unknown_param_exits_1(fc_url: str) -> None:
    r = gcs("param", "get", "NO_SUCH_PARAM", connect=fc_url)
    assert r.returncode == 1
    assert r.stderr.startswith("smcpilot gcs: error: ") and "NO_SUCH_PARAM" in r.stderr


@pytest.mark.slow
def test_takeoff_while_disarmed_exits_1_with_the_reason(fc_url: str) -> None:
    r = gcs("takeoff", "2", connect=fc_url)
    assert r.returncode == 1
    assert r.stderr.strip() == "smcpilot gcs: error: MAV_CMD_NAV_TAKEOFF refused with MAV_RESULT_DENIED: Takeoff: arm first"


@pytest.mark.slow
def test_watch_once_prints_one_frame(fc_url: str) -> None:
    r = gcs("watch", "--once", connect=fc_url)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert len(lines) == len(render_frame(Telemetry()))
    assert "\x1b" not in r.stdout
    assert "mode GUIDED" in lines[1] and "disarmed" in lines[1]
    assert lines[6].split()[0] == "chi_hat" and lines[7].split()[0] == "sigma"
    assert lines[2].startswith("  position N E D")


def _ctrl_c_reaches_the_child() -> None:
    """preexec_fn: the child takes SIGINT as Ctrl-C even when this test runs with SIGINT ignored
    (a background job of a non-interactive shell inherits SIG_IGN, and Python then keeps it)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.slow
def test_watch_without_a_tty_prints_one_line_per_update_and_ends_on_ctrl_c(fc_url: str) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "lab.cli", "gcs", "--connect", fc_url, "watch", "--rate-hz", "20"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        stdin=subprocess.DEVNULL,
        preexec_fn=_ctrl_c_reaches_the_child,
    )
    try:
        assert proc.stdout is not None
        lines = [proc.stdout.readline() for _ in range(5)]
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert all(line.startswith("t=") and " GUIDED " in line and "\x1b" not in line for line in lines), lines


# ------------------------------------------------------------------- flights and missions
@pytest.mark.slow
def test_fly_from_the_command_line(fresh_fc_url: str) -> None:
    url = fresh_fc_url
    r = gcs("arm", connect=url)
    assert (r.returncode, r.stdout) == (0, "armed\n"), r.stderr
    r = gcs("takeoff", "2", "--wait", connect=url)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("taking off to 2 m\nat ")
    r = gcs("goto", "2", "1", "-2.5", "--yaw", "90", "--wait", "--tol", "0.3", connect=url)
    assert r.returncode == 0, r.stderr
    assert "arrived" in r.stdout
    st = json.loads(gcs("status", "--json", connect=url).stdout)
    assert math.dist(st["position_ned_m"], [2.0, 1.0, -2.5]) < 0.35
    assert st["armed"] is True and st["landed_state"] == "IN_AIR"
    r = gcs("mode", "loiter", connect=url)
    assert (r.returncode, r.stdout) == (0, "mode LOITER\n"), r.stderr
    r = gcs("mode", "STABILIZE", connect=url)
    assert r.returncode == 1 and "MAV_RESULT_DENIED" in r.stderr
    r = gcs("land", "--wait", connect=url)
    assert r.returncode == 0, r.stderr
    assert "landed and disarmed" in r.stdout


@pytest.mark.slow
def test_mission_upload_download_start(fresh_fc_url: str, tmp_path: Path) -> None:
    url = fresh_fc_url
    mission = tmp_path / "mission.toml"
    mission.write_text(MISSION_TOML, encoding="utf-8")
    r = gcs("mission", "start", connect=url)
    assert r.returncode == 1 and "MAV_CMD_MISSION_START refused" in r.stderr
    r = gcs("mission", "upload", str(mission), connect=url)
    assert (r.returncode, r.stdout) == (0, f"uploaded 5 items (+ home) from {mission}\n"), r.stderr
    r = gcs("mission", "download", "--json", connect=url)
    assert r.returncode == 0, r.stderr
    entries = json.loads(r.stdout)
    assert [e["type"] for e in entries] == ["takeoff", "speed", "waypoint", "loiter_time", "land"]
    wp = entries[2]
    assert (wp["north_m"], wp["east_m"]) == pytest.approx((3.0, -1.0), abs=0.02)
    assert (wp["alt_m"], wp["hold_s"], wp["yaw_deg"]) == (2.5, 0.5, 45.0)
    assert entries[1]["speed_mps"] == 2.5
    r = gcs("mission", "download", "--json", "--latlon", connect=url)
    wp_ll = json.loads(r.stdout)[2]
    assert "north_m" not in wp_ll and wp_ll["lat_deg"] > -35.3633 and wp_ll["lon_deg"] < 149.16523
    # TOML download re-uploads unchanged.
    saved = tmp_path / "saved.toml"
    r = gcs("mission", "download", str(saved), connect=url)
    assert (r.returncode, r.stdout) == (0, f"downloaded 5 items to {saved}\n"), r.stderr
    assert [it.type for it in load_mission(saved).items] == [e["type"] for e in entries]
    assert gcs("mission", "upload", str(saved), connect=url).returncode == 0
    assert json.loads(gcs("mission", "download", "--json", connect=url).stdout) == entries
    # Fly it.
    assert gcs("arm", connect=url).returncode == 0
    r = gcs("mission", "start", connect=url)
    assert (r.returncode, r.stdout) == (0, "mission started (AUTO)\n"), r.stderr
    assert json.loads(gcs("status", "--json", connect=url).stdout)["mode"] == "AUTO"
    assert gcs("mission", "clear", connect=url).returncode == 0
    assert json.loads(gcs("mission", "download", "--json", connect=url).stdout) == []


# --------------------------------------------------------------------------- pure: rendering
def test_render_frame_and_line_show_state_position_setpoint_gains_and_last_text() -> None:
    t = Telemetry(
        sim_time_s=12.5,
        system_id=1,
        armed=True,
        mode_number=4,
        position_ned_m=(1.0, -2.0, -3.0),
        velocity_ned_mps=(0.1, 0.0, 0.0),
        attitude_rad=(0.0, 0.0, math.pi / 2),
        setpoint_ned_m=(1.0, -2.0, -3.0),
        chi={"PHI": 0.5, "THETA": 0.6, "PSI": 0.7, "Z": 0.8},
        sigma={"PHI": 0.01, "THETA": -0.02, "PSI": float("nan"), "Z": 0.0},
        statustexts=(StatusText(6, "Takeoff to 3.0 m", 1.0, 0.0),),
    )
    frame = render_frame(t, url="udpin:x")
    text = "\n".join(frame)
    assert "ARMED" in frame[1] and "mode GUIDED" in frame[1]
    assert "1.00   -2.00   -3.00" in frame[2] and "altitude    3.00 m" in frame[2]
    assert "90.00 deg" in frame[4]
    assert "phi 0.500" in frame[6] and "z 0.800" in frame[6]
    assert "theta -0.020" in frame[7] and "psi —" in frame[7]  # no value yet: never "nan"
    assert "nan" not in text
    assert "Takeoff to 3.0 m" in text and "12.50 s" in frame[0]
    line = render_line(t)
    assert "\n" not in line
    assert line.startswith("t=12.50 ARMED GUIDED ned=1.00,-2.00,-3.00 alt=3.00")
    assert line.endswith('msg="Takeoff to 3.0 m"')


def test_render_handles_empty_telemetry() -> None:
    assert all("—" in line for line in render_frame(Telemetry())[1:])
    assert render_line(Telemetry()).startswith("t=- disarmed -")


def test_disarmed_status_says_so_instead_of_nan() -> None:
    """Disarmed, the FC sends χ̂ and σ as NaN (the law's state exists only in flight)."""
    nan = float("nan")
    t = Telemetry(sim_time_s=3.0, system_id=1, armed=False, mode_number=4, position_ned_m=(0.0, 0.0, 0.0),
                  chi=dict.fromkeys(("PHI", "THETA", "PSI", "Z"), nan), sigma=dict.fromkeys(("PHI", "THETA", "PSI", "Z"), nan))  # fmt: skip
    text = render_status(t)
    assert "nan" not in text.lower(), text
    assert "chi_hat  — (disarmed)" in text and "sigma    — (disarmed)" in text
    assert "nan" not in render_line(t).lower()


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pseudo-terminal")
def test_watch_on_a_tty_redraws_in_place(fc_url: str) -> None:
    master, slave = os.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "lab.cli", "gcs", "--connect", fc_url, "watch", "--rate-hz", "20"],
        stdout=slave,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        preexec_fn=_ctrl_c_reaches_the_child,
    )
    os.close(slave)
    data = b""
    try:
        while data.count(b"\x1b[H") < 3:
            chunk = os.read(master, 65536)
            if not chunk:
                break
            data += chunk
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10.0)
        try:
            while chunk := os.read(master, 65536):
                data += chunk
        except OSError:
            pass
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    assert proc.returncode == 0
    assert data.startswith(b"\x1b[?25l\x1b[2J"), data[:40]
    assert data.count(b"\x1b[H") >= 3 and b"mode GUIDED" in data and b"\x1b[K" in data
    assert data.rstrip().endswith(b"\x1b[?25h"), "the cursor comes back on exit"
