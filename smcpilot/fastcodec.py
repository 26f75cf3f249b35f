"""Hand-written MAVLink 2 encode/decode for the messages of the 500 Hz control loop.

ATTITUDE (30) and LOCAL_POSITION_NED (32) go from the flight controller to ground stations and the
simulator every control tick; HIL_ACTUATOR_CONTROLS (93) goes to the simulator every tick;
HIGHRES_IMU (105, the sensed IMU) and ODOMETRY (331, the plant's true state, for the log only)
come from the simulator with each state. For these ids this module produces exactly the bytes pymavlink produces (same header, sequence number,
CRC_EXTRA, and MAVLink 2 truncation of trailing zero bytes of the payload down to one byte), and
decodes them into the very pymavlink message classes with the same fields and header. The link
picks this path automatically; callers never need to.

Measured with timeit (best of 9, pymavlink 2.4.50 with fastcrc, CPython 3.11, µs per message):

=====================  ==========================  ===========  ===========================  ===========
message                pymavlink encode + pack     fast encode  pymavlink decode (parse_buf)  fast decode
=====================  ==========================  ===========  ===========================  ===========
ATTITUDE               3.4                         0.72         3.8 (5.9)                    1.9
LOCAL_POSITION_NED     3.5                         0.70         3.8 (7.5)                    1.9
HIL_ACTUATOR_CONTROLS  6.3                         0.89         6.2 (8.7)                    2.3
=====================  ==========================  ===========  ===========================  ===========

Through :class:`~smcpilot.link.MavlinkUdp`, one ATTITUDE + LOCAL_POSITION_NED datagram parses in
4.9 µs instead of 12.3 µs, and ``send_many`` of the pair (incl. the sendto) takes 4.7 µs instead of
11.2 µs.

Only unsigned MAVLink 2 packets are handled; anything else (signing, MAVLink 1, other ids) is
left to pymavlink by :mod:`smcpilot.link`.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot.protocol import (
    ACTUATOR_FLAG_LOCKSTEP,
    COV_UNKNOWN,
    FC_COMPONENT_ID,
    IMU_FIELDS_UPDATED,
    SIM_COMPONENT_ID,
    SMC_ARRAY_ID,
    SMC_ARRAY_NAME,
    TRUTH_ESTIMATOR_TYPE,
    TRUTH_FRAME,
    TRUTH_QUALITY,
)

__all__ = [
    "FAST_MSG_IDS",
    "FAST_MESSAGE_TYPES",
    "encode_attitude",
    "encode_local_position_ned",
    "encode_hil_actuator_controls",
    "encode_debug_float_array",
    "encode_highres_imu",
    "encode_odometry",
    "pack_message",
    "decode_packet",
    "Layout",
    "layout",
    "framed",
    "TickRecords",
    "decode_state_datagram",
    "decode_actuator_datagram",
]

_crc16 = mavlink.mcrf4xx
if _crc16 is None:  # pragma: no cover - pymavlink without fastcrc; keep identical results, lose speed

    def _crc16(data: bytes, initial: int | None = None) -> int:
        crc = mavlink.x25crc()
        if initial is not None:
            crc.crc = initial
        crc.accumulate(bytes(data))
        return int(crc.crc)


_MAGIC_V2 = mavlink.PROTOCOL_MARKER_V2
_HEADER = struct.Struct("<BBBBBBBHB")
_HEADER_PACK = _HEADER.pack
_HEADER_BYTES = 10
_CRC_BYTES = 2

_ATTITUDE = mavlink.MAVLink_attitude_message
_LOCAL_POSITION_NED = mavlink.MAVLink_local_position_ned_message
_HIL_ACTUATOR_CONTROLS = mavlink.MAVLink_hil_actuator_controls_message
_DEBUG_FLOAT_ARRAY = mavlink.MAVLink_debug_float_array_message
_HIGHRES_IMU = mavlink.MAVLink_highres_imu_message
_ODOMETRY = mavlink.MAVLink_odometry_message
_MAVLinkHeader = mavlink.MAVLink_header

ID_ATTITUDE = _ATTITUDE.id
ID_LOCAL_POSITION_NED = _LOCAL_POSITION_NED.id
ID_HIL_ACTUATOR_CONTROLS = _HIL_ACTUATOR_CONTROLS.id
ID_DEBUG_FLOAT_ARRAY = _DEBUG_FLOAT_ARRAY.id
ID_HIGHRES_IMU = _HIGHRES_IMU.id
ID_ODOMETRY = _ODOMETRY.id

#: Message ids :func:`decode_packet` handles.
FAST_MSG_IDS = frozenset({ID_ATTITUDE, ID_LOCAL_POSITION_NED, ID_HIL_ACTUATOR_CONTROLS, ID_HIGHRES_IMU, ID_ODOMETRY})
#: pymavlink message classes :func:`pack_message` handles.
FAST_MESSAGE_TYPES = frozenset({_ATTITUDE, _LOCAL_POSITION_NED, _HIL_ACTUATOR_CONTROLS, _DEBUG_FLOAT_ARRAY, _HIGHRES_IMU, _ODOMETRY})

# Payload layouts and CRC_EXTRA bytes come from pymavlink's generated classes, so a dialect
# update that changed them would change both paths alike (and the byte-for-byte tests would say).
_ATTITUDE_PAYLOAD = _ATTITUDE.unpacker
_LOCAL_POSITION_NED_PAYLOAD = _LOCAL_POSITION_NED.unpacker
_HIL_PAYLOAD = _HIL_ACTUATOR_CONTROLS.unpacker
_ATTITUDE_EXTRA = bytes([_ATTITUDE.crc_extra])
_LOCAL_POSITION_NED_EXTRA = bytes([_LOCAL_POSITION_NED.crc_extra])
_HIL_EXTRA = bytes([_HIL_ACTUATOR_CONTROLS.crc_extra])
_DFA_PAYLOAD = _DEBUG_FLOAT_ARRAY.unpacker
_DFA_EXTRA = bytes([_DEBUG_FLOAT_ARRAY.crc_extra])
assert _ATTITUDE_PAYLOAD.format == _LOCAL_POSITION_NED_PAYLOAD.format == "<Iffffff"
assert _HIL_PAYLOAD.format == "<QQ16fB"
assert _ATTITUDE.ordered_fieldnames == _ATTITUDE.fieldnames
assert _LOCAL_POSITION_NED.ordered_fieldnames == _LOCAL_POSITION_NED.fieldnames
assert _HIL_ACTUATOR_CONTROLS.ordered_fieldnames == ["time_usec", "flags", "controls", "mode"]
assert _DFA_PAYLOAD.format == "<QH10s58f"
assert _DEBUG_FLOAT_ARRAY.ordered_fieldnames == ["time_usec", "array_id", "name", "data"]
_IMU_PAYLOAD = _HIGHRES_IMU.unpacker
_IMU_EXTRA = bytes([_HIGHRES_IMU.crc_extra])
assert _IMU_PAYLOAD.format == "<QfffffffffffffHB"
assert _HIGHRES_IMU.ordered_fieldnames == _HIGHRES_IMU.fieldnames
_ODO_PAYLOAD = _ODOMETRY.unpacker
_ODO_EXTRA = bytes([_ODOMETRY.crc_extra])
assert _ODO_PAYLOAD.format == "<Qfff4fffffff21f21fBBBBb"
assert _ODOMETRY.ordered_fieldnames == [
    "time_usec", "x", "y", "z", "q", "vx", "vy", "vz", "rollspeed", "pitchspeed", "yawspeed",
    "pose_covariance", "velocity_covariance", "frame_id", "child_frame_id", "reset_counter", "estimator_type", "quality",
]  # fmt: skip


# -- one pack a message: header and payload together ------------------------------------------------
#: (pack(magic, 0, 0, 0, seq, system, component, id low 16 bits, id high 8 bits, payload fields...),
#: id low 16 bits, id high 8 bits, CRC_EXTRA): a message's header and payload packed in one call
#: and then :func:`framed`, the same bytes as :func:`_frame` (and pymavlink) in fewer steps.
Layout = tuple[Callable[..., bytes], int, int, bytes]
_LENGTH = [bytes((_MAGIC_V2, n)) for n in range(256)]


def layout(msg_class: type, payload_format: str) -> Layout:
    """The one-pack :data:`Layout` of ``msg_class`` with ``payload_format`` (its wire order; a
    prefix of its fields is allowed: the rest are zeros, which MAVLink 2 trims anyway)."""
    msg_id: int = msg_class.id  # type: ignore[attr-defined]
    return struct.Struct(_HEADER.format + payload_format[1:]).pack, msg_id & 0xFFFF, msg_id >> 16, bytes([msg_class.crc_extra])  # type: ignore[attr-defined]


def framed(full: bytes, crc_extra: bytes) -> bytes:
    """A MAVLink 2 packet of ``full`` (a :data:`Layout`'s pack: the header, length 0, then the whole
    payload) as pymavlink frames it: the payload's trailing zeros trimmed (at least one byte kept),
    the length set, the CRC appended."""
    body = full.rstrip(b"\x00")
    n = len(body) - _HEADER_BYTES
    if n < 1:
        body = full[: _HEADER_BYTES + 1]
        n = 1
    packet = _LENGTH[n] + body[2:]
    return packet + _crc16(crc_extra, _crc16(packet[1:])).to_bytes(2, "little")


ATTITUDE_LAYOUT = layout(_ATTITUDE, "<Iffffff")
LOCAL_POSITION_NED_LAYOUT = layout(_LOCAL_POSITION_NED, "<Iffffff")
HIGHRES_IMU_LAYOUT = layout(_HIGHRES_IMU, "<QfffffffffffffHB")
ODOMETRY_LAYOUT = layout(_ODOMETRY, "<Q13f")  # the 13 leading floats: the tail packed on its own
HIL_ACTUATOR_CONTROLS_LAYOUT = layout(_HIL_ACTUATOR_CONTROLS, "<QQ16fB")
DEBUG_FLOAT_ARRAY_LAYOUT = layout(_DEBUG_FLOAT_ARRAY, "<QH10s58f")
_ODO_TAIL = struct.Struct("<21f21fBBBBb").pack
_ATT_PACK, _ATT_LO, _ATT_HI, _ = ATTITUDE_LAYOUT
_LPN_PACK, _LPN_LO, _LPN_HI, _ = LOCAL_POSITION_NED_LAYOUT
_IMU_PACK, _IMU_LO, _IMU_HI, _ = HIGHRES_IMU_LAYOUT
_ODO_PACK, _ODO_LO, _ODO_HI, _ = ODOMETRY_LAYOUT
_HIL_PACK, _HIL_LO, _HIL_HI, _ = HIL_ACTUATOR_CONTROLS_LAYOUT
_DFA_PACK, _DFA_LO, _DFA_HI, _ = DEBUG_FLOAT_ARRAY_LAYOUT


def encode_attitude(
    seq: int,
    src_system: int,
    src_component: int,
    time_boot_ms: int,
    roll: float,
    pitch: float,
    yaw: float,
    rollspeed: float,
    pitchspeed: float,
    yawspeed: float,
) -> bytes:
    """ATTITUDE packet (angles rad, rates rad/s) with sequence number ``seq`` (0..255)."""
    return framed(_ATT_PACK(0xFD, 0, 0, 0, seq, src_system, src_component, _ATT_LO, _ATT_HI, time_boot_ms, roll, pitch, yaw,
                            rollspeed, pitchspeed, yawspeed), _ATTITUDE_EXTRA)  # fmt: skip


def encode_local_position_ned(
    seq: int,
    src_system: int,
    src_component: int,
    time_boot_ms: int,
    x: float,
    y: float,
    z: float,
    vx: float,
    vy: float,
    vz: float,
) -> bytes:
    """LOCAL_POSITION_NED packet (positions m, velocities m/s, NED) with sequence number ``seq``."""
    return framed(_LPN_PACK(0xFD, 0, 0, 0, seq, src_system, src_component, _LPN_LO, _LPN_HI, time_boot_ms, x, y, z, vx, vy, vz),
                  _LOCAL_POSITION_NED_EXTRA)  # fmt: skip


def encode_hil_actuator_controls(
    seq: int,
    src_system: int,
    src_component: int,
    time_usec: int,
    controls: Sequence[float],
    mode: int,
    flags: int,
) -> bytes:
    """HIL_ACTUATOR_CONTROLS packet; ``controls`` holds 16 values (extra ones are ignored, as pymavlink does)."""
    c = controls
    return framed(_HIL_PACK(
        0xFD, 0, 0, 0, seq, src_system, src_component, _HIL_LO, _HIL_HI, time_usec, flags,
        c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7],
        c[8], c[9], c[10], c[11], c[12], c[13], c[14], c[15],
        mode,
    ), _HIL_EXTRA)  # fmt: skip


def encode_debug_float_array(
    seq: int,
    src_system: int,
    src_component: int,
    time_usec: int,
    name: bytes | str,
    array_id: int,
    data: Sequence[float],
) -> bytes:
    """DEBUG_FLOAT_ARRAY packet (encode only: the flight controller logs one per control tick).

    ``data`` holds 58 floats; ``name`` at most 10 bytes (NUL-padded, as pymavlink does).
    """
    if isinstance(name, str):  # pymavlink keeps str names on messages it built
        name = name.encode("utf-8")
    return framed(_DFA_PACK(0xFD, 0, 0, 0, seq, src_system, src_component, _DFA_LO, _DFA_HI, time_usec, array_id, name, *data), _DFA_EXTRA)


def encode_highres_imu(
    seq: int,
    src_system: int,
    src_component: int,
    time_usec: int,
    xacc: float,
    yacc: float,
    zacc: float,
    xgyro: float,
    ygyro: float,
    zgyro: float,
    fields_updated: int,
    xmag: float = 0.0,
    ymag: float = 0.0,
    zmag: float = 0.0,
    abs_pressure: float = 0.0,
    diff_pressure: float = 0.0,
    pressure_alt: float = 0.0,
    temperature: float = 0.0,
    imu_id: int = 0,
) -> bytes:
    """HIGHRES_IMU packet: specific force (m/s^2) and rates (rad/s), body FRD; ``fields_updated``
    the HIGHRES_IMU_UPDATED_* bits of the valid fields."""
    return framed(_IMU_PACK(
        0xFD, 0, 0, 0, seq, src_system, src_component, _IMU_LO, _IMU_HI,
        time_usec, xacc, yacc, zacc, xgyro, ygyro, zgyro, xmag, ymag, zmag, abs_pressure, diff_pressure, pressure_alt, temperature,
        fields_updated, imu_id,
    ), _IMU_EXTRA)  # fmt: skip


def encode_odometry(
    seq: int,
    src_system: int,
    src_component: int,
    time_usec: int,
    frame_id: int,
    child_frame_id: int,
    x: float,
    y: float,
    z: float,
    q: Sequence[float],
    vx: float,
    vy: float,
    vz: float,
    rollspeed: float,
    pitchspeed: float,
    yawspeed: float,
    pose_covariance: Sequence[float],
    velocity_covariance: Sequence[float],
    reset_counter: int = 0,
    estimator_type: int = 0,
    quality: int = 0,
) -> bytes:
    """ODOMETRY packet (``q`` 4 floats w, x, y, z; each covariance 21 floats), arguments in
    pymavlink's ``odometry_encode`` order."""
    head = _ODO_PACK(0xFD, 0, 0, 0, seq, src_system, src_component, _ODO_LO, _ODO_HI,
                     time_usec, x, y, z, q[0], q[1], q[2], q[3], vx, vy, vz, rollspeed, pitchspeed, yawspeed)  # fmt: skip
    tail = _ODO_TAIL(*pose_covariance[:21], *velocity_covariance[:21], frame_id, child_frame_id, reset_counter, estimator_type, quality)
    return framed(head + tail, _ODO_EXTRA)


class TickRecords:
    """The per-tick messages of one vehicle, encoded: the simulator's state (ATTITUDE,
    LOCAL_POSITION_NED, HIGHRES_IMU, ODOMETRY: what the simulator process sends and the FC logs)
    and the FC's answer and record (HIL_ACTUATOR_CONTROLS, the ``SMC`` DEBUG_FLOAT_ARRAY). The one
    writer of these records: the simulator process sends them, the FC process answers and logs
    with them, the in-process runner writes its log with them (a compiled flight's rows through
    the layouts themselves, :attr:`att` ...). The same bytes as the ``encode_*`` functions and
    pymavlink (tested)."""

    def __init__(self, sysid: int) -> None:
        self.sysid = sysid
        self.att = ATTITUDE_LAYOUT
        self.lpn = LOCAL_POSITION_NED_LAYOUT
        self.imu = HIGHRES_IMU_LAYOUT
        self.odo = ODOMETRY_LAYOUT
        self.act = HIL_ACTUATOR_CONTROLS_LAYOUT
        self.dfa = DEBUG_FLOAT_ARRAY_LAYOUT
        #: the SMC record's 31 leading values: the rest are zeros, which MAVLink 2 trims anyway.
        self.smc31 = layout(_DEBUG_FLOAT_ARRAY, "<QH10s31f")
        #: ODOMETRY's constant tail in the truth: the covariances (unknown), frames, reset counter, estimator, quality.
        self.odo_tail = _ODO_TAIL(*COV_UNKNOWN, *COV_UNKNOWN, TRUTH_FRAME, TRUTH_FRAME, 0, TRUTH_ESTIMATOR_TYPE, TRUTH_QUALITY)

    def attitude(self, seq: int, t_ms: int, roll: float, pitch: float, yaw: float, p: float, q: float, r: float) -> bytes:
        """Attitude (rad, FRD in NED) and body rates (rad/s, FRD)."""
        return framed(_ATT_PACK(0xFD, 0, 0, 0, seq, self.sysid, SIM_COMPONENT_ID, _ATT_LO, _ATT_HI, t_ms, roll, pitch, yaw, p, q, r),
                      _ATTITUDE_EXTRA)  # fmt: skip

    def local_position_ned(self, seq: int, t_ms: int, x: float, y: float, z: float, vx: float, vy: float, vz: float) -> bytes:
        """Position (m) and velocity (m/s), NED."""
        return framed(_LPN_PACK(0xFD, 0, 0, 0, seq, self.sysid, SIM_COMPONENT_ID, _LPN_LO, _LPN_HI, t_ms, x, y, z, vx, vy, vz),
                      _LOCAL_POSITION_NED_EXTRA)  # fmt: skip

    def highres_imu(self, seq: int, t_us: int, fx: float, fy: float, fz: float, p: float, q: float, r: float) -> bytes:
        """Specific force (m/s^2) and rates (rad/s), body FRD; the accelerometer and the gyro updated."""
        return framed(_IMU_PACK(0xFD, 0, 0, 0, seq, self.sysid, SIM_COMPONENT_ID, _IMU_LO, _IMU_HI, t_us, fx, fy, fz, p, q, r,
                                0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, IMU_FIELDS_UPDATED, 0), _IMU_EXTRA)  # fmt: skip

    def odometry(self, seq: int, t_us: int, x: float, y: float, z: float, qw: float, qx: float, qy: float, qz: float,
                 vx: float, vy: float, vz: float, p: float, q: float, r: float) -> bytes:  # fmt: skip
        """The true state: position and velocity NED (m, m/s), the attitude quaternion (FRD body in
        NED), body rates FRD (rad/s)."""
        head = _ODO_PACK(0xFD, 0, 0, 0, seq, self.sysid, SIM_COMPONENT_ID, _ODO_LO, _ODO_HI, t_us, x, y, z, qw, qx, qy, qz, vx, vy, vz, p, q, r)
        return framed(head + self.odo_tail, _ODO_EXTRA)

    def actuators(self, seq: int, t_us: int, m: Sequence[float], mode: int, flags: int = ACTUATOR_FLAG_LOCKSTEP) -> bytes:
        """The FC's motor commands (rotors 1..4 in [0, 1]) and mode flags."""
        return framed(_HIL_PACK(0xFD, 0, 0, 0, seq, self.sysid, FC_COMPONENT_ID, _HIL_LO, _HIL_HI, t_us, flags, m[0], m[1], m[2], m[3],
                                0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, mode), _HIL_EXTRA)  # fmt: skip

    def smc(self, seq: int, t_us: int, data: Sequence[float]) -> bytes:
        """The FC's ``SMC`` record of a tick (58 floats)."""
        return framed(_DFA_PACK(0xFD, 0, 0, 0, seq, self.sysid, FC_COMPONENT_ID, _DFA_LO, _DFA_HI, t_us, SMC_ARRAY_ID, SMC_NAME, *data),
                      _DFA_EXTRA)  # fmt: skip


#: the ``SMC`` record's name as the payload carries it.
SMC_NAME = SMC_ARRAY_NAME.encode("ascii") if isinstance(SMC_ARRAY_NAME, str) else SMC_ARRAY_NAME


def _pack_highres_imu(m: mavlink.MAVLink_message, seq: int, src_system: int, src_component: int) -> bytes:
    return encode_highres_imu(
        seq, src_system, src_component, m.time_usec, m.xacc, m.yacc, m.zacc, m.xgyro, m.ygyro, m.zgyro, m.fields_updated,
        m.xmag, m.ymag, m.zmag, m.abs_pressure, m.diff_pressure, m.pressure_alt, m.temperature, m.id,
    )  # fmt: skip


def _pack_odometry(m: mavlink.MAVLink_message, seq: int, src_system: int, src_component: int) -> bytes:
    return encode_odometry(
        seq, src_system, src_component, m.time_usec, m.frame_id, m.child_frame_id, m.x, m.y, m.z, m.q, m.vx, m.vy, m.vz,
        m.rollspeed, m.pitchspeed, m.yawspeed, m.pose_covariance, m.velocity_covariance, m.reset_counter, m.estimator_type, m.quality,
    )  # fmt: skip


def _pack_debug_float_array(m: mavlink.MAVLink_message, seq: int, src_system: int, src_component: int) -> bytes:
    return encode_debug_float_array(seq, src_system, src_component, m.time_usec, m.name, m.array_id, m.data)


def _pack_attitude(m: mavlink.MAVLink_message, seq: int, src_system: int, src_component: int) -> bytes:
    return encode_attitude(seq, src_system, src_component, m.time_boot_ms, m.roll, m.pitch, m.yaw, m.rollspeed, m.pitchspeed, m.yawspeed)


def _pack_local_position_ned(m: mavlink.MAVLink_message, seq: int, src_system: int, src_component: int) -> bytes:
    return encode_local_position_ned(seq, src_system, src_component, m.time_boot_ms, m.x, m.y, m.z, m.vx, m.vy, m.vz)


def _pack_hil_actuator_controls(m: mavlink.MAVLink_message, seq: int, src_system: int, src_component: int) -> bytes:
    return encode_hil_actuator_controls(seq, src_system, src_component, m.time_usec, m.controls, m.mode, m.flags)


_PACKERS: dict[type, Callable[[mavlink.MAVLink_message, int, int, int], bytes]] = {
    _ATTITUDE: _pack_attitude,
    _LOCAL_POSITION_NED: _pack_local_position_ned,
    _HIL_ACTUATOR_CONTROLS: _pack_hil_actuator_controls,
    _DEBUG_FLOAT_ARRAY: _pack_debug_float_array,
    _HIGHRES_IMU: _pack_highres_imu,
    _ODOMETRY: _pack_odometry,
}

#: ``type(msg) -> packer(msg, seq, src_system, src_component) -> bytes`` for the fast types.
PACKERS = _PACKERS


def pack_message(msg: mavlink.MAVLink_message, seq: int, src_system: int, src_component: int) -> bytes | None:
    """Unsigned MAVLink 2 packet of ``msg`` if its type is one of the fast three, else None.

    Unlike ``msg.pack(mav)`` this does not store the header, payload and CRC on ``msg``.
    """
    packer = _PACKERS.get(type(msg))
    if packer is None:
        return None
    return packer(msg, seq, src_system, src_component)


def _finish(msg: mavlink.MAVLink_message, packet: bytes, length: int, crc: int, msg_id: int) -> mavlink.MAVLink_message:
    """Set the header attributes pymavlink's ``MAVLink.decode`` sets."""
    msg._header = _MAVLinkHeader(msg_id, 0, packet[3], length, packet[4], packet[5], packet[6])
    msgbuf = bytearray(packet)
    msg._msgbuf = msgbuf
    # pymavlink stores msgbuf[6:-2] here even for MAVLink 2 (header bytes 6..9 included); same
    # value so that get_payload() does not depend on which decoder ran.
    msg._payload = msgbuf[6:-2]
    msg._crc = crc
    return msg


def _checked_payload(packet: bytes, crc_extra: bytes, full_length: int) -> tuple[bytes, int, int] | None:
    length = packet[1]
    body_end = _HEADER_BYTES + length
    crc = packet[body_end] | (packet[body_end + 1] << 8)
    if _crc16(crc_extra, _crc16(packet[1:body_end])) != crc:
        return None
    payload = packet[_HEADER_BYTES:body_end]
    if length < full_length:
        payload += bytes(full_length - length)
    return payload, length, crc


def _decode_attitude(packet: bytes) -> mavlink.MAVLink_message | None:
    checked = _checked_payload(packet, _ATTITUDE_EXTRA, 28)
    if checked is None:
        return None
    payload, length, crc = checked
    msg = _ATTITUDE(*_ATTITUDE_PAYLOAD.unpack_from(payload))
    return _finish(msg, packet, length, crc, ID_ATTITUDE)


def _decode_local_position_ned(packet: bytes) -> mavlink.MAVLink_message | None:
    checked = _checked_payload(packet, _LOCAL_POSITION_NED_EXTRA, 28)
    if checked is None:
        return None
    payload, length, crc = checked
    msg = _LOCAL_POSITION_NED(*_LOCAL_POSITION_NED_PAYLOAD.unpack_from(payload))
    return _finish(msg, packet, length, crc, ID_LOCAL_POSITION_NED)


def _decode_hil_actuator_controls(packet: bytes) -> mavlink.MAVLink_message | None:
    checked = _checked_payload(packet, _HIL_EXTRA, _HIL_PAYLOAD.size)
    if checked is None:
        return None
    payload, length, crc = checked
    values = _HIL_PAYLOAD.unpack_from(payload)
    msg = _HIL_ACTUATOR_CONTROLS(values[0], list(values[2:18]), values[18], values[1])
    return _finish(msg, packet, length, crc, ID_HIL_ACTUATOR_CONTROLS)


def _decode_highres_imu(packet: bytes) -> mavlink.MAVLink_message | None:
    checked = _checked_payload(packet, _IMU_EXTRA, _IMU_PAYLOAD.size)
    if checked is None:
        return None
    payload, length, crc = checked
    msg = _HIGHRES_IMU(*_IMU_PAYLOAD.unpack_from(payload))
    return _finish(msg, packet, length, crc, ID_HIGHRES_IMU)


def _decode_odometry(packet: bytes) -> mavlink.MAVLink_message | None:
    checked = _checked_payload(packet, _ODO_EXTRA, _ODO_PAYLOAD.size)
    if checked is None:
        return None
    payload, length, crc = checked
    v = _ODO_PAYLOAD.unpack_from(payload)
    msg = _ODOMETRY(
        v[0], v[56], v[57], v[1], v[2], v[3], list(v[4:8]), v[8], v[9], v[10], v[11], v[12], v[13],
        list(v[14:35]), list(v[35:56]), v[58], v[59], v[60],
    )  # fmt: skip
    return _finish(msg, packet, length, crc, ID_ODOMETRY)


_DECODERS: dict[int, Callable[[bytes], mavlink.MAVLink_message | None]] = {
    ID_ATTITUDE: _decode_attitude,
    ID_LOCAL_POSITION_NED: _decode_local_position_ned,
    ID_HIL_ACTUATOR_CONTROLS: _decode_hil_actuator_controls,
    ID_HIGHRES_IMU: _decode_highres_imu,
    ID_ODOMETRY: _decode_odometry,
}

#: ``msg_id -> decoder(packet) -> message or None (bad CRC)`` for unsigned MAVLink 2 packets.
DECODERS = _DECODERS


def decode_packet(packet: bytes) -> mavlink.MAVLink_message | None:
    """Decode one complete, unsigned MAVLink 2 packet of a fast id; None if its CRC is wrong.

    ``packet`` must be exactly one frame (``10 + packet[1] + 2`` bytes, incompat_flags 0): the
    link checks the framing before calling. Raises :class:`KeyError` for an id outside
    :data:`FAST_MSG_IDS`.
    """
    msg_id = packet[7] | (packet[8] << 8) | (packet[9] << 16)
    return _DECODERS[msg_id](packet)


# -- the simulator's per-tick datagram, decoded straight to values ---------------------------------
#: (message id, CRC_EXTRA, payload unpack_from, full payload length) of the simulator's per-tick
#: datagram, in the order the simulator sends them: ATTITUDE, HIGHRES_IMU, ODOMETRY, LOCAL_POSITION_NED.
_STATE_LAYOUT = (
    (ID_ATTITUDE, _ATTITUDE_EXTRA, _ATTITUDE_PAYLOAD.unpack_from, _ATTITUDE_PAYLOAD.size),
    (ID_HIGHRES_IMU, _IMU_EXTRA, _IMU_PAYLOAD.unpack_from, _IMU_PAYLOAD.size),
    (ID_ODOMETRY, _ODO_EXTRA, _ODO_PAYLOAD.unpack_from, _ODO_PAYLOAD.size),
    (ID_LOCAL_POSITION_NED, _LOCAL_POSITION_NED_EXTRA, _LOCAL_POSITION_NED_PAYLOAD.unpack_from, _LOCAL_POSITION_NED_PAYLOAD.size),
)


def decode_actuator_datagram(data: bytes, system: int) -> tuple[int, int, tuple[float, ...], int] | None:
    """A flight controller's answer (one HIL_ACTUATOR_CONTROLS from ``system``'s FC component,
    unsigned MAVLink 2, as :meth:`TickRecords.actuators` writes it) decoded straight to values:
    (time_usec, flags, the 16 controls, mode), pymavlink's values (float32 widened). None for
    anything else (another message, a signed or foreign packet, a bad CRC, trailing bytes): the
    link's full parse then handles it, counts and all."""
    size = len(data)
    if (size < 12 or data[0] != 0xFD or data[2] or data[3] or 12 + data[1] != size or data[5] != system
            or data[6] != FC_COMPONENT_ID or (data[7] | (data[8] << 8) | (data[9] << 16)) != ID_HIL_ACTUATOR_CONTROLS):  # fmt: skip
        return None
    checked = _checked_payload(data, _HIL_EXTRA, _HIL_PAYLOAD.size)
    if checked is None:
        return None
    v = _HIL_PAYLOAD.unpack_from(checked[0])
    return v[0], v[1], v[2:18], v[18]


def decode_state_datagram(data: bytes, system: int) -> tuple[tuple, tuple, tuple, tuple, tuple[bytes, bytes, bytes, bytes]] | None:
    """The simulator's per-tick datagram (ATTITUDE, HIGHRES_IMU, ODOMETRY, LOCAL_POSITION_NED from
    ``system``'s simulator component, unsigned MAVLink 2, as :class:`TickRecords` writes them),
    decoded straight to values: (ATTITUDE's fields, HIGHRES_IMU's, ODOMETRY's (in wire order), LOCAL_POSITION_NED's,
    the four packets' bytes), each field tuple in pymavlink's wire order and with its values (the
    same floats: float32 widened). None for anything else (another layout, a signed or foreign
    packet, a bad CRC, trailing bytes): the link's full parse then handles it, counts and all."""
    out = []
    packets = []
    i = 0
    size = len(data)
    for msg_id, extra, unpack_from, full in _STATE_LAYOUT:
        if i + 12 > size or data[i] != 0xFD or data[i + 2] or data[i + 3]:
            return None
        n = data[i + 1]
        end = i + 12 + n
        if (end > size or data[i + 5] != system or data[i + 6] != SIM_COMPONENT_ID
                or (data[i + 7] | (data[i + 8] << 8) | (data[i + 9] << 16)) != msg_id):  # fmt: skip
            return None
        packet = data[i:end]
        checked = _checked_payload(packet, extra, full)
        if checked is None:
            return None
        out.append(unpack_from(checked[0]))
        packets.append(packet)
        i = end
    if i != size:
        return None
    return out[0], out[1], out[2], out[3], (packets[0], packets[1], packets[2], packets[3])

