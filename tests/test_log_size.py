"""Flight logs that do not fill the disk, a progress line that shows, and a log summary that agrees
with the run's own figures. Real flights (``smcpilot sitl`` in lockstep), real files, pymavlink's
own reader and ``mavlogdump.py``."""

from __future__ import annotations

import gzip
import json
import os
import pty
import re
import select
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from ground.logs.housekeeping import KEEP_PLAIN, clean_logs, compress_old_flights, flight_stem
from ground.logs.progress import ProgressLine, TlogFollower, format_progress
from smcpilot.tlog import TlogWriter, read_tlog

PLAN = '[[step]]\nt_s = 0.0\naction = "takeoff"\nalt_m = 2.0\n'
ENDED = re.compile(r"SITL ended: ([0-9.]+) simulated s in [0-9.]+ wall s, (\d+) control ticks, (\d+) overruns")


def smcpilot(*args: str | Path, cwd: Path, **kw) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "lab.cli", *map(str, args)], cwd=cwd, capture_output=True, text=True,
                          timeout=300, check=False, **kw)  # fmt: skip


def fly(tmp: Path, log_dir: Path, *extra: str, duration_s: float = 3.0) -> tuple[subprocess.CompletedProcess[str], Path]:
    plan = tmp / "plan.toml"
    plan.write_text(PLAN, encoding="utf-8")
    before = set(log_dir.glob("*.tlog")) if log_dir.is_dir() else set()
    r = smcpilot("sitl", "--duration", f"{duration_s:g}", "--gcs", "none", "--plan", plan, "--log-dir", log_dir, *extra, cwd=tmp)
    assert r.returncode == 0, r.stdout + r.stderr
    (log,) = set(log_dir.glob("*.tlog")) - before
    return r, log


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> tuple[subprocess.CompletedProcess[str], Path]:
    tmp = tmp_path_factory.mktemp("flight")
    return fly(tmp, tmp / "logs", "--lockstep")


def summary_json(log: Path, cwd: Path) -> dict:
    r = smcpilot("log", "summary", log, "--json", "-", cwd=cwd)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


# ----------------------------------------------------------------------------- summary vs the run
@pytest.mark.slow
def test_log_summary_agrees_with_the_lockstep_run(flight, tmp_path: Path) -> None:
    r, log = flight
    m = ENDED.search(r.stdout)
    assert m, r.stdout
    s = summary_json(log, tmp_path)
    assert s["duration_s"] == pytest.approx(float(m.group(1)), abs=0.005)
    assert s["overruns"] == int(m.group(3)) == 0
    assert s["message_counts"]["HIL_ACTUATOR_CONTROLS"] == int(m.group(2))


@pytest.mark.slow
def test_log_summary_agrees_with_a_real_time_run(tmp_path: Path) -> None:
    r, log = fly(tmp_path, tmp_path / "logs", duration_s=2.0)
    m = ENDED.search(r.stdout)
    assert m, r.stdout
    s = summary_json(log, tmp_path)
    # The simulator's clock is the simulated time; the FC's count of late ticks is in the log.
    assert s["duration_s"] == pytest.approx(float(m.group(1)), abs=0.05)
    assert s["overruns"] == int(m.group(3))


# ------------------------------------------------------------------------------------ compression
@pytest.mark.slow
def test_compressed_log_is_smaller_and_reads_the_same(flight, tmp_path: Path) -> None:
    _, original = flight
    plain = tmp_path / original.name
    plain.write_bytes(original.read_bytes())
    size = plain.stat().st_size
    want = summary_json(plain, tmp_path)
    r = smcpilot("log", "compress", plain, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    gz = tmp_path / (original.name + ".gz")
    assert gz.is_file() and not plain.exists()
    assert gz.stat().st_size < 0.5 * size, (gz.stat().st_size, size)
    got = summary_json(gz, tmp_path)
    for key in ("log", "path"):
        want.pop(key), got.pop(key)
    assert got == want
    assert gzip.decompress(gz.read_bytes()) == original.read_bytes()  # gunzip -k gives the log back
    plots = smcpilot("plot", gz, cwd=tmp_path)
    assert plots.returncode == 0, plots.stderr
    assert (tmp_path / f"{flight_stem(gz)}-plots" / "track.png").is_file()


@pytest.mark.slow
def test_plain_log_is_read_by_pymavlink_and_mavlogdump(flight, tmp_path: Path) -> None:
    _, log = flight
    conn = mavutil.mavlink_connection(str(log))
    n = 0
    while conn.recv_match() is not None:
        n += 1
    conn.close()
    assert n == sum(1 for _ in read_tlog(log))
    dump = subprocess.run([sys.executable, "-m", "pymavlink.tools.mavlogdump", "--types", "NAMED_VALUE_INT", str(log)],
                          capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
    assert dump.returncode == 0, dump.stderr
    assert "OVERRUN" in dump.stdout  # the run's own overrun count, logged at its end


def copies(src: Path, directory: Path, n: int, *, age_s: float) -> list[Path]:
    """``n`` copies of a flight log with decreasing modification times (the first is newest)."""
    directory.mkdir(parents=True, exist_ok=True)
    out = []
    now = time.time()
    for i in range(n):
        p = directory / f"sitl-old-{i}.tlog"
        p.write_bytes(src.read_bytes())
        (directory / f"sitl-old-{i}.scenario.toml").write_text("# scenario\n", encoding="utf-8")
        os.utime(p, (now - age_s - i, now - age_s - i))
        out.append(p)
    return out


@pytest.mark.slow
def test_sitl_compresses_older_flights_and_keeps_the_newest_plain(flight, tmp_path: Path) -> None:
    _, src = flight
    logs = tmp_path / "logs"
    old = copies(src, logs, KEEP_PLAIN + 1, age_s=3600)
    (logs / "fc-params.parm").write_text("SMC_Z_KP 6\n", encoding="utf-8")
    r, new = fly(tmp_path, logs, "--lockstep", duration_s=1.0)
    assert "compressed 2 older flight log(s)" in r.stdout, r.stdout
    plain = sorted(p.name for p in logs.glob("*.tlog"))
    assert plain == sorted([new.name] + [p.name for p in old[: KEEP_PLAIN - 1]])
    assert sorted(p.name for p in logs.glob("*.tlog.gz")) == sorted(p.name + ".gz" for p in old[KEEP_PLAIN - 1 :])
    assert (logs / "fc-params.parm").read_text(encoding="utf-8") == "SMC_Z_KP 6\n"


@pytest.mark.slow
def test_a_log_still_being_written_is_never_compressed(flight, tmp_path: Path) -> None:
    _, src = flight
    logs = tmp_path / "logs"
    copies(src, logs, KEEP_PLAIN + 3, age_s=0)  # all "just written"
    assert compress_old_flights(logs) == []
    assert len(compress_old_flights(logs, now_s=time.time() + 3600)) == 3


@pytest.mark.slow
def test_log_clean_deletes_all_but_the_newest(flight, tmp_path: Path) -> None:
    _, src = flight
    logs = tmp_path / "logs"
    old = copies(src, logs, 4, age_s=100)
    (logs / f"{old[3].stem}-plots").mkdir()
    (logs / f"{old[3].stem}-plots" / "track.png").write_bytes(b"x")
    (logs / f"{old[3].stem}.parm").write_text("X 1\n", encoding="utf-8")  # that run's own parameters
    (logs / "kept.parm").write_text("X 1\n", encoding="utf-8")  # kept with --param-file: no flight's
    dry = smcpilot("log", "clean", logs, "--keep", "2", "--dry-run", cwd=tmp_path)
    assert dry.returncode == 0 and "would delete" in dry.stdout and len(list(logs.glob("*.tlog"))) == 4
    r = smcpilot("log", "clean", logs, "--keep", "2", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in logs.glob("*.tlog")) == sorted(p.name for p in old[:2])
    assert not (logs / f"{old[3].stem}-plots").exists() and not (logs / f"{old[3].stem}.scenario.toml").exists()
    assert not (logs / f"{old[3].stem}.parm").exists()
    assert (logs / "kept.parm").is_file()
    assert clean_logs(logs, keep=5).touched == []
    bad = smcpilot("log", "clean", tmp_path / "nope", cwd=tmp_path)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "nope" in bad.stderr


# ------------------------------------------------------------------------------------ progress
@pytest.mark.slow
def test_no_progress_line_in_a_ci_log_unless_asked(flight) -> None:
    r, _ = flight  # stderr was a pipe, not a terminal
    assert "progress" not in r.stderr and "\r" not in r.stderr + r.stdout and "\x1b" not in r.stderr + r.stdout


@pytest.mark.slow
def test_progress_when_asked_is_plain_lines(tmp_path: Path) -> None:
    r, _ = fly(tmp_path, tmp_path / "logs", "--lockstep", "--speed", "5", "--progress", duration_s=30.0)  # >= 6 wall s
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("progress: ")]
    assert lines, r.stderr
    assert "\r" not in r.stderr and "\x1b" not in r.stderr
    m = re.match(r"progress: sim +([0-9.]+)/30 s \( *\d+ %\) +([0-9.]+)x real time +ETA +\d+ s", lines[0])
    assert m, lines[0]
    assert 0 < float(m.group(1)) <= 30.0 and 0.5 < float(m.group(2)) < 8.0  # paced at 5x


@pytest.mark.slow
def test_progress_line_on_a_terminal_is_redrawn_and_erased(tmp_path: Path) -> None:
    """stderr is a real pseudo-terminal: the line is drawn in place with \\r and erased at the end."""
    master, slave = pty.openpty()
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN, encoding="utf-8")
    proc = subprocess.Popen(
        [sys.executable, "-m", "lab.cli", "sitl", "--lockstep", "--speed", "5", "--duration", "5", "--gcs", "none",
         "--plan", str(plan), "--log-dir", str(tmp_path / "logs")],
        cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=slave,
    )  # fmt: skip
    os.close(slave)
    seen = b""
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.5)
            if ready:
                try:
                    chunk = os.read(master, 4096)
                except OSError:  # the terminal closed: the process has ended
                    break
                if not chunk:
                    break
                seen += chunk
            elif proc.poll() is not None:
                break
        assert proc.wait(timeout=60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    text = seen.decode("utf-8", "replace")
    assert re.search(r"\rsim +[0-9.]+/5 s .*x real time", text), text
    assert text.rstrip("\n").endswith("\r\x1b[K")  # erased, no stale line left behind


def test_follower_reads_only_whole_records(tmp_path: Path) -> None:
    path = tmp_path / "grow.tlog"
    follower = TlogFollower(path)
    assert follower.poll() is None  # not there yet
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    packet = mav.heartbeat_encode(2, 3, 0, 0, 4).pack(mav)
    with TlogWriter(path, buffer_bytes=0) as w:
        w.write(1_000_000, packet)
        assert follower.poll() == 1_000_000
        w.write(3_500_000, packet)
        with open(path, "ab") as raw:  # half a record, as a reader may see mid-write
            raw.write((4_000_000).to_bytes(8, "big") + packet[:5])
        assert follower.poll() == 3_500_000
    assert follower.first_us == 1_000_000
    assert format_progress(2.5, 1.0, 10.0) == "sim    2.5/10 s ( 25 %)    2.5x real time  ETA    3 s"
    assert format_progress(2.5, 1.0, None) == "sim    2.5 s    2.5x real time"


def test_progress_line_stops_cleanly_without_records(tmp_path: Path) -> None:
    import io

    out = io.StringIO()
    line = ProgressLine(tmp_path / "never.tlog", 10.0, out, tty=True, period_s=0.01).start()
    time.sleep(0.05)
    line.stop()
    assert out.getvalue() == ""  # nothing to show, nothing drawn, nothing to erase
