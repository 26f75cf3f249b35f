"""MAVLink 2 framing at the byte level, in the pure style: what the compiled per-tick codecs share.

The simulator makes each vehicle's state datagram compiled (:mod:`sim_bridge.state_encoder`); the
FC decodes it compiled, and makes its answer and its log record the same way
(:mod:`fc.state_kernel`). These functions read and write little-endian fields in byte arrays,
frame a payload (header, MAVLink 2's trimming of trailing zeros, the CRC) and check a frame's CRC,
as :mod:`smcpilot.fastcodec` and pymavlink do in CPython. They run in CPython (slowly: a loop over
the bytes) and compile unchanged under numba (:func:`smcpilot.jit.compile_pure`); a caller compiles
them with its own kernel (:data:`FRAMING_FUNCTIONS`).

``bits`` and ``f32`` below are a uint32 array of one element and its float32 view: the way to turn
a float32's bits into a value and back without a per-call allocation.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

#: MAVLink 2 header bytes (magic, length, flags, seq, system, component, id).
HEADER_BYTES = 10


def _id_extra(cls: type) -> tuple[int, int]:
    return int(cls.id), int(cls.crc_extra)  # type: ignore[attr-defined]


#: (message id, CRC_EXTRA) of the per-tick messages: the simulator's state datagram in its order
#: (ATTITUDE, HIGHRES_IMU, ODOMETRY, LOCAL_POSITION_NED), the FC's answer and its SMC record.
ATTITUDE = _id_extra(mavlink.MAVLink_attitude_message)
HIGHRES_IMU = _id_extra(mavlink.MAVLink_highres_imu_message)
ODOMETRY = _id_extra(mavlink.MAVLink_odometry_message)
LOCAL_POSITION_NED = _id_extra(mavlink.MAVLink_local_position_ned_message)
HIL_ACTUATOR_CONTROLS = _id_extra(mavlink.MAVLink_hil_actuator_controls_message)
DEBUG_FLOAT_ARRAY = _id_extra(mavlink.MAVLink_debug_float_array_message)
_F32_MAX = 3.4028234663852886e38


def crc_x25(data, start, end, extra):  # type: ignore[no-untyped-def]
    """MAVLink's CRC-16/MCRF4XX of ``data[start:end]`` and then the byte ``extra``."""
    crc = 0xFFFF
    for j in range(start, end + 1):
        b = int(data[j]) if j < end else extra
        tmp = (b ^ (crc & 0xFF)) & 0xFF
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        crc = ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    return crc


def get_byte(data, j, end):  # type: ignore[no-untyped-def]
    """``data[j]``, or 0 past the payload's ``end`` (MAVLink 2 trims a payload's trailing zeros)."""
    return int(data[j]) if j < end else 0


def get_u32(data, j, end):  # type: ignore[no-untyped-def]
    return get_byte(data, j, end) | (get_byte(data, j + 1, end) << 8) | (get_byte(data, j + 2, end) << 16) | (get_byte(data, j + 3, end) << 24)


def get_u64(data, j, end):  # type: ignore[no-untyped-def]
    return np.uint64(get_u32(data, j, end)) | (np.uint64(get_u32(data, j + 4, end)) << np.uint64(32))


def get_f32(data, j, end, bits, f32):  # type: ignore[no-untyped-def]
    """The little-endian float32 at ``data[j]``, widened."""
    bits[0] = get_u32(data, j, end)
    return np.float64(f32[0])


def put_u32(out, j, v):  # type: ignore[no-untyped-def]
    out[j] = v & 0xFF
    out[j + 1] = (v >> 8) & 0xFF
    out[j + 2] = (v >> 16) & 0xFF
    out[j + 3] = (v >> 24) & 0xFF


def put_u64(out, j, v):  # type: ignore[no-untyped-def]
    put_u32(out, j, v & 0xFFFFFFFF)
    put_u32(out, j + 4, (v >> 32) & 0xFFFFFFFF)


def put_f32(out, j, x, bits, f32):  # type: ignore[no-untyped-def]
    """``x`` as a little-endian float32 at ``out[j]``; False when a finite ``x`` is beyond float32's
    range (``struct`` raises there: the caller leaves that record to CPython)."""
    if math.isfinite(x) and (x > _F32_MAX or x < -_F32_MAX):
        f32[0] = x
        if not math.isfinite(f32[0]):
            return False
    f32[0] = x
    put_u32(out, j, np.int64(bits[0]))
    return True


def frame(out, start, n_full, msg_id, extra, seq, sysid, compid):  # type: ignore[no-untyped-def]
    """Frame the payload of ``n_full`` bytes written at ``out[start + 10]``: the header, the payload's
    trailing zeros trimmed (one byte kept), the CRC. Returns the packet's end."""
    p = start + HEADER_BYTES
    n = n_full
    while n > 1 and out[p + n - 1] == 0:
        n -= 1
    out[start] = 0xFD
    out[start + 1] = n
    out[start + 2] = 0
    out[start + 3] = 0
    out[start + 4] = seq & 0xFF
    out[start + 5] = sysid
    out[start + 6] = compid
    out[start + 7] = msg_id & 0xFF
    out[start + 8] = (msg_id >> 8) & 0xFF
    out[start + 9] = (msg_id >> 16) & 0xFF
    end = p + n
    crc = crc_x25(out, start + 1, end, extra)
    out[end] = crc & 0xFF
    out[end + 1] = crc >> 8
    return end + 2


#: the functions above (a kernel that calls them compiles them with it).
FRAMING_FUNCTIONS = (crc_x25, get_byte, get_u32, get_u64, get_f32, put_u32, put_u64, put_f32, frame)
