"""The simulator's per-tick state datagram, decoded compiled: bytes to the flight core's inputs in one call.

A lockstep flight controller receives one datagram a tick from the simulator (ATTITUDE, HIGHRES_IMU,
ODOMETRY, LOCAL_POSITION_NED, as :class:`smcpilot.fastcodec.TickRecords` writes them). In CPython,
:func:`smcpilot.fastcodec.decode_state_datagram` unpacks it and :func:`fc.app.state_from_wire`
converts it; :func:`decode_state` does both in one pass, in the pure style, for numba to compile:
the frames checked (layout, system and component, message ids, CRCs), the float32 fields widened,
the 12 wire values converted to the paper frame (:func:`smcpilot.wire.paper_of_wire`, the one
conversion), infinite values made NaN and counted as ``state_from_wire`` counts them. The results go
into two arrays the caller owns (:data:`F_STATE` …, :data:`I_STAMP` …): nothing crosses the boundary
as a tuple. A datagram of any other shape gives 0 and the caller parses it the ordinary way.

Same values as the CPython pair, bit for bit (``tests/test_state_kernel.py``). Run in CPython the
function is correct but slow (a loop over the bytes): :func:`compiled_decoder` gives the compiled
entry point, or None, and the caller then keeps the CPython pair.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot.framing import FRAMING_FUNCTIONS, HEADER_BYTES, crc_x25, get_byte, get_f32, get_u32, get_u64
from smcpilot.protocol import SIM_COMPONENT_ID
from smcpilot.wire import paper_of_wire

#: the float outputs: the paper-frame state (:class:`fc.pipeline.VehicleState`'s 12 values), then
#: the body rates p, q, r (FLU, rad/s), then HIGHRES_IMU's xacc, yacc, zacc (m/s^2, float32 widened).
F_STATE = 0
F_RATES = 12
F_ACCEL = 15
F_SIZE = 18
#: the integer outputs (uint64): ATTITUDE's time_boot_ms (ms), ``missing`` (0: every wire value
#: finite, 1: some NaN, 2: some infinite), HIGHRES_IMU's time_usec and fields_updated, ODOMETRY's
#: time_usec, then the end offsets of the four packets in the datagram (bytes).
I_STAMP = 0
I_MISSING = 1
I_IMU_USEC = 2
I_IMU_FIELDS = 3
I_ODO_USEC = 4
I_ENDS = 5
I_SIZE = 9

_ID_ATT = int(mavlink.MAVLINK_MSG_ID_ATTITUDE)
_ID_IMU = int(mavlink.MAVLINK_MSG_ID_HIGHRES_IMU)
_ID_ODO = int(mavlink.MAVLINK_MSG_ID_ODOMETRY)
_ID_LPN = int(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
_IDS = (_ID_ATT, _ID_IMU, _ID_ODO, _ID_LPN)
_EXTRAS = (
    int(mavlink.MAVLink_attitude_message.crc_extra), int(mavlink.MAVLink_highres_imu_message.crc_extra),
    int(mavlink.MAVLink_odometry_message.crc_extra), int(mavlink.MAVLink_local_position_ned_message.crc_extra),
)  # fmt: skip
_COMPONENT = int(SIM_COMPONENT_ID)
#: HIGHRES_IMU's fields_updated: after time_usec (8 bytes) and 13 floats.
_IMU_FIELDS_AT = 8 + 13 * 4
_NAN = math.nan
_isfinite = math.isfinite


def decode_state(data, system, fo, io, bits, f32):  # type: ignore[no-untyped-def]
    """Decode the state datagram ``data`` (bytes) from ``system``'s simulator component into ``fo``
    (float64, :data:`F_SIZE`) and ``io`` (uint64, :data:`I_SIZE`); ``bits``/``f32``: a uint32 array
    of one element and its float32 view. 1 when it is the simulator's state datagram with good CRCs
    and ATTITUDE's stamp equal to LOCAL_POSITION_NED's; else 0 (the arrays then hold nothing useful)."""
    size = len(data)
    i = 0
    for k in range(4):
        if i + 12 > size or data[i] != 0xFD or data[i + 2] != 0 or data[i + 3] != 0:
            return 0
        n = data[i + 1]
        end = i + 12 + n
        if end > size or data[i + 5] != system or data[i + 6] != _COMPONENT:
            return 0
        if (data[i + 7] | (data[i + 8] << 8) | (data[i + 9] << 16)) != _IDS[k]:
            return 0
        body = i + HEADER_BYTES + n
        if crc_x25(data, i + 1, body, _EXTRAS[k]) != (data[body] | (data[body + 1] << 8)):
            return 0
        p = i + HEADER_BYTES
        if k == 0:
            t_ms = get_u32(data, p, body)
            roll = get_f32(data, p + 4, body, bits, f32)
            pitch = get_f32(data, p + 8, body, bits, f32)
            yaw = get_f32(data, p + 12, body, bits, f32)
            ps = get_f32(data, p + 16, body, bits, f32)
            qs = get_f32(data, p + 20, body, bits, f32)
            rs = get_f32(data, p + 24, body, bits, f32)
        elif k == 1:
            io[I_IMU_USEC] = get_u64(data, p, body)
            fo[F_ACCEL] = get_f32(data, p + 8, body, bits, f32)
            fo[F_ACCEL + 1] = get_f32(data, p + 12, body, bits, f32)
            fo[F_ACCEL + 2] = get_f32(data, p + 16, body, bits, f32)
            io[I_IMU_FIELDS] = get_byte(data, p + _IMU_FIELDS_AT, body) | (get_byte(data, p + _IMU_FIELDS_AT + 1, body) << 8)
        elif k == 2:
            io[I_ODO_USEC] = get_u64(data, p, body)
        else:
            if get_u32(data, p, body) != t_ms:
                return 0
            xn = get_f32(data, p + 4, body, bits, f32)
            yn = get_f32(data, p + 8, body, bits, f32)
            zn = get_f32(data, p + 12, body, bits, f32)
            vxn = get_f32(data, p + 16, body, bits, f32)
            vyn = get_f32(data, p + 20, body, bits, f32)
            vzn = get_f32(data, p + 24, body, bits, f32)
        io[I_ENDS + k] = end
        i = end
    if i != size:
        return 0
    # fc.app.state_from_wire: an infinite value is garbage, NaN too ("missing" says which it was)
    missing = 0
    if not _isfinite(roll + pitch + yaw + ps + qs + rs + xn + yn + zn + vxn + vyn + vzn):
        roll, m0 = _finite_or_nan(roll)
        pitch, m1 = _finite_or_nan(pitch)
        yaw, m2 = _finite_or_nan(yaw)
        ps, m3 = _finite_or_nan(ps)
        qs, m4 = _finite_or_nan(qs)
        rs, m5 = _finite_or_nan(rs)
        xn, m6 = _finite_or_nan(xn)
        yn, m7 = _finite_or_nan(yn)
        zn, m8 = _finite_or_nan(zn)
        vxn, m9 = _finite_or_nan(vxn)
        vyn, m10 = _finite_or_nan(vyn)
        vzn, m11 = _finite_or_nan(vzn)
        missing = max(m0, m1, m2, m3, m4, m5, m6, m7, m8, m9, m10, m11)
    s = paper_of_wire(roll, pitch, yaw, ps, qs, rs, xn, yn, zn, vxn, vyn, vzn)
    for j in range(15):
        fo[F_STATE + j] = s[j]
    io[I_STAMP] = t_ms
    io[I_MISSING] = missing
    return 1


def _finite_or_nan(v):  # type: ignore[no-untyped-def]
    """(``v``, 0) when finite; (NaN, 1) for NaN; (NaN, 2) for an infinite value."""
    if _isfinite(v):
        return v, 0
    return _NAN, (1 if v != v else 2)


class StateDecoder:
    """:func:`decode_state`'s compiled entry point with the arrays it fills.

    ``decode(data, system)`` is 1 when the datagram was decoded into :attr:`fo` / :attr:`io`."""

    def __init__(self, entry: Any) -> None:
        self._entry = entry
        #: datagrams decoded (1 returned).
        self.decoded = 0
        self.fo = np.zeros(F_SIZE)
        self.io = np.zeros(I_SIZE, dtype=np.uint64)
        self._bits = np.zeros(1, dtype=np.uint32)
        self._f32 = self._bits.view(np.float32)

    def decode(self, data: bytes, system: int) -> int:
        ok: int = self._entry(data, system, self.fo, self.io, self._bits, self._f32)
        self.decoded += ok
        return ok


_TWINS: dict[Any, Any] = {}


def _twins() -> dict[Any, Any]:
    """The compiled twins (made once a process: every flight controller of a group shares them)."""
    if _TWINS:
        return _TWINS
    from fc.control.purity import pure_closure
    from smcpilot.jit import compile_pure

    wire, problems = pure_closure((paper_of_wire,))  # (the wire's conversion and what it calls)
    assert not problems, problems
    _TWINS.update(compile_pure((decode_state, _finite_or_nan, *FRAMING_FUNCTIONS, *wire)))
    return _TWINS


def compiled_decoder(*, compile_new: bool) -> StateDecoder | None:
    """The compiled :func:`decode_state` (loaded from numba's on-disk cache, or compiled first when
    ``compile_new``: a few seconds, once), or None when it cannot be had (no numba, JIT off, not
    cached and not ``compile_new``)."""
    from smcpilot.jit import cache_index, jit_unavailable_reason, numba_module

    if jit_unavailable_reason() is not None:
        return None
    import os

    twins = _twins()
    fn = twins[decode_state]
    index = cache_index(fn)
    if not compile_new and (index is None or not os.path.exists(index)):
        return None
    types = numba_module().types
    sig = (
        types.Bytes(types.uint8, 1, "C", readonly=True), types.int64, types.float64[::1], types.uint64[::1],
        types.uint32[::1], types.float32[::1],
    )  # fmt: skip
    fn.compile(sig)
    return StateDecoder(fn.overloads[sig].entry_point)
