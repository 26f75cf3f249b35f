"""The state datagram's compiled decoder (:mod:`fc.state_kernel`) against the CPython pair it
replaces: :func:`smcpilot.fastcodec.decode_state_datagram` (itself tested against pymavlink in
``tests/test_fastcodec.py``) and :func:`fc.app.state_from_wire`. Bit for bit, for any values the
simulator can send (NaN, infinities, float32 extremes, payloads trimmed to one byte), and the same
refusals. The FC process flying with it writes the log it writes without it:
``tests/test_compiled_pipeline.py`` (``--jit wait`` against ``--jit off``)."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from bits_helpers import needs_jit
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc import state_kernel as sk
from fc.app import state_from_wire
from smcpilot import fastcodec
from tests.test_fastcodec import state_datagram

_F32 = st.one_of(st.floats(width=32), st.sampled_from([0.0, -0.0, math.nan, math.inf, -math.inf, 3.4028234663852886e38]))



def _bits(v: float) -> bytes:
    """``v``'s bits, every NaN alike. A NaN's sign is the one thing that differs: a NaN body rate
    through the Euler-rate conversion comes out as +NaN compiled and -NaN in CPython (IEEE 754 does
    not fix the sign of an operation's NaN; LLVM orders the products differently). Nothing reads
    more than NaN-ness there: such a state is "attitude lost" to the estimate (:mod:`fc.estimate`),
    never flown, never logged (the log has the packets as they came)."""
    return b"nan" if v != v else struct.pack("<d", v)


def _cpython(data: bytes, sysid: int) -> tuple | None:
    """What the FC takes from ``data`` without the kernel: (float outputs, integer outputs, packets) in
    the kernel's layout, or None (the full parse then)."""
    d = fastcodec.decode_state_datagram(data, sysid)
    if d is None or d[0][0] != d[3][0]:
        return None
    att, imu, odo, lpn, packets = d
    state, rates, missing = state_from_wire((*att[1:7], *lpn[1:7]))
    floats = (*state, *rates, imu[1], imu[2], imu[3])
    ends, at = [], 0
    for p in packets:
        at += len(p)
        ends.append(at)
    return floats, (att[0], missing, imu[0], imu[14], odo[0], *ends), packets


def _kernel(decode, data: bytes, sysid: int) -> tuple | None:  # type: ignore[no-untyped-def]
    """The kernel's outputs for ``data`` (``decode``: the compiled entry or the pure function in CPython)."""
    fo = np.zeros(sk.F_SIZE)
    io = np.zeros(sk.I_SIZE, dtype=np.uint64)
    bits = np.zeros(1, dtype=np.uint32)
    if not decode(data, sysid, fo, io, bits, bits.view(np.float32)):
        return None
    ints = io.tolist()
    ends = ints[sk.I_ENDS : sk.I_ENDS + 4]
    packets = (data[: ends[0]], data[ends[0] : ends[1]], data[ends[1] : ends[2]], data[ends[2] : ends[3]])
    return tuple(fo.tolist()), tuple(ints), packets


@pytest.fixture(scope="module")
def compiled():  # type: ignore[no-untyped-def]
    dec = sk.compiled_decoder(compile_new=True)
    assert dec is not None
    return dec._entry


def _same(a: tuple | None, b: tuple | None) -> bool:
    if a is None or b is None:
        return a is b
    return [_bits(x) for x in a[0]] == [_bits(x) for x in b[0]] and a[1] == b[1] and a[2] == b[2]


@needs_jit
@settings(max_examples=400, deadline=None)
@given(st.integers(1, 255), st.integers(0, 255), st.integers(0, 2**42), st.lists(_F32, min_size=31, max_size=31))
@example(1, 0, 0, [0.0] * 31)  # every payload trimmed to one byte
@example(7, 255, 2**32 * 1000 + 5, [math.inf] + [0.5] * 30)  # the stamp's milliseconds wrapped; an infinite roll
def test_the_compiled_decoder_gives_the_cpython_pairs_values(compiled, sysid: int, seq: int, t_us: int, v: list[float]) -> None:  # type: ignore[no-untyped-def]
    data = state_datagram(sysid, seq, t_us, v)
    want = _cpython(data, sysid)
    assert want is not None
    got = _kernel(compiled, data, sysid)
    assert _same(got, want), (got, want)


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 255), st.integers(0, 2**40), st.lists(_F32, min_size=31, max_size=31))
def test_the_pure_function_in_cpython_gives_the_same(sysid: int, t_us: int, v: list[float]) -> None:
    """One source: the function numba compiles is correct as CPython runs it (SMCPILOT_JIT=0 flies
    the CPython pair instead, for speed)."""
    data = state_datagram(sysid, 3, t_us, v)
    with np.errstate(all="ignore"):  # (numpy scalars in CPython: NaN and overflow are what is tested)
        assert _same(_kernel(sk.decode_state, data, sysid), _cpython(data, sysid))


def _refusals() -> dict[str, tuple[bytes, int]]:
    v = [0.1 * i for i in range(31)]
    good = state_datagram(3, 7, 123_456_789, v)
    att_len = 12 + good[1]
    statustext = mavlink.MAVLink(None, srcSystem=3, srcComponent=200).statustext_encode(4, b"SIM: hello")
    return {
        "another system": (good, 4),
        "a corrupted byte": (good[:20] + bytes([good[20] ^ 1]) + good[21:], 3),
        "a corrupted CRC": (good[:-1] + bytes([good[-1] ^ 0x80]), 3),
        "cut short": (good[:-1], 3),
        "a byte more": (good + b"\x00", 3),
        "three messages": (good[att_len:], 3),
        "reordered": (good[att_len:] + good[:att_len], 3),
        "a signed packet": (good[:2] + b"\x01" + good[3:], 3),
        "another component": (good[:6] + b"\x01" + good[7:], 3),
        "a STATUSTEXT after": (good + statustext.pack(mavlink.MAVLink(None, 3, 200)), 3),
        "the stamps differ": (state_datagram(3, 7, 123_456_789, v, lpn_t_ms=123_457), 3),
        "empty": (b"", 3),
    }


@needs_jit
@pytest.mark.parametrize("case", sorted(_refusals()))
def test_anything_else_is_refused_as_the_cpython_pair_refuses_it(compiled, case: str) -> None:  # type: ignore[no-untyped-def]
    data, sysid = _refusals()[case]
    assert _cpython(data, sysid) is None
    assert _kernel(compiled, data, sysid) is None
    assert _kernel(sk.decode_state, data, sysid) is None


@needs_jit
def test_the_decoder_counts_what_it_decoded() -> None:
    dec = sk.compiled_decoder(compile_new=True)
    assert dec is not None
    good = state_datagram(5, 0, 2_000_000, [0.25] * 31)
    assert dec.decode(good, 5) == 1 and dec.decode(good, 6) == 0 and dec.decode(good[:-2], 5) == 0
    assert dec.decoded == 1
    assert dec.io.tolist()[sk.I_STAMP] == 2000


def test_without_the_jit_there_is_no_decoder(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setenv("SMCPILOT_JIT", "0")
    assert sk.compiled_decoder(compile_new=True) is None


# -- the tick's answer and record ----------------------------------------------------------------------
_OUT = st.one_of(st.floats(-1e3, 1e3), st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -0.0, math.nan, 3.5e38]))


def _answer_cpython(io: list[float], t_us: int, act_seq: int, armed: bool, log_seq: int, flags: int, mode: int,
                    target: tuple[float, float, float], yaw_t: float, has: tuple[bool, bool, bool]) -> tuple[bytes, bytes] | None:  # fmt: skip
    """What the FC's tick makes in CPython of the compiled pipeline's outputs ``io`` (from IO_OUT on):
    ``fc.flight.FlightControl._held_output``'s PipelineOutput, ``fc.telemetry.smc_data``, TickRecords."""
    from fc.control.base import Diagnostics
    from fc.flight import PipelineOutput
    from fc.telemetry import smc_data
    from smcpilot.protocol import ACTUATOR_FLAG_LOCKSTEP

    o = io
    diag = Diagnostics(tuple(o[12:16]) if has[0] else None, tuple(o[16:20]) if has[1] else None, tuple(o[20:24]) if has[2] else None,
                       tuple(o[24:28]), None)  # fmt: skip
    out = PipelineOutput(tuple(o[0:4]), tuple(o[4:8]), tuple(v != 0.0 for v in o[8:12]), diag, tuple(o[32:36]), tuple(o[36:40]))
    try:
        act = fastcodec.TickRecords(7).actuators(act_seq, t_us, out.motors, mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0,
                                                 ACTUATOR_FLAG_LOCKSTEP)  # fmt: skip
        smc = fastcodec.TickRecords(9).smc(log_seq, t_us, smc_data(out, target, yaw_t, flags, mode))
    except OverflowError:
        return None
    return act, smc


@needs_jit
@settings(max_examples=300, deadline=None)
@given(st.lists(_OUT, min_size=41, max_size=41), st.integers(0, 2**53), st.integers(0, 255), st.booleans(), st.integers(0, 255),
       st.integers(0, 2**16), st.integers(0, 20), st.tuples(_OUT, _OUT, _OUT), _OUT, st.tuples(st.booleans(), st.booleans(), st.booleans()))  # fmt: skip
@example([0.0] * 41, 0, 0, False, 0, 0, 0, (0.0, 0.0, 0.0), 0.0, (True, True, True))
def test_the_compiled_answer_and_record_are_the_cpython_bytes(io_out, t_us, act_seq, armed, log_seq, flags, mode, target, yaw_t, has) -> None:  # type: ignore[no-untyped-def]
    from fc.compiled_pipeline import IO_OUT, IO_SIZE

    enc = sk.compiled_answer_encoder(7, 9, 1, has, compile_new=True)
    assert enc is not None
    io = np.zeros(IO_SIZE)
    io[IO_OUT : IO_OUT + 41] = io_out
    got = enc.encode(io, t_us, act_seq, mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0, log_seq, flags, mode, target, yaw_t)
    assert got == _answer_cpython(io_out, t_us, act_seq, armed, log_seq, flags, mode, target, yaw_t, has)


@settings(max_examples=20, deadline=None)
@given(st.lists(_OUT, min_size=41, max_size=41), st.integers(0, 2**40), st.integers(0, 255), st.tuples(_OUT, _OUT, _OUT))
def test_the_answers_pure_function_in_cpython_gives_the_same(io_out, t_us, seq, target) -> None:  # type: ignore[no-untyped-def]
    from fc.compiled_pipeline import IO_OUT, IO_SIZE

    io = np.zeros(IO_SIZE)
    io[IO_OUT : IO_OUT + 41] = io_out
    enc = sk.AnswerEncoder(sk.encode_answer, 7, 9, 1, (True, False, True))  # (the pure function itself, run by CPython)
    with np.errstate(all="ignore"):  # (numpy scalars in CPython: NaN and overflow are what is tested)
        got = enc.encode(io, t_us, seq, 128, seq, 3, 4, target, 0.5)
    assert got == _answer_cpython(io_out, t_us, seq, True, seq, 3, 4, target, 0.5, (True, False, True))
