"""TlogWriter / read_tlog: the standard .tlog format, read back by us and by pymavlink's mavlogdump."""

from __future__ import annotations

import json
import math
import signal
import struct
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

import smcpilot.tlog as tlog_module
from smcpilot.errors import TlogError, TlogFormatError
from smcpilot.link import MavlinkUdp
from smcpilot.tlog import TlogWriter, read_tlog

MAVLOGDUMP_SCRIPT = Path(sys.executable).parent / "mavlogdump.py"


def sample_records() -> list[tuple[int, bytes]]:
    """(time_us, packet) pairs: MAVLink 2, MAVLink 1, a signed packet, NaN and extreme values."""
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    records = []
    messages = [
        mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 81, 4, 4),
        mav.attitude_encode(10, 0.1, -0.2, math.pi, math.nan, math.inf, 0.0),
        mav.local_position_ned_encode(12, 1.0, 2.0, -3.0, 0.0, 0.0, 0.0),
        mav.hil_actuator_controls_encode(2**40, [0.5] * 4 + [0.0] * 12, 0, 1),
        mav.statustext_encode(mavlink.MAV_SEVERITY_INFO, b"smcpilot ready"),
    ]
    for i, msg in enumerate(messages):
        records.append((1_000_000 + 2_000 * i, msg.pack(mav)))
        mav.seq += 1
    records.append((1_700_000_000_123_457, mav.attitude_encode(99, 0, 0, 0, 0, 0, 0).pack(mav, force_mavlink1=True)))
    mav.seq += 1
    mav.signing.secret_key = bytes(32)
    mav.signing.sign_outgoing = True
    records.append((1_700_000_000_123_999, mav.system_time_encode(5, 6).pack(mav)))
    return records


def write_records(path: Path, records: list[tuple[int, bytes]], **kwargs: int) -> None:
    with TlogWriter(path, **kwargs) as writer:
        for time_us, packet in records:
            writer.write(time_us, packet)


def test_file_layout_is_big_endian_timestamp_then_raw_packet(tmp_path: Path) -> None:
    records = sample_records()
    path = tmp_path / "layout.tlog"
    write_records(path, records)
    assert path.read_bytes() == b"".join(struct.pack(">Q", t) + p for t, p in records)


def test_round_trip_through_read_tlog(tmp_path: Path) -> None:
    records = sample_records()
    path = tmp_path / "round.tlog"
    write_records(path, records)
    read = list(read_tlog(path))
    assert [t for t, _ in read] == [t for t, _ in records]
    assert [bytes(m.get_msgbuf()) for _, m in read] == [p for _, p in records]
    types = [m.get_type() for _, m in read]
    assert types == ["HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED", "HIL_ACTUATOR_CONTROLS", "STATUSTEXT", "ATTITUDE", "SYSTEM_TIME"]
    assert math.isnan(read[1][1].rollspeed) and read[1][1].yaw == pytest.approx(math.pi)
    assert read[3][1].time_usec == 2**40
    assert read[0][1]._timestamp == pytest.approx(1.0)


def test_read_tlog_across_read_chunk_boundaries(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    records = sample_records() * 3
    path = tmp_path / "chunks.tlog"
    write_records(path, records)
    monkeypatch.setattr(tlog_module, "_READ_CHUNK_BYTES", 7)
    assert [t for t, _ in read_tlog(path)] == [t for t, _ in records]


@pytest.mark.parametrize(
    "command",
    [
        pytest.param([sys.executable, "-m", "pymavlink.tools.mavlogdump"], id="module"),
        pytest.param(
            [sys.executable, str(MAVLOGDUMP_SCRIPT)],
            id="console-script",
            marks=pytest.mark.skipif(not MAVLOGDUMP_SCRIPT.exists(), reason="mavlogdump.py not installed beside python"),
        ),
    ],
)
def test_mavlogdump_reads_our_tlog(tmp_path: Path, command: list[str]) -> None:
    records = sample_records()
    path = tmp_path / "dump.tlog"
    write_records(path, records)
    result = subprocess.run(
        [*command, "--format", "json", "--show-source", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    lines = [json.loads(line) for line in result.stdout.splitlines() if line.startswith("{")]
    expected = [(t, m.get_type(), m.to_dict()) for t, m in read_tlog(path)]
    assert len(lines) == len(expected)
    for line, (time_us, msg_type, fields) in zip(lines, expected):
        assert line["meta"]["type"] == msg_type
        assert round(line["meta"]["timestamp"] * 1e6) == time_us
        assert (line["meta"]["srcSystem"], line["meta"]["srcComponent"]) == (1, 1)
        if msg_type == "ATTITUDE":
            assert line["data"]["time_boot_ms"] == fields["time_boot_ms"]
            assert line["data"]["roll"] == pytest.approx(fields["roll"])
    assert lines[1]["data"]["rollspeed"] != lines[1]["data"]["rollspeed"]  # NaN survives
    assert lines[4]["data"]["text"] == "smcpilot ready"


def run_lockstep_exchange(path: Path) -> None:
    """A small FC <-> sim exchange over loopback, logged with a simulated clock."""
    sim_time_us = [0]
    with TlogWriter(path) as tlog:
        with MavlinkUdp("udpin:127.0.0.1:0", source_system=1, source_component=1, tlog=tlog, clock_us=lambda: sim_time_us[0]) as fc:
            with MavlinkUdp(f"udpout:127.0.0.1:{fc.local_address[1]}", source_system=2, source_component=1) as sim:
                for step in range(50):
                    sim_time_us[0] = step * 2_000
                    sim.send(sim.mav.hil_actuator_controls_encode(sim_time_us[0], [0.1 * step] * 16, 0, 0))
                    received: list[object] = []
                    while not received:
                        received = fc.recv(2.0)
                    fc.send_many(
                        [
                            fc.mav.attitude_encode(step * 2, 0.01 * step, 0.0, 0.0, 0.0, 0.0, 0.0),
                            fc.mav.local_position_ned_encode(step * 2, 0.0, 0.0, -0.1 * step, 0.0, 0.0, 0.0),
                        ]
                    )


def test_logs_are_bit_for_bit_deterministic_with_an_injected_clock(tmp_path: Path) -> None:
    first, second = tmp_path / "a.tlog", tmp_path / "b.tlog"
    run_lockstep_exchange(first)
    run_lockstep_exchange(second)
    assert first.read_bytes() == second.read_bytes()
    records = list(read_tlog(first))
    assert len(records) == 150
    assert [t for t, _ in records[:6]] == [0, 0, 0, 2000, 2000, 2000]


def test_small_buffer_hands_only_whole_records_to_the_os(tmp_path: Path) -> None:
    records = sample_records()
    path = tmp_path / "small.tlog"
    boundaries = {0}
    total = 0
    for _time_us, packet in records:
        total += 8 + len(packet)
        boundaries.add(total)
    with TlogWriter(path, buffer_bytes=100) as writer:
        for time_us, packet in records:
            writer.write(time_us, packet)
            assert path.stat().st_size in boundaries
        writer.flush()
        assert path.stat().st_size == total
        assert writer.records_written == len(records)


def test_flush_makes_records_readable_before_close(tmp_path: Path) -> None:
    records = sample_records()
    path = tmp_path / "flush.tlog"
    writer = TlogWriter(path)
    try:
        writer.write_many(5, [p for _, p in records])
        assert path.stat().st_size == 0  # still buffered
        writer.flush(fsync=True)
        assert [t for t, _ in read_tlog(path)] == [5] * len(records)
    finally:
        writer.close()


def test_closed_writer_raises_and_close_is_idempotent(tmp_path: Path) -> None:
    writer = TlogWriter(tmp_path / "closed.tlog")
    writer.close()
    writer.close()
    assert writer.closed
    with pytest.raises(TlogError, match="closed"):
        writer.write(0, b"\xfe")
    with pytest.raises(TlogError, match="closed"):
        writer.flush()


@pytest.mark.parametrize("bad_time", [-1, 2**64, 1.5])
def test_bad_timestamp_raises_tlog_error(tmp_path: Path, bad_time: object) -> None:
    with TlogWriter(tmp_path / "t.tlog") as writer:
        with pytest.raises(TlogError, match="timestamp"):
            writer.write(bad_time, b"\xfe")  # type: ignore[arg-type]


def test_unwritable_path_raises_tlog_error(tmp_path: Path) -> None:
    with pytest.raises(TlogError, match="no-such-dir"):
        TlogWriter(tmp_path / "no-such-dir" / "x.tlog")


def test_corrupt_and_truncated_logs_raise_after_the_good_prefix(tmp_path: Path) -> None:
    records = sample_records()
    good = b"".join(struct.pack(">Q", t) + p for t, p in records[:2])
    truncated = tmp_path / "truncated.tlog"
    truncated.write_bytes(good + struct.pack(">Q", 9) + records[2][1][:-3])
    seen = []
    with pytest.raises(TlogFormatError, match="cut short"):
        for time_us, _ in read_tlog(truncated):
            seen.append(time_us)
    assert seen == [t for t, _ in records[:2]]

    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    (tmp_path / "crc.tlog").write_bytes(bytes(bad_crc))
    with pytest.raises(TlogFormatError, match="CRC"):
        list(read_tlog(tmp_path / "crc.tlog"))

    (tmp_path / "magic.tlog").write_bytes(good + struct.pack(">Q", 1) + b"\x00" * 20)
    with pytest.raises(TlogFormatError, match="0x00"):
        list(read_tlog(tmp_path / "magic.tlog"))


CHILD = textwrap.dedent(
    """
    import signal, sys
    from pymavlink.dialects.v20 import ardupilotmega as mavlink
    from smcpilot.tlog import TlogWriter

    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(143))
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    writer = TlogWriter(sys.argv[1])
    try:
        for i in range(1000):
            writer.write(i, mav.attitude_encode(i, 0, 0, 0, 0, 0, 0).pack(mav))
        print("ready", flush=True)
        sys.stdin.readline()
    finally:
        writer.close()
    """
)


@pytest.mark.slow
@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_sigterm_loses_nothing_when_the_owner_closes_in_finally(tmp_path: Path) -> None:
    path = tmp_path / "term.tlog"
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert child.stdout is not None
        assert child.stdout.readline().strip() == "ready"
        assert path.stat().st_size < 1000 * 48  # records were still buffered
        child.send_signal(signal.SIGTERM)
        assert child.wait(timeout=60) == 143
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert [t for t, _ in read_tlog(path)] == list(range(1000))
