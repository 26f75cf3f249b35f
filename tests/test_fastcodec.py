"""smcpilot.fastcodec produces and reads exactly what pymavlink does, for random field values."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot import fastcodec
from smcpilot.protocol import FC_COMPONENT_ID, SIM_COMPONENT_ID

U8 = st.integers(0, 0xFF)
U32 = st.integers(0, 2**32 - 1)
U64 = st.integers(0, 2**64 - 1)
#: float32-representable values (NaN, ±inf, ±0, subnormals, extremes) with plenty of zeros, so
#: that MAVLink 2 trailing-zero truncation is exercised down to the 1-byte minimum payload.
F32 = st.one_of(st.just(0.0), st.floats(width=32), st.sampled_from([math.nan, math.inf, -math.inf, -0.0, 3.4028234663852886e38]))
#: any Python float, including ones float32 cannot hold (both encoders must then fail alike).
F64 = st.one_of(F32, st.floats(allow_nan=True, allow_infinity=True))


def reference(msg: mavlink.MAVLink_message, seq: int, system: int, component: int) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=component)
    mav.seq = seq
    return msg.pack(mav)


def same_value(a: object, b: object) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return struct.pack("<d", a) == struct.pack("<d", b) or (math.isnan(a) and math.isnan(b))
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same_value(x, y) for x, y in zip(a, b))
    return a == b


def assert_same_message(fast: mavlink.MAVLink_message, slow: mavlink.MAVLink_message) -> None:
    assert type(fast) is type(slow)
    fast_vars, slow_vars = vars(fast), vars(slow)
    assert fast_vars.keys() == slow_vars.keys()
    for key, slow_value in slow_vars.items():
        if key == "_header":
            assert vars(fast_vars[key]) == vars(slow_value)
        else:
            assert same_value(fast_vars[key], slow_value), key


def assert_round_trip(packet: bytes) -> None:
    slow = mavlink.MAVLink(None).decode(bytearray(packet))
    fast = fastcodec.decode_packet(packet)
    assert fast is not None
    assert_same_message(fast, slow)


@settings(max_examples=400, deadline=None)
@given(seq=U8, system=U8, component=U8, t=U32, values=st.lists(F32, min_size=6, max_size=6))
@example(seq=0, system=0, component=0, t=0, values=[0.0] * 6)  # all-zero payload -> 1 byte
@example(seq=255, system=255, component=255, t=2**32 - 1, values=[math.nan, math.inf, -math.inf, -0.0, 1e-45, 0.0])
def test_attitude_and_local_position_ned_match_pymavlink(seq: int, system: int, component: int, t: int, values: list[float]) -> None:
    mav = mavlink.MAVLink(None)
    for encode_msg, encode_fast in (
        (mav.attitude_encode, fastcodec.encode_attitude),
        (mav.local_position_ned_encode, fastcodec.encode_local_position_ned),
    ):
        msg = encode_msg(t, *values)
        expected = reference(msg, seq, system, component)
        assert encode_fast(seq, system, component, t, *values) == expected
        assert fastcodec.pack_message(msg, seq, system, component) == expected
        assert_round_trip(expected)


@settings(max_examples=400, deadline=None)
@given(seq=U8, system=U8, component=U8, t=U64, controls=st.lists(F32, min_size=16, max_size=16), mode=U8, flags=U64)
@example(seq=0, system=1, component=1, t=0, controls=[0.0] * 16, mode=0, flags=0)
@example(seq=7, system=1, component=1, t=2**64 - 1, controls=[0.5] * 4 + [0.0] * 12, mode=0, flags=2**64 - 1)
def test_hil_actuator_controls_match_pymavlink(
    seq: int, system: int, component: int, t: int, controls: list[float], mode: int, flags: int
) -> None:
    msg = mavlink.MAVLink(None).hil_actuator_controls_encode(t, controls, mode, flags)
    expected = reference(msg, seq, system, component)
    assert fastcodec.encode_hil_actuator_controls(seq, system, component, t, controls, mode, flags) == expected
    assert fastcodec.pack_message(msg, seq, system, component) == expected
    assert_round_trip(expected)


@settings(max_examples=300, deadline=None)
@given(values=st.lists(F64, min_size=6, max_size=6), t=st.integers(-(2**33), 2**33))
def test_out_of_range_values_fail_like_pymavlink(values: list[float], t: int) -> None:
    msg = mavlink.MAVLink(None).attitude_encode(t, *values)
    try:
        expected: bytes | type[BaseException] = reference(msg, 0, 1, 1)
    except (struct.error, OverflowError) as exc:
        expected = type(exc)
    try:
        got: bytes | type[BaseException] = fastcodec.encode_attitude(0, 1, 1, t, *values)
    except (struct.error, OverflowError) as exc:
        got = type(exc)
    assert got == expected


def test_pack_message_leaves_other_types_to_pymavlink() -> None:
    msg = mavlink.MAVLink(None).heartbeat_encode(2, 3, 0, 0, 0)
    assert fastcodec.pack_message(msg, 0, 1, 1) is None
    assert fastcodec.FAST_MSG_IDS == {30, 32, 93, 105, 331}


@pytest.mark.parametrize("flip_index", [1 + 9, 12, -2, -1])
def test_corrupted_packet_decodes_to_none(flip_index: int) -> None:
    packet = bytearray(fastcodec.encode_attitude(3, 1, 1, 1000, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6))
    packet[flip_index] ^= 0x01
    assert fastcodec.decode_packet(bytes(packet)) is None


def test_payload_longer_than_known_fields_decodes_like_pymavlink() -> None:
    """A newer dialect may append extension fields; both decoders ignore the extra bytes."""
    base = fastcodec.encode_local_position_ned(9, 1, 1, 5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    payload = base[10:-2] + b"\x11\x22\x33"
    header = bytes([0xFD, len(payload)]) + base[2:10]
    extra = bytes([mavlink.MAVLink_local_position_ned_message.crc_extra])
    crc = mavlink.x25crc(header[1:] + payload + extra).crc
    packet = header + payload + struct.pack("<H", crc)
    assert_round_trip(packet)


@settings(max_examples=200, deadline=None)
@given(
    seq=U8,
    system=U8,
    component=U8,
    t=U64,
    # ASCII names: pymavlink itself re-encodes non-ASCII name bytes as UTF-8 text, so they do
    # not survive its own pack/unpack; our names ("SMC") are ASCII.
    name=st.text(alphabet=st.characters(min_codepoint=0x21, max_codepoint=0x7E), max_size=10).map(str.encode),
    array_id=st.integers(0, 0xFFFF),
    data=st.lists(F32, min_size=58, max_size=58),
)
@example(seq=0, system=1, component=1, t=0, name=b"SMC", array_id=1, data=[0.0] * 58)
def test_debug_float_array_matches_pymavlink(
    seq: int, system: int, component: int, t: int, name: bytes, array_id: int, data: list[float]
) -> None:
    msg = mavlink.MAVLink(None).debug_float_array_encode(t, name, array_id, data)
    expected = reference(msg, seq, system, component)
    assert fastcodec.encode_debug_float_array(seq, system, component, t, name, array_id, data) == expected
    assert fastcodec.pack_message(msg, seq, system, component) == expected
    # pymavlink reads it back with the same values (the fast path does not decode this id).
    back = mavlink.MAVLink(None).decode(bytearray(expected))
    assert same_value(list(back.data), [struct.unpack("<f", struct.pack("<f", v))[0] for v in data])


I8 = st.integers(-128, 127)
U16 = st.integers(0, 0xFFFF)


@settings(max_examples=300, deadline=None)
@given(seq=U8, system=U8, component=U8, t=U64, values=st.lists(F32, min_size=13, max_size=13), fields=U16, imu_id=U8)
@example(seq=0, system=0, component=0, t=0, values=[0.0] * 13, fields=0, imu_id=0)  # all zeros -> 1 byte
@example(seq=9, system=1, component=200, t=10**6, values=[0.1, -0.2, -9.81, 0.01, 0.02, 0.03] + [0.0] * 7, fields=0x3F, imu_id=0)
@example(seq=9, system=1, component=200, t=10**6, values=[math.nan] * 3 + [0.0] * 10, fields=0x3F, imu_id=0)  # a dropout
def test_highres_imu_matches_pymavlink(seq: int, system: int, component: int, t: int, values: list[float], fields: int, imu_id: int) -> None:
    """The simulator's sensed IMU, every tick: the same bytes as pymavlink, and decoded to the same message."""
    acc_gyro, rest = values[:6], values[6:]
    msg = mavlink.MAVLink(None).highres_imu_encode(t, *acc_gyro, *rest, fields, imu_id)
    expected = reference(msg, seq, system, component)
    assert fastcodec.encode_highres_imu(seq, system, component, t, *acc_gyro, fields, *rest, imu_id) == expected
    assert fastcodec.pack_message(msg, seq, system, component) == expected
    assert_round_trip(expected)


@settings(max_examples=300, deadline=None)
@given(
    seq=U8, system=U8, component=U8, t=U64, frames=st.lists(U8, min_size=2, max_size=2), values=st.lists(F32, min_size=13, max_size=13),
    cov=st.lists(F32, min_size=42, max_size=42), reset=U8, est=U8, quality=I8,
)  # fmt: skip
@example(seq=0, system=0, component=0, t=0, frames=[0, 0], values=[0.0] * 13, cov=[0.0] * 42, reset=0, est=0, quality=0)
@example(seq=3, system=2, component=200, t=2 * 10**6, frames=[1, 1], values=[1.0, -2.0, -3.0, 1.0, 0.0, 0.0, 0.0] + [0.5] * 6,
         cov=[math.nan] + [0.0] * 20 + [math.nan] + [0.0] * 20, reset=0, est=6, quality=100)  # fmt: skip
def test_odometry_matches_pymavlink(
    seq: int, system: int, component: int, t: int, frames: list[int], values: list[float], cov: list[float], reset: int, est: int, quality: int
) -> None:
    """The plant's true state, every tick (logged for scoring): the same bytes as pymavlink, decoded alike."""
    x, y, z = values[:3]
    q = values[3:7]
    vx, vy, vz, p, qr, r = values[7:]
    msg = mavlink.MAVLink(None).odometry_encode(t, frames[0], frames[1], x, y, z, q, vx, vy, vz, p, qr, r, cov[:21], cov[21:], reset, est, quality)
    expected = reference(msg, seq, system, component)
    got = fastcodec.encode_odometry(seq, system, component, t, frames[0], frames[1], x, y, z, q, vx, vy, vz, p, qr, r, cov[:21], cov[21:],
                                    reset, est, quality)  # fmt: skip
    assert got == expected
    assert fastcodec.pack_message(msg, seq, system, component) == expected
    assert_round_trip(expected)


# -- the simulator's per-tick datagram, decoded straight to values ---------------------------------
_F32 = st.one_of(st.floats(width=32), st.sampled_from([0.0, -0.0, math.nan, math.inf, -math.inf]))


def _same(a: object, b: object) -> bool:
    """Equal, NaN equal to NaN (and the sign of a zero counted)."""
    if isinstance(a, float) and isinstance(b, float):
        return struct.pack("<d", a) == struct.pack("<d", b) or (a != a and b != b)
    return a == b


def state_datagram(sysid: int, seq: int, t_us: int, v: list[float], lpn_t_ms: int | None = None) -> bytes:
    """The simulator's state datagram (as ``sim_bridge`` writes it) of 31 values (``lpn_t_ms``:
    LOCAL_POSITION_NED stamped otherwise than ATTITUDE)."""
    rec = fastcodec.TickRecords(sysid)
    t_ms = (t_us // 1000) & 0xFFFFFFFF
    return b"".join((
        rec.attitude(seq, t_ms, *v[0:6]),
        rec.highres_imu((seq + 1) & 0xFF, t_us, *v[6:12]),
        rec.odometry((seq + 2) & 0xFF, t_us, *v[12:25]),
        rec.local_position_ned((seq + 3) & 0xFF, t_ms if lpn_t_ms is None else lpn_t_ms, *v[25:31]),
    ))  # fmt: skip


@settings(max_examples=300, deadline=None)
@given(st.integers(1, 255), st.integers(0, 255), st.integers(0, 2**42), st.lists(_F32, min_size=31, max_size=31))
@example(1, 0, 0, [0.0] * 31)  # every payload trimmed to one byte
def test_the_simulators_datagram_decodes_to_pymavlinks_values(sysid: int, seq: int, t_us: int, v: list[float]) -> None:
    data = state_datagram(sysid, seq, t_us, v)
    d = fastcodec.decode_state_datagram(data, sysid)
    assert d is not None
    msgs = mavlink.MAVLink(None).parse_buffer(data)
    assert [m.get_type() for m in msgs] == ["ATTITUDE", "HIGHRES_IMU", "ODOMETRY", "LOCAL_POSITION_NED"]
    for values, m, packet in zip(d[:4], msgs, d[4]):
        cls = type(m)
        assert bytes(packet) == bytes(m.get_msgbuf())
        # the payload's fields in wire order, as pymavlink decoded them (arrays flattened)
        wire: list[object] = []
        for name in cls.ordered_fieldnames:
            f = getattr(m, name)
            wire.extend(f if isinstance(f, list) else [f])
        assert len(values) == len(wire) and all(_same(a, b) for a, b in zip(values, wire)), cls.__name__


def test_anything_but_the_simulators_datagram_goes_to_the_full_parse() -> None:
    v = [0.1 * i for i in range(31)]
    good = state_datagram(3, 7, 123_456_789, v)
    assert fastcodec.decode_state_datagram(good, 3) is not None
    att_len = 12 + good[1]
    cases = {
        "another system": fastcodec.decode_state_datagram(good, 4),
        "a corrupted byte": fastcodec.decode_state_datagram(good[:20] + bytes([good[20] ^ 1]) + good[21:], 3),
        "cut short": fastcodec.decode_state_datagram(good[:-1], 3),
        "a byte more": fastcodec.decode_state_datagram(good + b"\x00", 3),
        "three messages": fastcodec.decode_state_datagram(good[att_len:], 3),
        "reordered": fastcodec.decode_state_datagram(good[att_len:] + good[:att_len], 3),
        "a signed packet": fastcodec.decode_state_datagram(good[:2] + b"\x01" + good[3:], 3),
        "a STATUSTEXT after": fastcodec.decode_state_datagram(
            good + mavlink.MAVLink(None, srcSystem=3, srcComponent=200).statustext_encode(4, b"SIM: hello").pack(mavlink.MAVLink(None, 3, 200)), 3),
    }  # fmt: skip
    assert all(d is None for d in cases.values()), [k for k, d in cases.items() if d is not None]


# -- the flight controller's answer, decoded straight to values (the simulator's side) ---------------------
@settings(max_examples=300, deadline=None)
@given(st.integers(1, 255), st.integers(0, 255), st.integers(0, 2**63 - 1), st.lists(_F32, min_size=16, max_size=16),
       st.integers(0, 255), st.integers(0, 2**64 - 1))  # fmt: skip
@example(1, 0, 0, [0.0] * 16, 0, 0)  # the payload trimmed to one byte
def test_the_fcs_answer_decodes_to_pymavlinks_values(sysid: int, seq: int, t_us: int, controls: list[float], mode: int, flags: int) -> None:
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=FC_COMPONENT_ID)
    mav.seq = seq
    data = bytes(mav.hil_actuator_controls_encode(t_us, controls, mode, flags).pack(mav))
    if controls[4:] == [0.0] * 12 and all(struct.pack("<f", c) != struct.pack("<f", -0.0) for c in controls[4:]):
        assert data == fastcodec.TickRecords(sysid).actuators(seq, t_us, controls[:4], mode, flags)  # (what the FC sends)
    d = fastcodec.decode_actuator_datagram(data, sysid)
    assert d is not None
    (m,) = mavlink.MAVLink(None).parse_buffer(data)
    assert d[0] == m.time_usec and d[1] == m.flags and d[3] == m.mode and len(d[2]) == 16
    assert all(_same(a, b) for a, b in zip(d[2], m.controls))


def test_anything_but_the_fcs_answer_goes_to_the_full_parse() -> None:
    good = fastcodec.TickRecords(3).actuators(9, 4_000_000, [0.5, 0.5, 0.5, 0.5], 129)
    assert fastcodec.decode_actuator_datagram(good, 3) is not None
    sim = mavlink.MAVLink(None, srcSystem=3, srcComponent=SIM_COMPONENT_ID)
    cases = {
        "another system": fastcodec.decode_actuator_datagram(good, 4),
        "a corrupted byte": fastcodec.decode_actuator_datagram(good[:20] + bytes([good[20] ^ 1]) + good[21:], 3),
        "cut short": fastcodec.decode_actuator_datagram(good[:-1], 3),
        "a byte more": fastcodec.decode_actuator_datagram(good + b"\x00", 3),
        "two answers": fastcodec.decode_actuator_datagram(good + good, 3),
        "a signed packet": fastcodec.decode_actuator_datagram(good[:2] + b"\x01" + good[3:], 3),
        "another component": fastcodec.decode_actuator_datagram(bytes(sim.hil_actuator_controls_encode(1, [0.0] * 16, 0, 0).pack(sim)), 3),
        "a PARAM_SET": fastcodec.decode_actuator_datagram(bytes(sim.param_set_encode(3, 0, b"SIM_MOT_OFF", 1.0, 9).pack(sim)), 3),
        "nothing": fastcodec.decode_actuator_datagram(b"", 3),
    }  # fmt: skip
    assert all(d is None for d in cases.values()), [k for k, d in cases.items() if d is not None]
