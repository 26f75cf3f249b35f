"""``smcpilot gcs`` waits for the vehicle's verdict and says it: commands that were refused exit
non-zero with the reason (whole, however long), impossible targets never leave the command line,
``status`` says why arming would fail, and watching while commanding works out of the box.

Real processes: lockstep SITL paced at 4x, ``python -m lab.cli gcs`` subprocesses."""

from __future__ import annotations

import contextlib
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_gcs_cli import LOOPBACK, gcs

from ground.sitl import Sitl, SitlOptions
from smcpilot.protocol import DEFAULT_GCS_URL, FC_GROUND_PORT


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((LOOPBACK, 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def fc_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    tmp = tmp_path_factory.mktemp("verdicts")
    opts = SitlOptions.of(lockstep=True, speed=4.0, gcs=f"udpin:{LOOPBACK}:0", log_dir=tmp, tlog=tmp / "v.tlog")
    with Sitl(opts) as sitl:
        assert sitl.gcs_address
        yield f"udpout:{sitl.gcs_address}"


def _one_line_error(r: subprocess.CompletedProcess[str]) -> str:
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    return lines[0]


@pytest.mark.slow
def test_goto_while_disarmed_exits_1_with_the_reason(fc_url: str) -> None:
    r = gcs("goto", "2", "0", "-2", connect=fc_url)
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert r.stdout == ""  # no "going to ..." for a set-point that was not taken
    assert _one_line_error(r) == "smcpilot gcs: error: set-point refused: not armed (arm and take off first)"


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (("goto", "1e6", "0", "-3"), "goto: 1e+06 m from home is outside the absolute limit 10000 m"),
        (("goto", "0", "0", "5"), "goto: altitude -5 m is below ground (home is 0 m)"),
        (("takeoff", "1000"), "takeoff: altitude 1000 m is above the absolute limit 500 m"),
    ],
)
def test_impossible_targets_are_usage_errors_with_the_shared_rule(args: tuple[str, ...], reason: str) -> None:
    r = gcs(*args, connect=f"udpout:{LOOPBACK}:9", timeout_s=10.0)  # nothing listens: refused before any wait
    assert r.returncode == 2
    assert _one_line_error(r) == f"smcpilot gcs: error: {reason}"


@pytest.mark.slow
def test_the_vehicles_fence_refusal_arrives_whole(fc_url: str) -> None:
    """Beyond 50 characters: the FC sends STATUSTEXT chunks, the client joins them."""
    r = gcs("takeoff", "200", connect=fc_url)
    assert r.returncode == 1
    reason = "Takeoff refused: altitude 200 m is above fence FENCE_ALT_MAX 100 m"
    assert len(reason) > 50
    assert _one_line_error(r) == f"smcpilot gcs: error: MAV_CMD_NAV_TAKEOFF refused with MAV_RESULT_DENIED: {reason}"
    r = gcs("goto", "400", "0", "-3", connect=fc_url)  # inside the absolute limit, outside the fence
    assert r.returncode == 1
    assert _one_line_error(r) == "smcpilot gcs: error: set-point refused: 400 m from home is outside fence FENCE_RADIUS 300 m"


@pytest.mark.slow
def test_status_says_why_arming_would_fail(fc_url: str) -> None:
    assert gcs("mode", "RTL", connect=fc_url).returncode == 0
    try:
        r = gcs("status", connect=fc_url)
        assert r.returncode == 0, r.stderr
        assert "prearm FAIL" in r.stdout
        line = [ln for ln in r.stdout.splitlines() if ln.strip().startswith("prearm ") and "PreArm:" in ln]
        assert line and "RTL" in line[0], r.stdout
    finally:
        assert gcs("mode", "GUIDED", connect=fc_url).returncode == 0
    r = gcs("status", connect=fc_url)
    assert "prearm ok" in r.stdout and "PreArm:" not in r.stdout


# -- watching and commanding at once ----------------------------------------------------------------
@contextlib.contextmanager
def _watch(url: str) -> Iterator[subprocess.Popen[str]]:
    proc = subprocess.Popen([sys.executable, "-m", "lab.cli", "gcs", "--connect", url, "watch", "--rate-hz", "10"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)  # fmt: skip
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().startswith("t="), proc.stderr.read() if proc.stderr else ""
        yield proc
    finally:
        proc.kill()
        proc.communicate(timeout=10)


@pytest.mark.slow
def test_watch_and_command_through_the_fcs_own_ground_port(tmp_path: Path) -> None:
    """The FC sends telemetry to the watcher's port and answers on a known port of its own."""
    watch_port, fc_port = _free_port(), _free_port()
    opts = SitlOptions.of(lockstep=True, speed=4.0, gcs=f"udp:{LOOPBACK}:{watch_port}", log_dir=tmp_path, tlog=tmp_path / "w.tlog",
                          fc_args=("--gcs-port", str(fc_port)))  # fmt: skip
    with Sitl(opts) as sitl:
        assert sitl.gcs_address == f"{LOOPBACK}:{fc_port}"
        with _watch(f"udpin:{LOOPBACK}:{watch_port}"):
            r = gcs("status", connect=f"udpin:{LOOPBACK}:{watch_port}", timeout_s=20)
            assert r.returncode == 2
            assert _one_line_error(r) == (
                f"smcpilot gcs: error: udpin:{LOOPBACK}:{watch_port}: port taken (another ground station listens there,"
                f" e.g. smcpilot gcs watch); use the FC's own ground port: --connect udpout:127.0.0.1:{FC_GROUND_PORT}"
                " (or the gcs= address the FC prints)"
            )
            r = gcs("arm", connect=f"udpout:{LOOPBACK}:{fc_port}")
            assert (r.returncode, r.stdout) == (0, "armed\n"), r.stderr
            r = gcs("disarm", connect=f"udpout:{LOOPBACK}:{fc_port}")
            assert r.returncode == 0, r.stderr


def _ports_free(*ports: int) -> bool:
    for port in ports:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind((LOOPBACK, port))
            except OSError:
                return False
    return True


@pytest.mark.slow
def test_out_of_the_box_watch_then_arm(tmp_path: Path) -> None:
    """The defaults: `smcpilot sitl` (telemetry to 14550, FC on 14551), `gcs watch` holds 14550,
    `gcs arm` finds it taken and talks to the FC's own port."""
    if not _ports_free(14550, FC_GROUND_PORT):
        pytest.skip("the default ground ports 14550/14551 are in use on this machine")
    opts = SitlOptions.of(lockstep=True, speed=4.0, gcs=DEFAULT_GCS_URL, log_dir=tmp_path, tlog=tmp_path / "d.tlog")
    with Sitl(opts) as sitl:
        assert sitl.gcs_address == f"{LOOPBACK}:{FC_GROUND_PORT}"
        with _watch("udpin:127.0.0.1:14550"):
            time.sleep(0.2)
            r = gcs("arm")
            assert (r.returncode, r.stdout) == (0, "armed\n"), r.stderr
            assert "talking to the FC's own ground port (udpout:127.0.0.1:14551)" in r.stderr
            assert gcs("disarm").returncode == 0


@pytest.mark.slow
def test_param_list_prints_units_ranges_and_descriptions(fc_url: str) -> None:
    r = gcs("param", "list", connect=fc_url)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].split() == ["NAME", "VALUE", "UNIT", "RANGE", "DESCRIPTION"]
    fence = next(ln for ln in lines if ln.startswith("FENCE_RADIUS "))
    assert fence.split()[1:6] == ["300", "m", "10", "..", "10000"], fence
    assert "largest horizontal distance of a target from home" in fence
    gcs_fs = next(ln for ln in lines if ln.startswith("FS_GCS_ENABLE "))
    assert "0 (off)" in gcs_fs
    assert "[restart]" in next(ln for ln in lines if ln.startswith("FC_RATE_HZ "))
