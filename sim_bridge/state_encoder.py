"""A vehicle's per-tick state datagram, made compiled: the observation to the wire's bytes in one call.

Each control period the simulator sends each vehicle's FC one datagram: ATTITUDE, HIGHRES_IMU,
ODOMETRY, LOCAL_POSITION_NED (:meth:`sim_bridge.app.SimVehicle.make_state`). In CPython that is
two wire conversions (:func:`smcpilot.wire.wire_of_paper`), the accelerometer's specific force
(:func:`sim_bridge.sensors.specific_force_frd`), the truth's quaternion in NED/FRD and four packets
packed and framed by :class:`smcpilot.fastcodec.TickRecords`. :func:`encode_state` does all of it
in the pure style, for numba to compile, into a byte array the caller owns; the same bytes as
``TickRecords`` (``tests/test_state_encoder.py``). Two kinds of state give 0, and the caller makes
them in CPython: a finite value beyond float32's range, which ``TickRecords`` refuses (``struct``
raises, as it always has), and a NaN anywhere (a sensor's dropout, say): the sign of a NaN that
arithmetic makes is not fixed by IEEE 754, and compiled code gives +NaN where CPython gives −NaN
(the specific force of a NaN quaternion), which would change the FC's log.

The FC's side decodes these datagrams the same way: :mod:`fc.state_kernel`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim_bridge.sensors import specific_force_frd
from smcpilot.fastcodec import TickRecords
from smcpilot.frames import (
    euler_flu_to_frd,
    flu_to_frd,
    nwu_to_ned,
    quat_nwu_flu_to_ned_frd,
    quat_rotate,
    quat_rotate_inverse,
    rates_flu_to_frd,
)
from smcpilot.framing import ATTITUDE, FRAMING_FUNCTIONS, HIGHRES_IMU, LOCAL_POSITION_NED, ODOMETRY, frame, put_f32, put_u32, put_u64
from smcpilot.protocol import IMU_FIELDS_UPDATED, SIM_COMPONENT_ID
from smcpilot.wire import wire_of_paper

#: the inputs (``vin``, float64): the observation's Euler angles (rad, FLU in NWU), body rates
#: (rad/s, FLU), position (m, NWU), velocity (m/s, NWU), acceleration (m/s^2, NWU); the truth's
#: quaternion (FLU in NWU), Euler angles, body rates, position, velocity; gravity (m/s^2).
V_OBS = 0
V_ACCEL = 12
V_QUAT = 15
V_TRUTH = 19
V_GRAVITY = 31
V_SIZE = 32
#: the largest datagram (four packets of at most 12 + 255 bytes), the buffer's size.
OUT_BYTES = 4 * (12 + 255)
#: the longest datagram :func:`encode_state` makes: four untrimmed payloads (28, 63, 233, 28 bytes),
#: 12 bytes of header and CRC each.
DATAGRAM_MAX_BYTES = 4 * 12 + 28 + 63 + 233 + 28

_ID_ATT, _X_ATT = ATTITUDE
_ID_IMU, _X_IMU = HIGHRES_IMU
_ID_ODO, _X_ODO = ODOMETRY
_ID_LPN, _X_LPN = LOCAL_POSITION_NED
_COMPONENT = int(SIM_COMPONENT_ID)
_IMU_FIELDS = int(IMU_FIELDS_UPDATED)


def _put_f32_nan(out, j, x, bits, f32):  # type: ignore[no-untyped-def]
    """:func:`smcpilot.framing.put_f32`, and False for a NaN too (whose sign compiled arithmetic
    does not give as CPython's does: CPython makes that state)."""
    if x != x:
        return False
    return put_f32(out, j, x, bits, f32)


def _floats(out, j, ok, a, b, c, bits, f32):  # type: ignore[no-untyped-def]
    """Three float32 at ``out[j]``; ``ok`` and-ed with each one's range check."""
    ok = _put_f32_nan(out, j, a, bits, f32) and ok
    ok = _put_f32_nan(out, j + 4, b, bits, f32) and ok
    return _put_f32_nan(out, j + 8, c, bits, f32) and ok


def encode_state(vin, t_us, seq, sysid, odo_tail, out, bits, f32):  # type: ignore[no-untyped-def]
    """The state datagram of ``vin`` (see :data:`V_OBS` …) stamped ``t_us`` (µs) into ``out`` (uint8,
    :data:`OUT_BYTES`), the four packets numbered ``seq`` … ``seq + 3`` (mod 256) from ``sysid``'s
    simulator component; ``odo_tail``: ODOMETRY's constant tail (:attr:`TickRecords.odo_tail`).
    Returns the datagram's length, or 0 when a value is NaN or does not fit a float32 (the caller
    then makes this state in CPython)."""
    roll, pitch, yaw, p, q, r, x, y, z, vx, vy, vz = wire_of_paper(
        vin[0], vin[1], vin[2], vin[3], vin[4], vin[5], vin[6], vin[7], vin[8], vin[9], vin[10], vin[11]
    )  # fmt: skip
    quat = (vin[V_QUAT], vin[V_QUAT + 1], vin[V_QUAT + 2], vin[V_QUAT + 3])
    fx, fy, fz = specific_force_frd((vin[V_ACCEL], vin[V_ACCEL + 1], vin[V_ACCEL + 2]), quat, vin[V_GRAVITY])
    tv = V_TRUTH
    _a, _b, _c, tp, tq, tr, tx, ty, tz, tvx, tvy, tvz = wire_of_paper(
        vin[tv], vin[tv + 1], vin[tv + 2], vin[tv + 3], vin[tv + 4], vin[tv + 5], vin[tv + 6], vin[tv + 7], vin[tv + 8],
        vin[tv + 9], vin[tv + 10], vin[tv + 11],
    )  # fmt: skip
    qw, qx, qy, qz = quat_nwu_flu_to_ned_frd(quat)
    t_ms = (t_us // 1000) & 0xFFFFFFFF
    ok = True
    # ATTITUDE: time_boot_ms, roll, pitch, yaw, rollspeed, pitchspeed, yawspeed
    s = 0
    put_u32(out, s + 10, t_ms)
    ok = _floats(out, s + 14, ok, roll, pitch, yaw, bits, f32)
    ok = _floats(out, s + 26, ok, p, q, r, bits, f32)
    s = frame(out, s, 28, _ID_ATT, _X_ATT, seq, sysid, _COMPONENT)
    # HIGHRES_IMU: time_usec, xacc .. zgyro, seven zeros, fields_updated, id
    put_u64(out, s + 10, t_us)
    ok = _floats(out, s + 18, ok, fx, fy, fz, bits, f32)
    ok = _floats(out, s + 30, ok, p, q, r, bits, f32)
    for j in range(s + 42, s + 70):
        out[j] = 0
    out[s + 70] = _IMU_FIELDS & 0xFF
    out[s + 71] = (_IMU_FIELDS >> 8) & 0xFF
    out[s + 72] = 0
    s = frame(out, s, 63, _ID_IMU, _X_IMU, seq + 1, sysid, _COMPONENT)
    # ODOMETRY: time_usec, x, y, z, q[4], vx, vy, vz, rollspeed, pitchspeed, yawspeed, the constant tail
    put_u64(out, s + 10, t_us)
    ok = _floats(out, s + 18, ok, tx, ty, tz, bits, f32)
    ok = _put_f32_nan(out, s + 30, qw, bits, f32) and ok
    ok = _floats(out, s + 34, ok, qx, qy, qz, bits, f32)
    ok = _floats(out, s + 46, ok, tvx, tvy, tvz, bits, f32)
    ok = _floats(out, s + 58, ok, tp, tq, tr, bits, f32)
    n_tail = len(odo_tail)
    for j in range(n_tail):
        out[s + 70 + j] = odo_tail[j]
    s = frame(out, s, 60 + n_tail, _ID_ODO, _X_ODO, seq + 2, sysid, _COMPONENT)
    # LOCAL_POSITION_NED: time_boot_ms, x, y, z, vx, vy, vz
    put_u32(out, s + 10, t_ms)
    ok = _floats(out, s + 14, ok, x, y, z, bits, f32)
    ok = _floats(out, s + 26, ok, vx, vy, vz, bits, f32)
    s = frame(out, s, 28, _ID_LPN, _X_LPN, seq + 3, sysid, _COMPONENT)
    return s if ok else 0


class StateEncoder:
    """:func:`encode_state`'s compiled entry point with the arrays it uses, for one vehicle."""

    def __init__(self, entry: Any, sysid: int) -> None:
        self._entry = entry
        self.sysid = sysid
        self.vin = np.zeros(V_SIZE)
        self.out = np.zeros(OUT_BYTES, dtype=np.uint8)
        self._tail = np.frombuffer(TickRecords(sysid).odo_tail, dtype=np.uint8).copy()
        self._bits = np.zeros(1, dtype=np.uint32)
        self._f32 = self._bits.view(np.float32)
        #: datagrams made.
        self.made = 0

    def encode(self, t_us: int, seq: int) -> bytes | None:
        """The datagram of :attr:`vin` (filled by the caller) stamped ``t_us``, its packets numbered
        from ``seq``; None when a value is NaN or does not fit a float32 (make it in CPython)."""
        n: int = self._entry(self.vin, t_us, seq, self.sysid, self._tail, self.out, self._bits, self._f32)
        if not n:
            return None
        self.made += 1
        return self.out[:n].tobytes()


#: :func:`encode_state` and every function it calls, compiled together (also with the simulator's
#: fused physics and state, :mod:`sim_bridge.fused_state`).
ENCODER_FUNCTIONS = (
    encode_state, _put_f32_nan, _floats, *FRAMING_FUNCTIONS, wire_of_paper, specific_force_frd,
    quat_nwu_flu_to_ned_frd, euler_flu_to_frd, rates_flu_to_frd, nwu_to_ned, flu_to_frd, quat_rotate_inverse, quat_rotate,
)  # fmt: skip

_TWINS: dict[Any, Any] = {}


def _twins() -> dict[Any, Any]:
    """The compiled twins (made once a process)."""
    if not _TWINS:
        from smcpilot.jit import compile_pure

        _TWINS.update(compile_pure(ENCODER_FUNCTIONS))
    return _TWINS


def compiled_encoder(sysid: int, *, compile_new: bool) -> StateEncoder | None:
    """The compiled :func:`encode_state` for vehicle ``sysid`` (loaded from numba's on-disk cache, or
    compiled first when ``compile_new``: a few seconds, once), or None when it cannot be had (no
    numba, JIT off, not cached and not ``compile_new``)."""
    from smcpilot.jit import cached_entry, jit_unavailable_reason, numba_module

    if jit_unavailable_reason() is not None:
        return None
    types = numba_module().types
    sig = (types.float64[::1], types.int64, types.int64, types.int64, types.uint8[::1], types.uint8[::1], types.uint32[::1],
           types.float32[::1])  # fmt: skip
    entry = cached_entry(_twins()[encode_state], sig, compile_new=compile_new)
    return None if entry is None else StateEncoder(entry, sysid)
