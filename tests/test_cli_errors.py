"""User errors on the ``smcpilot`` command line: one line on stderr, exit 2, no traceback; and no
traceback when the reader of stdout goes away (``smcpilot ... | head``).

Every test runs the real command in a new process, as a user would.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TIMEOUT_S = 180.0

PLAN_OK = '[[step]]\nt_s = 0.0\naction = "takeoff"\nalt_m = 2.0\n'
VEHICLE = (ROOT / "examples" / "vehicles" / "heavy-quad.toml").read_text(encoding="utf-8")


def smcpilot(*args: str | Path, cwd: Path, timeout_s: float = TIMEOUT_S) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lab.cli", *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=timeout_s, check=False
    )


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def assert_one_line_usage_error(r: subprocess.CompletedProcess[str], command: str, *needles: str) -> None:
    lines = r.stderr.splitlines()
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"smcpilot {command}: error: "), r.stderr
    assert "Traceback" not in r.stdout + r.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


# ------------------------------------------------------------------------------- exit 2, one line
@pytest.mark.parametrize(
    ("args", "needles"),
    [
        pytest.param(["--duration", "inf"], ["--duration", "inf"], id="duration-inf"),
        pytest.param(["--duration", "nan"], ["--duration"], id="duration-nan"),
        pytest.param(["--duration", "-1"], ["--duration"], id="duration-negative"),
        pytest.param(["--duration", "1", "--gcs", "udp:foo"], ["udp:foo", "PORT"], id="gcs-no-port"),
        pytest.param(["--duration", "1", "--gcs", "tcp:1.2.3.4:5"], ["tcp:1.2.3.4:5"], id="gcs-scheme"),
        pytest.param(["--duration", "1", "--gust-std", "nan"], ["--gust-std"], id="gust-nan"),
        pytest.param(["--duration", "1", "--speed", "inf"], ["--speed"], id="speed-inf"),
    ],
)
def test_sitl_option_errors_are_one_line_exit_2(tmp_path: Path, args: list[str], needles: list[str]) -> None:
    t0 = time.monotonic()
    r = smcpilot("sitl", "--lockstep", "--log-dir", tmp_path / "logs", *args, cwd=tmp_path)
    assert_one_line_usage_error(r, "sitl", *needles)
    assert time.monotonic() - t0 < 60.0  # found before anything is flown
    assert not list((tmp_path / "logs").glob("*.tlog"))


@pytest.mark.slow
def test_sitl_gcs_host_the_fc_cannot_resolve_is_one_line_exit_2(tmp_path: Path) -> None:
    """Found by the FC process itself at start-up (the name is only resolved there): still one line."""
    r = smcpilot("sitl", "--lockstep", "--duration", "1", "--gcs", "udp:no-such-host.invalid:14550",
                 "--log-dir", tmp_path / "logs", cwd=tmp_path)  # fmt: skip
    assert_one_line_usage_error(r, "sitl", "no-such-host.invalid")
    assert r.stdout == ""  # the FC's own report of it is that line, not printed twice


@pytest.mark.parametrize(
    ("option", "text", "needles"),
    [
        pytest.param("--plan", "[[step]\n", ["plan.toml", "TOML"], id="plan-not-toml"),
        pytest.param("--plan", '[[step]]\nt_s = 0.0\naction = "fly"\n', ["plan.toml", "action"], id="plan-action"),
        pytest.param("--plan", PLAN_OK.replace("2.0", "-300.0"), ["plan.toml", "alt_m"], id="plan-range"),
        pytest.param("--vehicle", VEHICLE.replace("mass_kg = 1.5", "mass_kg = -1.5"), ["mass_kg"], id="vehicle-mass"),
        pytest.param("--vehicle", VEHICLE + "wingspan_m = 2\n", ["wingspan_m"], id="vehicle-key"),
        pytest.param("--vehicle", "[vehicle\n", ["TOML"], id="vehicle-not-toml"),
    ],
)
def test_bad_file_contents_are_one_line_exit_2(tmp_path: Path, option: str, text: str, needles: list[str]) -> None:
    path = tmp_path / ("plan.toml" if option == "--plan" else "vehicle.toml")
    path.write_text(text, encoding="utf-8")
    r = smcpilot("sitl", "--lockstep", "--duration", "1", "--gcs", "none", option, path, "--log-dir", tmp_path / "logs", cwd=tmp_path)
    assert_one_line_usage_error(r, "sitl", *needles)
    if option == "--vehicle":
        assert_one_line_usage_error(smcpilot("demo", "--vehicle", path, "--no-plots", cwd=tmp_path), "demo", *needles)


# ------------------------------------------------------------------------------------ gcs status
@pytest.mark.slow
def test_gcs_status_accepts_timeout_after_the_action_and_says_it_waits(tmp_path: Path) -> None:
    """No vehicle, stderr a terminal: it says at once what it waits for, waits --timeout (given
    after the action), erases the notice and leaves one error line; exit 1."""
    import pty
    import select

    url = f"udpin:127.0.0.1:{free_udp_port()}"
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "lab.cli", "gcs", "status", "--timeout", "3", "--connect", url],
        cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=slave,
    )  # fmt: skip
    os.close(slave)
    seen, first_at = b"", None
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < 60:
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                try:
                    chunk = os.read(master, 4096)
                except OSError:
                    break
                if not chunk:
                    break
                seen += chunk
                if first_at is None and b"waiting" in seen:
                    first_at = time.monotonic() - t0
            elif proc.poll() is not None:
                break
        rc = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    text = seen.decode("utf-8", "replace")
    assert f"waiting up to 3 s for a vehicle on {url}" in text, text
    assert first_at is not None and first_at < 2.5  # before the 3 s timeout runs out (Python start-up included)
    assert rc == 1, text
    notice, _, rest = text.partition("\r\x1b[K")  # erased, then the one error line
    assert "waiting" in notice and "waiting" not in rest
    assert rest.strip().count("\n") == 0 and rest.startswith("smcpilot gcs: error: no HEARTBEAT"), rest
    assert "within 3 s" in rest and "Traceback" not in text


def test_gcs_without_a_terminal_prints_only_the_error(tmp_path: Path) -> None:
    r = smcpilot("gcs", "status", "--timeout", "1", "--connect", f"udpin:127.0.0.1:{free_udp_port()}", cwd=tmp_path, timeout_s=60)
    assert r.returncode == 1
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("smcpilot gcs: error: no HEARTBEAT"), r.stderr


def test_gcs_link_options_before_the_action_still_work(tmp_path: Path) -> None:
    r = smcpilot("gcs", "--timeout", "0.5", "--connect", f"udpin:127.0.0.1:{free_udp_port()}", "status", cwd=tmp_path, timeout_s=60)
    assert r.returncode == 1 and "within 0.5 s" in r.stderr, r.stderr
    bad = smcpilot("gcs", "status", "--timeout", "-1", cwd=tmp_path, timeout_s=60)
    assert_one_line_usage_error(bad, "gcs", "--timeout")


# ------------------------------------------------------------------------------ stdout into head
def run_with_stdout_closed(args: list[str | Path], cwd: Path, timeout_s: float = TIMEOUT_S) -> tuple[int, str]:
    """Run ``smcpilot ARGS`` with stdout a real pipe whose reader has already gone (as ``| head -0``)."""
    read_end, write_end = os.pipe()
    os.close(read_end)  # every write to the pipe now fails with EPIPE
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "lab.cli", *map(str, args)], cwd=cwd, stdout=write_end, stderr=subprocess.PIPE,
            text=True, timeout=timeout_s, check=False,
        )  # fmt: skip
    finally:
        os.close(write_end)
    return proc.returncode, proc.stderr


def run_into_head(args: list[str | Path], cwd: Path, lines: int = 1) -> tuple[int, str, str]:
    """``smcpilot ARGS | head -n LINES`` with real processes; (smcpilot's exit code, its stderr, head's output)."""
    head = subprocess.Popen(["head", "-n", str(lines)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert head.stdin is not None
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "lab.cli", *map(str, args)], cwd=cwd, stdout=head.stdin, stderr=subprocess.PIPE, text=True
        )
        head.stdin.close()  # only head reads the pipe now
        _, err = proc.communicate(timeout=TIMEOUT_S)
        assert head.stdout is not None
        out = head.stdout.read()
        head.wait(timeout=TIMEOUT_S)
    finally:
        for p in (head,):
            if p.poll() is None:
                p.kill()
                p.wait()
    return proc.returncode, err, out


@pytest.fixture(scope="module")
def flight_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("pipe")
    plan = tmp / "plan.toml"
    plan.write_text(PLAN_OK, encoding="utf-8")
    r = smcpilot("sitl", "--lockstep", "--duration", "3", "--gcs", "none", "--plan", plan, "--log-dir", tmp / "logs", cwd=tmp)
    assert r.returncode == 0, r.stdout + r.stderr
    (log,) = (tmp / "logs").glob("*.tlog")
    return log


def test_log_summary_into_a_closed_pipe_has_no_traceback(flight_log: Path, tmp_path: Path) -> None:
    rc, err = run_with_stdout_closed(["log", "summary", flight_log], tmp_path)
    assert "Traceback" not in err and "BrokenPipe" not in err, err
    assert rc == 0 and err == "", err


def test_log_summary_into_head(flight_log: Path, tmp_path: Path) -> None:
    rc, err, out = run_into_head(["log", "summary", flight_log, "--json", "-"], tmp_path, lines=1)
    assert out == "{\n"
    assert rc == 0 and "Traceback" not in err, err


@pytest.mark.slow
def test_paper_into_a_closed_pipe_has_no_traceback_and_still_writes_its_results(tmp_path: Path) -> None:
    result = tmp_path / "p.json"
    rc, err = run_with_stdout_closed(["paper", "--controller", "pid_smc", "--no-figures", "--json", result], tmp_path)
    assert "Traceback" not in err and "BrokenPipe" not in err, err
    assert rc == 0, err
    assert json.loads(result.read_text(encoding="utf-8"))  # the command went on to its end


@pytest.mark.slow
def test_mission_run_is_not_aborted_when_stdout_goes_away(tmp_path: Path) -> None:
    mission = tmp_path / "m.toml"
    mission.write_text(
        'name = "pipe"\n[[item]]\ntype = "takeoff"\nalt_m = 2.0\n[[item]]\ntype = "land"\n'
        '[[expect]]\nkind = "landed"\nby_s = 30.0\n',
        encoding="utf-8",
    )
    report = tmp_path / "report.json"
    rc, err, out = run_into_head(["mission", "run", mission, "--json", report, "--no-plots", "--out", tmp_path / "out"], tmp_path)
    assert "Traceback" not in err and "BrokenPipe" not in err, err
    assert out.count("\n") == 1
    assert rc == 0, err
    data = json.loads(report.read_text(encoding="utf-8"))
    assert data["passed"] is True and data["finished"] is True


def test_pipe_safe_stdout_is_still_the_stream_for_everything_else() -> None:
    """Commands that reconfigure stdout (``smcpilot bench``) or ask for its encoding still can."""
    from lab.cli import PipeSafeStdout

    read_end, write_end = os.pipe()
    with open(write_end, "w", encoding="utf-8") as raw:
        out = PipeSafeStdout(raw)  # type: ignore[arg-type]
        out.reconfigure(line_buffering=True)  # type: ignore[attr-defined]
        assert raw.line_buffering and out.encoding == "utf-8"
        os.close(read_end)  # the reader goes away
        out.write("x" * 100_000)  # more than a pipe holds: EPIPE, then silence
        out.flush()
        assert out.broken
        out.write("later\n")  # still fine
        assert not out.isatty()
