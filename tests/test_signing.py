"""MAVLink 2 signing (smcpilot.signing, the link, the FC, the client), against pymavlink as oracle.

pymavlink's own ``MAVLink.setup_signing`` computes the reference signatures and checks ours; the
end-to-end tests run the real FC (lockstep SITL) with ``--signing-key`` and talk to it with a
pymavlink ``mavutil`` connection set up with the same key, both ways.
"""

from __future__ import annotations

import hashlib
import json
import re
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from gcs_helpers import FC_COMPID, FC_SYSID, LOOPBACK, Gcs
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as M

from ground.client import Vehicle
from ground.sitl import Sitl, SitlOptions
from smcpilot.link import MavlinkUdp
from smcpilot.signing import (
    ACCEPT_UNSIGNED,
    MAVLINK_EPOCH_UNIX_S,
    NEW_STREAM_WINDOW,
    OK,
    REJECT_BAD_SIGNATURE,
    REJECT_OLD_TIMESTAMP,
    REJECT_STREAM_WINDOW,
    REJECT_UNSIGNED,
    Signing,
    SigningKeyError,
    TimestampStore,
    key_from_text,
    load_key,
    redact_setup_signing,
    wall_timestamp,
)
from smcpilot.tlog import TlogWriter, read_tlog

pytest_plugins = ("pytester",)

KEY = hashlib.sha256(b"correct horse battery staple").digest()
OTHER_KEY = hashlib.sha256(b"not the key").digest()
NOW_UNIX_S = 1_750_000_000.0  # a fixed wall clock for the unit tests
NOW_TS = wall_timestamp(NOW_UNIX_S)


def pymav(key: bytes | None, *, link_id: int = 0, timestamp: int = NOW_TS, src: tuple[int, int] = (255, 190)) -> M.MAVLink:
    mav = M.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.link_id = link_id
        mav.signing.timestamp = timestamp
        mav.signing.sign_outgoing = True
    return mav


def command(mav: M.MAVLink) -> bytes:
    return mav.command_long_encode(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0).pack(mav)


def signing(key: bytes | None = KEY, now_s: list[float] | None = None, **kw) -> Signing:
    clock = now_s if now_s is not None else [NOW_UNIX_S]
    return Signing(key, wall_s=lambda: clock[0], **kw)


# -- keys --------------------------------------------------------------------------------------
def test_a_key_file_holds_64_hex_digits_or_a_passphrase(tmp_path: Path) -> None:
    hexfile = tmp_path / "hex.key"
    hexfile.write_text(KEY.hex().upper() + "\n", encoding="utf-8")
    assert load_key(hexfile) == KEY
    phrase = tmp_path / "phrase.key"
    phrase.write_text("  correct horse battery staple \n\n", encoding="utf-8")
    # MAVProxy's `signing setup PASSPHRASE`: key = SHA-256 of the passphrase
    assert load_key(phrase) == hashlib.sha256(b"correct horse battery staple").digest()
    assert key_from_text("ab" * 31) == hashlib.sha256(("ab" * 31).encode()).digest()  # 62 digits: a passphrase


@pytest.mark.parametrize(
    ("text", "message"),
    [("", "found 0 non-empty lines"), ("one\ntwo\n", "found 2 non-empty lines"), ("00" * 32, "all-zero key")],
)
def test_bad_key_files_give_one_clear_error(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.key"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SigningKeyError, match=message) as info:
        load_key(path)
    assert str(path) in str(info.value)
    with pytest.raises(SigningKeyError, match="not found"):
        load_key(tmp_path / "missing.key")


def test_wall_timestamp_counts_10_us_since_2015() -> None:
    assert wall_timestamp(MAVLINK_EPOCH_UNIX_S) == 0
    assert wall_timestamp(MAVLINK_EPOCH_UNIX_S + 1.5) == 150_000


# -- sending: byte for byte what pymavlink sends -------------------------------------------------
@pytest.mark.parametrize("link_id", [0, 7])
def test_signed_packets_are_the_bytes_pymavlink_signs(link_id: int) -> None:
    ours = signing()
    ref = pymav(KEY, link_id=link_id, timestamp=NOW_TS + 1, src=(1, 1))  # ours starts after the boot value
    plain = M.MAVLink(None, srcSystem=1, srcComponent=1)
    msgs = [
        lambda mav: mav.heartbeat_encode(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 3),
        lambda mav: mav.attitude_encode(1234, 0.1, -0.2, 3.0, 0.0, 0.5, 0.0),
        lambda mav: mav.statustext_encode(4, b"hello"),
        lambda mav: mav.param_value_encode(b"SMC_Z_KD", 1.5, M.MAV_PARAM_TYPE_REAL32, 100, 3),
    ]
    for build in msgs:
        want = build(ref).pack(ref)
        got = ours.sign(build(plain).pack(plain), link_id)
        assert got == want
        ref.seq = plain.seq = (plain.seq + 1) & 0xFF


def test_the_link_signs_the_fast_path_too_and_pymavlink_accepts_it() -> None:
    ours = signing(now_s=[time.time()])
    rx = pymav(KEY, timestamp=wall_timestamp())
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind((LOOPBACK, 0))
        sock.settimeout(5.0)
        url = f"udpout:{LOOPBACK}:{sock.getsockname()[1]}"
        with MavlinkUdp(url, source_system=1, source_component=1, signing=ours, link_id=3) as link:
            link.send_many([link.mav.attitude_encode(1, 0.1, 0.2, 0.3, 0, 0, 0), link.mav.local_position_ned_encode(1, 1, 2, 3, 0, 0, 0)])
            link.mav.heartbeat_send(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 3)
            seq = link.take_seq()
            from smcpilot.fastcodec import encode_attitude

            link.send_packets([encode_attitude(seq, 1, 1, 2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)])
            got = []
            for _ in range(3):
                got.extend(rx.parse_buffer(sock.recv(65535)) or [])
    assert [m.get_type() for m in got] == ["ATTITUDE", "LOCAL_POSITION_NED", "HEARTBEAT", "ATTITUDE"]
    assert all(m._signed and m._link_id == 3 for m in got)  # pymavlink checked every signature


# -- receiving -----------------------------------------------------------------------------------
def test_pymavlink_signed_packets_pass_and_replays_do_not() -> None:
    ours = signing()
    sender = pymav(KEY)
    first = command(sender)
    assert ours.check(first, M.MAVLINK_MSG_ID_COMMAND_LONG) == OK
    assert ours.check(first, M.MAVLINK_MSG_ID_COMMAND_LONG) == REJECT_OLD_TIMESTAMP  # a replay
    assert ours.check(command(sender), M.MAVLINK_MSG_ID_COMMAND_LONG) == OK
    assert ours.check(command(pymav(OTHER_KEY)), M.MAVLINK_MSG_ID_COMMAND_LONG) == REJECT_BAD_SIGNATURE
    assert ours.timestamp >= NOW_TS


def test_a_forged_future_timestamp_does_not_lock_out_the_real_sender() -> None:
    real = pymav(KEY)
    forged = bytearray(command(pymav(OTHER_KEY, timestamp=NOW_TS + 10**9)))  # right stream, wrong key
    ours = signing()
    assert ours.check(forged, M.MAVLINK_MSG_ID_COMMAND_LONG) == REJECT_BAD_SIGNATURE
    assert ours.streams == {}  # nothing recorded
    assert ours.check(command(real), M.MAVLINK_MSG_ID_COMMAND_LONG) == OK
    # pymavlink records the timestamp before it checks the signature: the same forgery locks
    # the real sender out of a pymavlink receiver (why we do not copy it)
    victim = pymav(KEY)
    victim.signing.sign_outgoing = False
    victim.signing.timestamp = NOW_TS
    assert not victim.check_signature(forged, 255, 190)
    assert not victim.check_signature(bytearray(command(pymav(KEY))), 255, 190)


def test_a_new_stream_is_accepted_only_within_a_minute_of_our_clock() -> None:
    ours = signing()
    window_s = NEW_STREAM_WINDOW / 100_000
    assert ours.check(command(pymav(KEY, timestamp=NOW_TS - int((window_s + 1) * 1e5))), 76) == REJECT_STREAM_WINDOW
    assert ours.check(command(pymav(KEY, timestamp=NOW_TS + int((window_s + 1) * 1e5))), 76) == REJECT_STREAM_WINDOW
    assert ours.check(command(pymav(KEY, timestamp=NOW_TS - int((window_s - 1) * 1e5))), 76) == OK
    # strictly increasing per (system, component, link): another link id is another stream
    assert ours.check(command(pymav(KEY, link_id=1, timestamp=NOW_TS - 5)), 76) == OK
    assert ours.check(command(pymav(KEY, link_id=1, timestamp=NOW_TS - 5)), 76) == REJECT_OLD_TIMESTAMP
    assert len(ours.streams) == 2


def test_only_the_listed_messages_pass_unsigned() -> None:
    ours = signing()
    plain = M.MAVLink(None, srcSystem=255, srcComponent=190)
    hb = plain.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(plain)
    assert ours.check(hb, M.MAVLINK_MSG_ID_HEARTBEAT) == OK
    assert ours.check(command(plain), M.MAVLINK_MSG_ID_COMMAND_LONG) == REJECT_UNSIGNED
    assert M.MAVLINK_MSG_ID_RADIO_STATUS in ACCEPT_UNSIGNED and len(ACCEPT_UNSIGNED) == 2
    off = signing(None)
    assert not off.enabled and off.check(command(plain), M.MAVLINK_MSG_ID_COMMAND_LONG) == OK
    ours.set_key(bytes(32))  # the zero key turns signing off
    assert not ours.enabled and ours.sign(hb, 0) == hb


@settings(max_examples=200, deadline=None)
@given(pos=st.integers(min_value=0), flip=st.integers(min_value=1, max_value=255))
def test_any_changed_byte_of_a_signed_packet_is_rejected_and_changes_nothing(pos: int, flip: int) -> None:
    ours = signing()
    packet = bytearray(command(pymav(KEY)))
    pos %= len(packet)
    if pos in (0, 1, 2):  # framing: the link never hands such a packet to the check
        return
    packet[pos] ^= flip
    assert ours.check(packet, M.MAVLINK_MSG_ID_COMMAND_LONG) != OK
    assert ours.streams == {}


# -- the link ------------------------------------------------------------------------------------
def test_link_drops_and_counts_unsigned_and_badly_signed_packets(tmp_path: Path) -> None:
    ours = signing(now_s=[time.time()])
    with (
        TlogWriter(tmp_path / "rx.tlog") as tlog,
        MavlinkUdp("udpin:127.0.0.1:0", source_system=1, source_component=1, signing=ours, tlog=tlog) as fc,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gcs,
    ):
        plain = M.MAVLink(None, srcSystem=255, srcComponent=190)
        good = pymav(KEY, timestamp=wall_timestamp())
        wrong = pymav(OTHER_KEY, timestamp=wall_timestamp())
        hb = plain.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(plain)
        signed = command(good)
        setup = good.setup_signing_encode(1, 1, list(OTHER_KEY), 123).pack(good)  # a later timestamp
        gcs.sendto(command(plain) + hb + command(wrong) + signed + setup + signed, fc.local_address)  # + a replay
        got = []
        deadline = time.monotonic() + 5
        while len(got) < 3 and time.monotonic() < deadline:
            got += fc.recv(0.2)
        assert [m.get_type() for m, _ in got] == ["HEARTBEAT", "COMMAND_LONG", "SETUP_SIGNING"], fc.counters
        assert [getattr(m, "_signed", False) for m, _ in got] == [False, True, True]
        c = fc.counters
        assert (c.rx_unsigned, c.rx_bad_signature, c.rx_old_timestamp, c.rx_rejected) == (1, 1, 1, 3)
        assert ("127.0.0.1", gcs.getsockname()[1]) in fc.pinned_peers  # signed packets came from it
    logged = [m for _, m in read_tlog(tmp_path / "rx.tlog") if m.get_type() == "SETUP_SIGNING"]
    assert len(logged) == 1 and bytes(logged[0].secret_key) == bytes(32)  # never the key in the log


def test_redacted_setup_signing_still_decodes() -> None:
    mav = M.MAVLink(None, srcSystem=255, srcComponent=190)
    packet = mav.setup_signing_encode(1, 1, list(KEY), 99).pack(mav)
    redacted = redact_setup_signing(packet)
    msg = M.MAVLink(None).decode(bytearray(redacted))  # the CRC was fixed
    assert bytes(msg.secret_key) == bytes(32) and msg.initial_timestamp == 99 and KEY not in redacted
    other = command(mav)
    assert redact_setup_signing(other) is other


# -- timestamps across restarts ------------------------------------------------------------------
def test_timestamps_survive_a_restart_even_when_the_clock_went_back(tmp_path: Path) -> None:
    path = tmp_path / "signing-timestamp"
    (tmp_path / "signing-timestamp.999.tmp").write_text("garbage", encoding="ascii")  # an interrupted save
    clock = [NOW_UNIX_S]
    first = Signing(KEY, store=TimestampStore(path, save_interval_s=0.05), wall_s=lambda: clock[0])
    sent = [first.sign(command(M.MAVLink(None, 1, 1)), 0) for _ in range(5)]
    last_ts = first.timestamp
    time.sleep(0.2)  # the background save runs
    first.close()
    assert int(path.read_text(encoding="ascii")) == last_ts
    assert not list(tmp_path.glob("*.tmp"))
    clock[0] = NOW_UNIX_S - 3600  # the clock went back an hour
    second = Signing(KEY, store=TimestampStore(path, save_interval_s=0.05), wall_s=lambda: clock[0])
    again = second.sign(command(M.MAVLink(None, 1, 1)), 0)
    second.close()
    # a receiver that saw the first run accepts the second
    rx = Signing(KEY, wall_s=lambda: NOW_UNIX_S)
    assert [rx.check(p, 76) for p in sent] == [OK] * 5
    assert rx.check(again, 76) == OK
    assert second.timestamp > last_ts


def test_a_broken_timestamp_file_starts_from_the_clock(tmp_path: Path) -> None:
    path = tmp_path / "ts"
    path.write_text("not a number\n", encoding="ascii")
    assert TimestampStore(path).boot(NOW_TS) == NOW_TS


# -- end to end: the FC with --signing-key, pymavlink's signing on the other side ----------------
def signed_gcs(key: bytes = KEY, link_id: int = 0) -> Gcs:
    """A pymavlink ground station signing with ``key`` (mavutil replaces its encoder, and forgets
    the signing set on it, at the first MAVLink 2 byte it reads: switch it first)."""
    gcs = Gcs()
    gcs.conn.auto_mavlink_version(b"\xfd")
    gcs.conn.setup_signing(key, sign_outgoing=True, link_id=link_id)
    return gcs


@contextmanager
def signed_sitl(tmp_path: Path, gcs: Gcs, key_file: Path | None) -> Iterator[Sitl]:
    opts = SitlOptions.of(lockstep=True, speed=5.0, gcs=f"udp:{LOOPBACK}:{gcs.port}", tlog=tmp_path / "fc.tlog",
                          param_file=tmp_path / "fc.parm", log_dir=tmp_path, watchdog_s=10.0, signing_key=key_file)  # fmt: skip
    with Sitl(opts, echo=lambda line: None) as sitl:
        yield sitl


def fc_address(sitl: Sitl) -> tuple[str, int]:
    assert sitl.gcs_address is not None
    host, port = sitl.gcs_address.rsplit(":", 1)
    return host, int(port)


@pytest.mark.slow
def test_fc_and_pymavlink_setup_signing_exchange_signed_traffic_both_ways(tmp_path: Path) -> None:
    key_file = tmp_path / "gcs.key"
    key_file.write_text("correct horse battery staple\n", encoding="utf-8")
    gcs = signed_gcs(link_id=5)
    intruder = None
    try:
        with signed_sitl(tmp_path, gcs, key_file) as sitl:
            hb = gcs.heartbeat()
            assert hb._signed, "the FC's heartbeat is not signed"
            gcs.run_wall(1.5)
            fc_msgs = [r.msg for r in gcs.log if r.msg.get_srcSystem() == FC_SYSID]
            assert len(fc_msgs) > 20 and all(m._signed for m in fc_msgs)  # everything, ATTITUDE (fast path) too
            assert {"ATTITUDE", "SYS_STATUS", "HEARTBEAT"} <= {m.get_type() for m in fc_msgs}
            # signed commands are obeyed
            mark = gcs.mark()
            gcs.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
            assert gcs.wait("AUTOPILOT_VERSION", since=mark)._signed
            # an unsigned station is heard (its heartbeat) but not obeyed, and counted
            intruder = Gcs(f"udpout:{fc_address(sitl)[0]}:{fc_address(sitl)[1]}", sysid=254)
            for _ in range(5):
                intruder.send_command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
                intruder.send_heartbeat()
                gcs.run_wall(0.1)
            gcs.run_wall(2.5)
            assert not [r for r in intruder.log if r.msg.get_type() in ("COMMAND_ACK", "AUTOPILOT_VERSION")]
            status = gcs.last["SYS_STATUS"]
            assert status.errors_count2 >= 5 and status.errors_comm >= 5, status
            sitl.stop()
            summary = sitl.fc_summary or {}
        assert summary["rx_rejected"]["gcs.rx_unsigned"] >= 5
        assert summary["links"]["gcs"]["rx_bad_signature"] == 0
        saved = tmp_path / "signing-timestamp"
        assert saved.is_file() and int(saved.read_text()) > wall_timestamp() - 60 * 100_000
    finally:
        gcs.close()
        if intruder is not None:
            intruder.close()


@pytest.mark.slow
def test_setup_signing_sets_the_key_when_none_is_set_and_never_logs_it(tmp_path: Path) -> None:
    gcs = Gcs()
    gcs.conn.auto_mavlink_version(b"\xfd")
    try:
        with signed_sitl(tmp_path, gcs, None):
            gcs.heartbeat()
            mark = gcs.mark()
            gcs.mav.setup_signing_send(FC_SYSID, FC_COMPID, list(KEY), wall_timestamp())
            gcs.conn.setup_signing(KEY, sign_outgoing=True)  # as MAVProxy's `signing setup` does
            text = gcs.wait("STATUSTEXT", lambda m: "Signing" in m.text, since=mark)
            assert text.text == "Signing enabled" and text._signed
            mark = gcs.mark()
            gcs.run_wall(1.0)
            assert all(r.msg._signed for r in gcs.log[mark:] if r.msg.get_srcSystem() == FC_SYSID)
            # the zero key (signed with the current one) turns signing off again
            gcs.mav.setup_signing_send(FC_SYSID, FC_COMPID, [0] * 32, 0)
            gcs.conn.disable_signing()  # the FC answers unsigned from now on
            text = gcs.wait("STATUSTEXT", lambda m: "Signing" in m.text, since=mark)
            assert text.text == "Signing disabled"
        logged = [m for _, m in read_tlog(tmp_path / "fc.tlog") if m.get_type() == "SETUP_SIGNING"]
        assert len(logged) == 2 and all(bytes(m.secret_key) == bytes(32) for m in logged)
        assert KEY not in (tmp_path / "fc.tlog").read_bytes()
    finally:
        gcs.close()


@pytest.mark.slow
def test_vehicle_client_and_gcs_cli_talk_to_a_signed_fc(tmp_path: Path) -> None:
    key_file = tmp_path / "gcs.key"
    key_file.write_text(KEY.hex() + "\n", encoding="utf-8")
    gcs = signed_gcs(link_id=9)  # the FC's configured destination (same ids as the Vehicle: another link id)
    try:
        with signed_sitl(tmp_path, gcs, key_file) as sitl:
            gcs.heartbeat()
            host, port = fc_address(sitl)
            with Vehicle(f"udpout:{host}:{port}", signing_key=key_file, connect_timeout_s=10) as v:
                v.wait_for(lambda t: t.sim_time_s is not None and bool(t.comm_errors), timeout_sim_s=5.0, what="SYS_STATUS")
                assert v.params.get("SYSID_THISMAV") == 1.0  # a signed request, a signed answer
                assert v.link_counters.rx_signing_rejected == 0
            with Vehicle(f"udpout:{host}:{port}", connect_timeout_s=10) as unsigned:
                with pytest.raises(Exception):  # noqa: B017 - any refusal: the request is never answered
                    unsigned.params.get("SYSID_THISMAV")
            out = subprocess.run(
                [sys.executable, "-m", "lab.cli", "gcs", "--connect", f"udpout:{host}:{port}", "--signing-key", str(key_file),
                 "status", "--json"],
                capture_output=True, text=True, timeout=60,
            )  # fmt: skip
            assert out.returncode == 0, out.stderr
            comm = json.loads(out.stdout)["comm_errors"]
            assert comm["errors_count2"] >= 1 and comm["errors_comm"] >= comm["errors_count2"], comm
            text = subprocess.run(
                [sys.executable, "-m", "lab.cli", "gcs", "--connect", f"udpout:{host}:{port}", "--signing-key", str(key_file), "status"],
                capture_output=True, text=True, timeout=60,
            )  # fmt: skip
            line = next(line for line in text.stdout.splitlines() if line.strip().startswith("rejected"))
            signing_count = re.search(r"(\d+) signing", line)
            assert signing_count is not None and int(signing_count.group(1)) >= comm["errors_count2"], line  # counts only grow
    finally:
        gcs.close()


# -- listening only where it should ----------------------------------------------------------------
@pytest.mark.parametrize("signed", [False, True])
def test_a_non_loopback_ground_bind_warns_unless_signing_is_on(tmp_path: Path, signed: bool) -> None:
    from sitl_helpers import FcProcess

    key_file = tmp_path / "k"
    key_file.write_text(KEY.hex(), encoding="utf-8")
    args = ["--sim", "udpin:127.0.0.1:0", "--gcs", "udpin:0.0.0.0:0", "--startup-timeout-s", "0.5", "--tlog", str(tmp_path / "fc.tlog")]
    fc = FcProcess(args + (["--signing-key", str(key_file)] if signed else []), cwd=tmp_path)
    try:
        fields = fc.listening()
        assert fields["sim"].startswith("127.0.0.1:")  # the sim link: loopback by default
        fc.wait()
    finally:
        fc.stop()
    warnings = [line for line in fc.all_lines if "not loopback" in line]
    if signed:
        assert not warnings, warnings
    else:
        assert len(warnings) == 1 and "without signing" in warnings[0] and "0.0.0.0" in warnings[0], fc.all_lines
        assert KEY.hex() not in "\n".join(fc.all_lines)


def test_a_bad_key_file_is_a_one_line_error_with_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.key"
    bad.write_text("a\nb\n", encoding="utf-8")
    for argv in (["-m", "fc", "--signing-key", str(bad), "--gcs", "none"], ["-m", "lab.cli", "sitl", "--signing-key", str(bad)]):
        out = subprocess.run([sys.executable, *argv], capture_output=True, text=True, timeout=60, cwd=tmp_path)
        assert out.returncode == 2, (argv, out.stdout, out.stderr)
        lines = out.stderr.strip().splitlines()
        assert len(lines) == 1 and "bad.key" in lines[0] and "2 non-empty lines" in lines[0], out.stderr


@pytest.mark.slow
def test_the_pytest_fixture_signs_with_the_option_or_the_marker(pytester: pytest.Pytester, tmp_path: Path) -> None:
    key_file = tmp_path / "fixture.key"
    key_file.write_text("fixture passphrase\n", encoding="utf-8")
    pytester.makepyfile(
        test_signed=f"""
import pytest

def test_signed(sitl, sitl_process):
    assert sitl_process.options.signing_key is not None and sitl.signing.enabled
    assert sitl.params.get("SYSID_THISMAV") == 1.0      # a signed request, a signed answer
    assert sitl.link_counters.rx_signing_rejected == 0

@pytest.mark.sitl_options(signing_key={str(key_file)!r})
def test_marker(sitl, sitl_process):
    assert sitl.signing.enabled and sitl.params.get("SYSID_THISMAV") == 1.0
"""
    )
    result = pytester.runpytest_subprocess("--sitl-signing-key", str(key_file), "-p", "no:cacheprovider")
    result.assert_outcomes(passed=2)


def test_a_trusted_link_takes_setup_signing_unsigned_and_nothing_else() -> None:
    ours = signing(now_s=[time.time()])
    trusted = ACCEPT_UNSIGNED | {M.MAVLINK_MSG_ID_SETUP_SIGNING}
    with (
        MavlinkUdp("udpin:127.0.0.1:0", source_system=1, source_component=1, signing=ours, accept_unsigned=trusted) as fc,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gcs,
    ):
        plain = M.MAVLink(None, srcSystem=255, srcComponent=190)
        gcs.sendto(plain.setup_signing_encode(1, 1, list(OTHER_KEY), 0).pack(plain) + command(plain), fc.local_address)
        got: list = []
        deadline = time.monotonic() + 5
        while not got and time.monotonic() < deadline:
            got += fc.recv(0.2)
        assert [m.get_type() for m, _ in got] == ["SETUP_SIGNING"] and fc.counters.rx_unsigned == 1
