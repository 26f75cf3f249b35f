"""The FC's per-tick datagrams, compiled: the simulator's state decoded, the tick's answer and record made.

A lockstep flight controller receives one datagram a tick from the simulator (ATTITUDE, HIGHRES_IMU,
ODOMETRY, LOCAL_POSITION_NED, as :class:`smcpilot.fastcodec.TickRecords` writes them). In CPython,
:func:`smcpilot.fastcodec.decode_state_datagram` unpacks it and :func:`fc.app.state_from_wire`
converts it; :func:`decode_state` does both in one pass, in the pure style, for numba to compile:
the frames checked (layout, system and component, message ids, CRCs), the float32 fields widened,
the 12 wire values converted to the paper frame (:func:`smcpilot.wire.paper_of_wire`, the one
conversion), infinite values made NaN and counted as ``state_from_wire`` counts them. The results go
into two arrays the caller owns (:data:`F_STATE` …, :data:`I_STAMP` …): nothing crosses the boundary
as a tuple. A datagram of any other shape gives 0 and the caller parses it the ordinary way.

Same values as the CPython pair, bit for bit (``tests/test_state_kernel.py``; the sign of a NaN
aside, which nothing reads). Run in CPython the function is correct but slow (a loop over the
bytes): :func:`compiled_decoder` gives the compiled entry point, or None, and the caller then keeps
the CPython pair.

The other way, :func:`encode_answer` makes the tick's HIL_ACTUATOR_CONTROLS and its ``SMC`` log
record from the compiled pipeline's outputs in one call (:func:`compiled_answer_encoder`), the
bytes :class:`smcpilot.fastcodec.TickRecords` makes of :func:`fc.telemetry.smc_record`. The
framing both use is :mod:`smcpilot.framing`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from fc.compiled_pipeline import IO_OUT as _IO_OUT
from smcpilot.framing import (
    ATTITUDE,
    DEBUG_FLOAT_ARRAY,
    FRAMING_FUNCTIONS,
    HEADER_BYTES,
    HIGHRES_IMU,
    HIL_ACTUATOR_CONTROLS,
    LOCAL_POSITION_NED,
    ODOMETRY,
    crc_x25,
    frame,
    get_byte,
    get_f32,
    get_u32,
    get_u64,
    put_f32,
    put_u64,
)
from smcpilot.protocol import FC_COMPONENT_ID, SIM_COMPONENT_ID, SMC_ARRAY_ID
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

_IDS = (ATTITUDE[0], HIGHRES_IMU[0], ODOMETRY[0], LOCAL_POSITION_NED[0])
_EXTRAS = (ATTITUDE[1], HIGHRES_IMU[1], ODOMETRY[1], LOCAL_POSITION_NED[1])
_COMPONENT = int(SIM_COMPONENT_ID)
#: HIGHRES_IMU's fields_updated: after time_usec (8 bytes) and 13 floats.
_IMU_FIELDS_AT = 8 + 13 * 4
_NAN = math.nan
_isfinite = math.isfinite


def _six_f32(data, j, end, bits, f32):  # type: ignore[no-untyped-def]
    """The six float32 from ``data[j]`` (ATTITUDE's and LOCAL_POSITION_NED's after their stamp), widened."""
    return (
        get_f32(data, j, end, bits, f32), get_f32(data, j + 4, end, bits, f32), get_f32(data, j + 8, end, bits, f32),
        get_f32(data, j + 12, end, bits, f32), get_f32(data, j + 16, end, bits, f32), get_f32(data, j + 20, end, bits, f32),
    )  # fmt: skip


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
            roll, pitch, yaw, ps, qs, rs = _six_f32(data, p + 4, body, bits, f32)
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
            xn, yn, zn, vxn, vyn, vzn = _six_f32(data, p + 4, body, bits, f32)
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


# -- the tick's answer and log record ---------------------------------------------------------------
#: the answer's constants (``consts``, int64): the simulator's system id (the answer's source
#: system), this FC's (the log record's), the answer's flags (HIL_ACTUATOR_CONTROLS ``flags``), and
#: whether the law reports S, sigma and chi-hat (1/0: the record's NaN where not).
C_SIM_SYSID = 0
C_SYSID = 1
C_ACT_FLAGS = 2
C_HAS_S = 3
C_HAS_SIGMA = 4
C_HAS_CHI = 5
C_SIZE = 6
#: the compiled pipeline's outputs in its ``io`` array (:data:`fc.compiled_pipeline.IO_OUT` on):
#: motors, realised inputs, limited, S, sigma, chi-hat, ... references.
O_MOTORS = 0
O_U = 4
O_LIMITED = 8
O_S = 12
O_SIGMA = 16
O_CHI = 20
O_REF = 32
#: the answer and the record together, at most (two frames of at most 12 + 255 bytes).
ANSWER_BYTES = 2 * (12 + 255)
_ID_HIL, _X_HIL = HIL_ACTUATOR_CONTROLS
_ID_DFA, _X_DFA = DEBUG_FLOAT_ARRAY
_FC_COMPONENT = int(FC_COMPONENT_ID)
_SMC_ID = int(SMC_ARRAY_ID)


def encode_answer(io, o, t_us, act_seq, act_mode, log_seq, flags, mode, tx, ty, tz, yaw_t, consts, name, out, bits, f32):  # type: ignore[no-untyped-def]
    """The tick's HIL_ACTUATOR_CONTROLS (to the simulator) and its ``SMC`` DEBUG_FLOAT_ARRAY (to the
    log), as :class:`smcpilot.fastcodec.TickRecords` makes them of :func:`fc.telemetry.smc_record`,
    from the compiled pipeline's outputs (``io`` from ``o``: see :data:`O_MOTORS` …) and the tick's
    set-point (``tx``, ``ty``, ``tz`` m, ``yaw_t`` rad), flags and mode, into ``out`` (uint8,
    :data:`ANSWER_BYTES`); ``name``: the record's 10-byte name. Returns ``len(answer) |
    len(record) << 16``, or 0 when a value does not fit a float32 (CPython makes both then)."""
    ok = True
    # HIL_ACTUATOR_CONTROLS: time_usec, flags, controls[16] (our four rotors, then zeros), mode
    put_u64(out, 10, t_us)
    put_u64(out, 18, consts[C_ACT_FLAGS])
    for k in range(4):
        ok = put_f32(out, 26 + 4 * k, io[o + O_MOTORS + k], bits, f32) and ok
    for j in range(42, 90):
        out[j] = 0
    out[90] = act_mode
    n1 = frame(out, 0, 81, _ID_HIL, _X_HIL, act_seq, consts[C_SIM_SYSID], _FC_COMPONENT)
    # DEBUG_FLOAT_ARRAY "SMC": time_usec, array_id, name, data[58] (fc.telemetry.smc_data)
    s = n1
    put_u64(out, s + 10, t_us)
    out[s + 18] = _SMC_ID & 0xFF
    out[s + 19] = (_SMC_ID >> 8) & 0xFF
    for k in range(10):
        out[s + 20 + k] = name[k]
    d = s + 30
    for k in range(4):
        ok = put_f32(out, d + 4 * k, io[o + O_CHI + k] if consts[C_HAS_CHI] else _NAN, bits, f32) and ok
        ok = put_f32(out, d + 16 + 4 * k, io[o + O_SIGMA + k] if consts[C_HAS_SIGMA] else _NAN, bits, f32) and ok
        ok = put_f32(out, d + 32 + 4 * k, io[o + O_S + k] if consts[C_HAS_S] else _NAN, bits, f32) and ok
        ok = put_f32(out, d + 48 + 4 * k, io[o + O_U + k], bits, f32) and ok
        ok = put_f32(out, d + 64 + 4 * k, io[o + O_REF + k], bits, f32) and ok
        ok = put_f32(out, d + 80 + 4 * k, io[o + O_MOTORS + k], bits, f32) and ok
    ok = put_f32(out, d + 96, tx, bits, f32) and ok
    ok = put_f32(out, d + 100, ty, bits, f32) and ok
    ok = put_f32(out, d + 104, tz, bits, f32) and ok
    ok = put_f32(out, d + 108, yaw_t, bits, f32) and ok
    lim = 0
    for k in range(4):
        if io[o + O_LIMITED + k] != 0.0:
            lim += 1 << k
    ok = put_f32(out, d + 112, float(lim), bits, f32) and ok
    ok = put_f32(out, d + 116, float(flags), bits, f32) and ok
    ok = put_f32(out, d + 120, float(mode), bits, f32) and ok
    for j in range(d + 124, d + 232):
        out[j] = 0
    n2 = frame(out, s, 252, _ID_DFA, _X_DFA, log_seq, consts[C_SYSID], _FC_COMPONENT) - n1
    if not ok:
        return 0
    return n1 | (n2 << 16)


class AnswerEncoder:
    """:func:`encode_answer`'s compiled entry point with its arrays, for one FC."""

    def __init__(self, entry: Any, sim_sysid: int, sysid: int, act_flags: int, mask: tuple[bool, ...]) -> None:
        from smcpilot.fastcodec import SMC_NAME

        self._entry = entry
        #: the law's diagnostics mask it was made for (:attr:`fc.flight.FlightControl.diag_mask`: S,
        #: sigma, chi-hat, u-dot reported; the record has NaN for the first three where not).
        self.mask = tuple(mask)
        self.consts = np.array([sim_sysid, sysid, act_flags, int(mask[0]), int(mask[1]), int(mask[2])], dtype=np.int64)
        self.name = np.frombuffer(SMC_NAME.ljust(10, b"\0"), dtype=np.uint8).copy()
        self.out = np.zeros(ANSWER_BYTES, dtype=np.uint8)
        self._bits = np.zeros(1, dtype=np.uint32)
        self._f32 = self._bits.view(np.float32)
        #: answers made.
        self.made = 0

    def encode(self, io: Any, t_us: int, act_seq: int, act_mode: int, log_seq: int, flags: int, mode: int,
               target: tuple[float, float, float], yaw_t: float) -> tuple[bytes, bytes] | None:  # fmt: skip
        """(the answer, the record) of the compiled pipeline's outputs in ``io``; None when a value
        does not fit a float32 (make them in CPython)."""
        n = self._entry(io, _IO_OUT, t_us, act_seq, act_mode, log_seq, flags, mode, target[0], target[1], target[2], yaw_t,
                        self.consts, self.name, self.out, self._bits, self._f32)  # fmt: skip
        if not n:
            return None
        self.made += 1
        n1 = n & 0xFFFF
        b = self.out[: n1 + (n >> 16)].tobytes()
        return b[:n1], b[n1:]


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


#: the decoder's and the encoder's functions (with :func:`smcpilot.wire.paper_of_wire`'s closure:
#: compiled, also into :mod:`fc.lockstep_kernel`).
KERNEL_FUNCTIONS = (decode_state, _six_f32, _finite_or_nan, encode_answer, *FRAMING_FUNCTIONS)

_TWINS: dict[Any, Any] = {}


def _twins() -> dict[Any, Any]:
    """The compiled twins (made once a process: every flight controller of a group shares them)."""
    if _TWINS:
        return _TWINS
    from fc.control.purity import pure_closure
    from smcpilot.jit import compile_pure

    wire, problems = pure_closure((paper_of_wire,))  # (the wire's conversion and what it calls)
    assert not problems, problems
    _TWINS.update(compile_pure((*KERNEL_FUNCTIONS, *wire)))
    return _TWINS


def compiled_answer_encoder(sim_sysid: int, sysid: int, act_flags: int, mask: tuple[bool, ...], *,
                            compile_new: bool) -> AnswerEncoder | None:  # fmt: skip
    """The compiled :func:`encode_answer` for an FC (``mask``: the law's diagnostics mask), as
    :func:`compiled_decoder` has it (None when it cannot be had)."""
    from smcpilot.jit import cached_entry, jit_unavailable_reason, numba_module

    if jit_unavailable_reason() is not None:
        return None
    t = numba_module().types
    sig = (t.float64[::1], *(t.int64,) * 7, *(t.float64,) * 4, t.int64[::1], t.uint8[::1], t.uint8[::1], t.uint32[::1], t.float32[::1])
    entry = cached_entry(_twins()[encode_answer], sig, compile_new=compile_new)
    return None if entry is None else AnswerEncoder(entry, sim_sysid, sysid, act_flags, mask)


def compiled_decoder(*, compile_new: bool) -> StateDecoder | None:
    """The compiled :func:`decode_state` (loaded from numba's on-disk cache, or compiled first when
    ``compile_new``: a few seconds, once), or None when it cannot be had (no numba, JIT off, not
    cached and not ``compile_new``)."""
    from smcpilot.jit import cached_entry, jit_unavailable_reason, numba_module

    if jit_unavailable_reason() is not None:
        return None
    types = numba_module().types
    sig = (
        types.Bytes(types.uint8, 1, "C", readonly=True), types.int64, types.float64[::1], types.uint64[::1],
        types.uint32[::1], types.float32[::1],
    )  # fmt: skip
    entry = cached_entry(_twins()[decode_state], sig, compile_new=compile_new)
    return None if entry is None else StateDecoder(entry)
