"""The ground link's intake (fc.intake): classes read from headers, most important and oldest first,
the least important oldest dropped when full, waits across periods counted; and the link's halves
of a receive (recv_datagrams + parse) and its bounded telemetry fan-out, over real UDP on 127.0.0.1.

The real-time loop's budget itself is exercised with real processes in tests/test_fuzz.py."""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Iterator

import pytest
from pymavlink.dialects.v10 import ardupilotmega as M1
from pymavlink.dialects.v20 import ardupilotmega as M

from fc.intake import CLASS_NAMES, COMMAND, CRITICAL, HEARTBEAT, OTHER, REQUEST, Intake, classify
from smcpilot.link import MavlinkUdp

LOOPBACK = "127.0.0.1"
enc = M.MAVLink(None, srcSystem=255, srcComponent=190)
enc1 = M1.MAVLink(None, srcSystem=255, srcComponent=190)


def cmd(command: int, *params: float) -> bytes:
    p = list(params) + [0.0] * (7 - len(params))
    return enc.command_long_encode(1, 1, command, 0, *p).pack(enc)


def cmd_int(command: int) -> bytes:
    return enc.command_int_encode(1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command, 0, 0, 0, 0, 0, 0, 0, 0, 0).pack(enc)


HEARTBEAT_PKT = enc.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 4).pack(enc)
PARAM_LIST = enc.param_request_list_encode(1, 1).pack(enc)


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        (cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 0), CRITICAL),  # a disarm: param1 0, trailing zeros trimmed
        (cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196), CRITICAL),
        (cmd(M.MAV_CMD_DO_SET_MODE, 1, 5), CRITICAL),
        (cmd(M.MAV_CMD_NAV_LAND), CRITICAL),
        (cmd(M.MAV_CMD_NAV_RETURN_TO_LAUNCH), CRITICAL),
        (cmd_int(M.MAV_CMD_DO_SET_MODE), CRITICAL),
        (enc.set_mode_encode(1, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 9).pack(enc), CRITICAL),
        (cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0), COMMAND),
        (cmd_int(M.MAV_CMD_DO_REPOSITION), COMMAND),
        (enc.param_set_encode(1, 1, b"RTL_ALT_M", 12.0, M.MAV_PARAM_TYPE_REAL32).pack(enc), COMMAND),
        (enc.set_position_target_local_ned_encode(0, 1, 1, M.MAV_FRAME_LOCAL_NED, 0xDF8, 1, 2, -3, 0, 0, 0, 0, 0, 0, 0, 0).pack(enc), COMMAND),
        (enc.mission_count_encode(1, 1, 3, 0).pack(enc), COMMAND),
        (HEARTBEAT_PKT, HEARTBEAT),
        (PARAM_LIST, REQUEST),
        (enc.param_request_read_encode(1, 1, b"RTL_ALT_M", -1).pack(enc), REQUEST),
        (enc.request_data_stream_encode(1, 1, 0, 50, 1).pack(enc), REQUEST),
        (cmd(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION), REQUEST),
        (cmd(M.MAV_CMD_SET_MESSAGE_INTERVAL, 33, 1000), REQUEST),
        (enc.attitude_encode(1, 0, 0, 0, 0, 0, 0).pack(enc), OTHER),
        (b"\x00\x01garbage", OTHER),
        (b"", OTHER),
        (b"\xfd\x09", OTHER),  # a truncated header
        (enc1.command_long_encode(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0, 0, 0, 0).pack(enc1), CRITICAL),  # MAVLink 1
        (enc1.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 4).pack(enc1), HEARTBEAT),
    ],
)
def test_classify_reads_the_class_from_the_header(data: bytes, expected: int) -> None:
    assert CLASS_NAMES[classify(data)] == CLASS_NAMES[expected]


def test_a_datagram_takes_the_class_of_its_most_important_packet() -> None:
    assert classify(PARAM_LIST + HEARTBEAT_PKT + cmd(M.MAV_CMD_NAV_LAND)) == CRITICAL
    assert classify(PARAM_LIST + HEARTBEAT_PKT) == HEARTBEAT
    assert classify(PARAM_LIST + b"\x00garbage" + cmd(M.MAV_CMD_NAV_LAND)) == REQUEST  # the walk stops at garbage
    signed = M.MAVLink(None, srcSystem=255, srcComponent=190)
    signed.signing.secret_key = bytes(32)
    signed.signing.sign_outgoing = True
    signed.signing.link_id = 0
    signed.signing.timestamp = 1
    assert classify(signed.command_long_encode(1, 1, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 3).pack(signed) + cmd(M.MAV_CMD_NAV_LAND)) == CRITICAL


def test_most_important_first_then_oldest() -> None:
    q: Intake[str] = Intake()
    for cls, item in ((REQUEST, "r1"), (HEARTBEAT, "h1"), (COMMAND, "c1"), (REQUEST, "r2"), (CRITICAL, "x1"), (COMMAND, "c2"), (OTHER, "o1")):
        q.put(cls, item, period=0)
    assert [q.pop(0) for _ in range(len(q))] == ["x1", "c1", "c2", "h1", "r1", "r2", "o1"]
    assert q.pop(0) is None
    assert q.counters.deferred == [0] * 5  # all handled in the period they came in


def test_a_full_intake_drops_the_oldest_of_the_least_important_class() -> None:
    q: Intake[str] = Intake(capacity=4)
    q.put(COMMAND, "c1", 0)
    q.put(REQUEST, "r1", 0)
    q.put(REQUEST, "r2", 0)
    q.put(HEARTBEAT, "h1", 0)
    q.put(CRITICAL, "x1", 0)  # full: r1 (the oldest request) goes
    q.put(REQUEST, "r3", 0)  # full: r2 goes, not r3's betters
    q.put(COMMAND, "c2", 0)  # full: r3 goes
    q.put(COMMAND, "c3", 0)  # full: no request left: the heartbeat goes
    c = q.counters
    assert c.dropped == [0, 0, 1, 3, 0]
    assert [q.pop(0) for _ in range(len(q))] == ["x1", "c1", "c2", "c3"]
    assert c.queued == [1, 3, 1, 3, 0] and c.handled == [1, 3, 0, 0, 0]
    assert sum(c.queued) == sum(c.handled) + sum(c.dropped)
    assert c.max_depth == 4


def test_a_critical_command_is_never_dropped_while_anything_else_waits() -> None:
    q: Intake[int] = Intake(capacity=32)
    for i in range(1000):  # a flood of requests with 20 critical commands among them, none handled
        q.put(REQUEST if i % 50 else CRITICAL, i, period=i // 10)
    c = q.counters
    assert c.dropped[CRITICAL] == 0 and c.dropped[REQUEST] == 980 - (32 - 20)
    waiting = [q.pop(100) for _ in range(len(q))]
    assert waiting[:20] == list(range(0, 1000, 50))  # every critical one, oldest first
    assert waiting[20:] == [i for i in range(1000) if i % 50][-12:]  # then the newest requests


def test_waits_across_periods_are_counted_deferred() -> None:
    q: Intake[str] = Intake()
    q.put(COMMAND, "a", period=3)
    q.put(COMMAND, "b", period=3)
    assert q.pop(3) == "a"  # handled in its own period
    assert q.pop(7) == "b"  # waited four periods
    c = q.counters
    assert c.deferred[COMMAND] == 1 and c.max_wait_periods == 4
    d = c.as_dict()
    assert d["queued"] == 2 and d["handled"] == 2 and d["deferred"] == 1 and d["dropped"] == 0
    assert d["by_class"] == {"command": {"queued": 2, "handled": 2, "deferred": 1, "dropped": 0}}
    q.put(OTHER, "c", 8)
    q.drop_all()
    assert len(q) == 0 and q.counters.dropped[OTHER] == 1
    with pytest.raises(ValueError):
        Intake(capacity=0)


# -- the link's halves of a receive, and its telemetry fan-out --------------------------------------
@contextlib.contextmanager
def sockets(n: int) -> Iterator[list[socket.socket]]:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)]
    try:
        for s in socks:
            s.bind((LOOPBACK, 0))
            s.settimeout(2.0)
        yield socks
    finally:
        for s in socks:
            s.close()


def _wait_datagrams(link: MavlinkUdp, n: int) -> list[tuple[bytes, tuple[str, int]]]:
    out: list[tuple[bytes, tuple[str, int]]] = []
    deadline = time.monotonic() + 2.0
    while len(out) < n and time.monotonic() < deadline:
        out += link.recv_datagrams()
    return out


def test_recv_datagrams_then_parse_is_recv() -> None:
    garbage_then_good = b"\x01\x02\x03" + HEARTBEAT_PKT
    with MavlinkUdp(f"udpin:{LOOPBACK}:0", source_system=1, source_component=1) as fc, sockets(1) as (gcs,):
        for data in (HEARTBEAT_PKT, garbage_then_good, b"\xfd\x00garbage", PARAM_LIST + HEARTBEAT_PKT):
            gcs.sendto(data, fc.local_address)
        raw = _wait_datagrams(fc, 4)
        assert [d for d, _ in raw] == [HEARTBEAT_PKT, garbage_then_good, b"\xfd\x00garbage", PARAM_LIST + HEARTBEAT_PKT]
        assert fc.counters.rx_datagrams == 4 and fc.counters.rx_messages == 0  # nothing parsed yet
        assert fc.peers == ()  # nor the sender noted
        msgs = [m.get_type() for d, a in raw for m, _ in fc.parse(d, a)]
        assert msgs == ["HEARTBEAT", "HEARTBEAT", "PARAM_REQUEST_LIST", "HEARTBEAT"]
        assert fc.counters.rx_messages == 4 and fc.counters.rx_bad == 2
        assert fc.peers == (gcs.getsockname(),)


def test_telemetry_to_strangers_is_bounded_and_taken_in_turn() -> None:
    with MavlinkUdp(f"udpin:{LOOPBACK}:0", source_system=1, source_component=1) as fc, sockets(6) as socks:
        for s in socks:
            s.sendto(HEARTBEAT_PKT, fc.local_address)
        for d, a in _wait_datagrams(fc, 6):
            fc.parse(d, a)
        pinned = socks[0]
        fc.pin_peer(pinned.getsockname())
        strangers = socks[1:]
        heard = dict.fromkeys((s.getsockname() for s in strangers), 0)
        for _ in range(10):
            skipped = fc.send_many([fc.mav.heartbeat_encode(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_GENERIC, 0, 0, 4)], others_limit=2)
            assert skipped == 3
            assert pinned.recv(1000)  # the station that matters: every batch
        for s in strangers:
            s.setblocking(False)
            with contextlib.suppress(BlockingIOError):
                while s.recv(1000):
                    heard[s.getsockname()] += 1
        assert sorted(heard.values()) == [4, 4, 4, 4, 4]  # 2 of 5 a batch, in turn: 20 sends, 4 each
        assert fc.send_many([fc.mav.heartbeat_encode(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_GENERIC, 0, 0, 4)]) == 0  # no limit
