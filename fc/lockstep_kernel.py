"""A lockstep flight controller's plain state in one compiled call: decoded, checked, estimated, flown, answered.

In lockstep the FC receives one state datagram a tick and answers it. Flown the ordinary way that is
some forty Python calls (:meth:`fc.app.FlightControllerApp._poll_sim`: the compiled decoder, the
stamp and IMU checks, :meth:`fc.core.FlightCore.tick` with the estimate, the commander and the
compiled pipeline, the compiled answer encoder, the log), about 60 µs a state, most of it the
glue between them. Most ticks are *plain*: nothing discrete happens in them. :func:`plain_state`
flies such a tick in one compiled call, from the datagram's bytes to the answer's and the log
record's, and returns 0 (nothing changed) the moment it sees that the tick is not plain, so the
caller flies it the ordinary way. A tick is plain when:

- the datagram is the simulator's state datagram (:func:`fc.state_kernel.decode_state`), stamped
  exactly one period after the last tick, every value finite, with its IMU (the accelerometer's
  bits set, finite, the same stamp) and its truth (the same stamp);
- the estimate's status stays "everything measured" (:func:`fc.estimate.estimate_step`);
- no plan step is due, the commander's disarm delay does not run out and the mode's watched
  condition does not hold (:func:`fc.modes.base.watch_holds`, as :mod:`lab.fast` checks them);
- the pipeline (:func:`fc.compiled_pipeline.held_step`) does not touch down and its output is
  finite, and the answer's values fit a float32 (:func:`fc.state_kernel.encode_answer`).

The caller checks the rest before the call (:meth:`fc.app.FlightControllerApp._fly_plain`:
armed, no failsafe, a compiled pipeline, a mode with a watch, no ground-station loss about to act) and, after it, brings every object the
ordinary path would have changed up to date. Only then is the pipeline's new state kept: a tick
that turns out not plain has changed nothing. The log and the answer are the same bytes
as the ordinary path's (``tests/test_lockstep_kernel.py`` flies both and compares the logs).

The function is compiled with the pipeline's twins for the flight's law
(:func:`fc.compiled_pipeline.plain_entry`), so it calls the same compiled step.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from fc.commander import ground_armed_count
from fc.compiled_pipeline import IO_CMD as _IO_CMD
from fc.compiled_pipeline import IO_DT as _IO_DT
from fc.compiled_pipeline import IO_OUT as _IO_OUT
from fc.compiled_pipeline import IO_SENSED as _IO_SENSED
from fc.compiled_pipeline import held_step, held_write
from fc.estimate import EST_OK, estimate_step
from fc.modes.base import watch_holds
from fc.pipeline import VehicleState
from fc.state_kernel import F_ACCEL, F_STATE, I_ENDS, I_IMU_FIELDS, I_IMU_USEC, I_MISSING, I_ODO_USEC, I_SIZE, I_STAMP, decode_state, encode_answer
from smcpilot.protocol import IMU_ACCEL_BITS
from smcpilot.wire import accel_of_specific_force

#: the float inputs (``kf``, float64): the last tick's stamp (ms), the control period (µs and s),
#: the first tick's time (µs), the next plan step's time (s after the first tick; inf: none), the
#: disarm delay (s), the time armed on the ground so far (s; the tick's new value on return), the
#: mode's watch (kind, a, b, c, r: :class:`fc.modes.base.Watch`) and the yaw set-point for the
#: record (rad).
K_LAST_MS = 0
K_PERIOD_US = 1
K_DT = 2
K_T0_US = 3
K_PLAN_S = 4
K_DISARM_S = 5
K_GROUND_S = 6
K_WATCH = 7
K_YAW_T = 12
K_SIZE = 13
#: the integer inputs and outputs (``ki``, int64): the answer's and the record's sequence numbers,
#: the answer's mode byte, the record's flags and mode, the log's clock before the tick (µs); out:
#: the lengths (``len(answer) | len(record) << 16``), the tick's stamp (ms) and the length of the
#: tick's log records (bytes, in ``rec``).
KI_ACT_SEQ = 0
KI_LOG_SEQ = 1
KI_ACT_MODE = 2
KI_FLAGS = 3
KI_MODE = 4
KI_CLOCK_US = 5
KI_LENGTHS = 6
KI_T_MS = 7
KI_REC_BYTES = 8
KI_SIZE = 9
#: the tick's log records at most (``rec``, uint8): six .tlog records (an 8-byte stamp and a packet
#: of at most 12 + 255 bytes each).
REC_BYTES = 6 * (8 + 12 + 255)
_isfinite = math.isfinite
_ACCEL = int(IMU_ACCEL_BITS)


def _i64(x):  # type: ignore[no-untyped-def]
    """``x`` (an unsigned or float array element) as a signed 64-bit integer."""
    return np.int64(x)


def _put_stamp(rec, j, t_us):  # type: ignore[no-untyped-def]
    """A .tlog record's stamp (µs, big-endian uint64, :mod:`smcpilot.tlog`) at ``rec[j]``; the end."""
    for k in range(8):
        rec[j + k] = (t_us >> (8 * (7 - k))) & 0xFF
    return j + 8


def _put_record(rec, j, t_us, src, a, b):  # type: ignore[no-untyped-def]
    """The .tlog record of the packet ``src[a:b]`` stamped ``t_us`` at ``rec[j]``; the end."""
    j = _put_stamp(rec, j, t_us)
    for k in range(a, b):
        rec[j] = src[k]
        j += 1
    return j


def plain_state(data, system, ps_box, pp_box, io, law_box, es, ep, kf, ki, fo, dio, bits, f32, consts, name, out, rec):  # type: ignore[no-untyped-def]
    """Fly the state datagram ``data`` from ``system``'s simulator if its tick is plain.

    Returns ``(1, new estimator state)`` when flown: the pipeline's state in ``ps_box`` is the
    tick's, its outputs are in ``io`` (:data:`fc.compiled_pipeline.IO_OUT` on), the answer and the
    record in ``out`` (lengths and stamp in ``ki``), the tick's .tlog records in ``rec`` (the
    state's ATTITUDE, LOCAL_POSITION_NED, HIGHRES_IMU and ODOMETRY stamped with the log's clock
    before the tick, the answer and the record stamped with the tick's time: what
    :meth:`fc.app.FlightControllerApp._take_state` and ``_tick`` log), the decoded state in
    ``fo``/``dio`` (:mod:`fc.state_kernel`) and the new ground time in ``kf``. Returns ``(0, es)`` when the tick
    is not plain: nothing the caller keeps has changed. ``io[12:20]`` must hold the commander's
    :class:`fc.pipeline.PipelineInputs` (armed)."""
    if decode_state(data, system, fo, dio, bits, f32) == 0 or dio[I_MISSING] != 0:
        return 0, es
    t_ms = _i64(dio[I_STAMP])
    last = _i64(kf[K_LAST_MS])
    if t_ms == last or abs((t_ms - last) * 1000 - _i64(kf[K_PERIOD_US])) >= 1000:
        return 0, es
    if _i64(dio[I_IMU_USEC]) // 1000 != t_ms or _i64(dio[I_ODO_USEC]) // 1000 != t_ms:
        return 0, es
    if (_i64(dio[I_IMU_FIELDS]) & _ACCEL) != _ACCEL or not _isfinite(fo[F_ACCEL] + fo[F_ACCEL + 1] + fo[F_ACCEL + 2]):
        return 0, es
    s = F_STATE
    st = VehicleState(fo[s], fo[s + 1], fo[s + 2], fo[s + 3], fo[s + 4], fo[s + 5], fo[s + 6], fo[s + 7], fo[s + 8], fo[s + 9],
                      fo[s + 10], fo[s + 11])  # fmt: skip
    dt = kf[K_DT]
    es_new, est, status, missing = estimate_step(es, st, dt, ep)
    if status != EST_OK or missing != 0:
        return 0, es
    t_us = t_ms * 1000
    t_s = (t_us - _i64(kf[K_T0_US])) * 1e-6
    if kf[K_PLAN_S] <= t_s + 1e-9:
        return 0, es
    # the commander's disarm delay (fc.commander.Commander.on_tick)
    delay = kf[K_DISARM_S]
    ground_s = ground_armed_count(kf[K_GROUND_S], delay, est[2], io[_IO_CMD + 2], io[_IO_CMD + 5] != 0.0, dt)
    if ground_s >= delay > 0.0:
        return 0, es
    w = K_WATCH
    if watch_holds(int(kf[w]), kf[w + 1], kf[w + 2], kf[w + 3], kf[w + 4], est[0], est[1], est[2], t_s):
        return 0, es
    for j in range(12):
        io[j] = est[j]
    io[_IO_DT] = dt
    # the IMU's acceleration for a law that measures it (fc.flight.FlightControl.step; the others never read it)
    a = accel_of_specific_force(fo[F_ACCEL], fo[F_ACCEL + 1], fo[F_ACCEL + 2], est[6], est[7], est[8], pp_box[0].gravity_mps2)
    io[_IO_SENSED] = a[0]
    io[_IO_SENSED + 1] = a[1]
    io[_IO_SENSED + 2] = a[2]
    new, o = held_step(ps_box, pp_box, io, law_box[0])
    if o[9] or held_write(io, o) == 0:  # touchdown, or not finite
        return 0, es
    n = encode_answer(io, _IO_OUT, t_us, ki[KI_ACT_SEQ], ki[KI_ACT_MODE], ki[KI_LOG_SEQ], ki[KI_FLAGS], ki[KI_MODE],
                      io[_IO_CMD], io[_IO_CMD + 1], io[_IO_CMD + 2], kf[K_YAW_T], consts, name, out, bits, f32)  # fmt: skip
    if n == 0:
        return 0, es
    e0 = _i64(dio[I_ENDS])
    e1 = _i64(dio[I_ENDS + 1])
    e2 = _i64(dio[I_ENDS + 2])
    e3 = _i64(dio[I_ENDS + 3])
    before = ki[KI_CLOCK_US]
    j = _put_record(rec, 0, before, data, 0, e0)
    j = _put_record(rec, j, before, data, e2, e3)
    j = _put_record(rec, j, before, data, e0, e1)
    j = _put_record(rec, j, before, data, e1, e2)
    n1 = n & 0xFFFF
    j = _put_record(rec, j, t_us, out, 0, n1)
    j = _put_record(rec, j, t_us, out, n1, n1 + (n >> 16))
    ps_box[0] = new
    kf[K_GROUND_S] = ground_s
    ki[KI_LENGTHS] = n
    ki[KI_T_MS] = t_ms
    ki[KI_REC_BYTES] = j
    return 1, es_new


#: compiled with the pipeline's twins (:data:`fc.compiled_pipeline.HELD_FUNCTIONS`).
PLAIN_FUNCTIONS = (plain_state, _i64, _put_stamp, _put_record)


class PlainLockstep:
    """:func:`plain_state`'s compiled entry point and the arrays it reads and fills, for one FC."""

    def __init__(self, entry: Any) -> None:
        self._entry = entry
        self.kf = np.zeros(K_SIZE)
        self.ki = np.zeros(KI_SIZE, dtype=np.int64)
        self.dio = np.zeros(I_SIZE, dtype=np.uint64)
        self.rec = np.zeros(REC_BYTES, dtype=np.uint8)
        #: ticks flown here.
        self.flown = 0
        #: the record's flags and mode the inputs were made with (the tick changes neither).
        self.flags = 0
        self.mode = 0

    def call(self, data: bytes, system: int, held: Any, es: Any, ep: Any, fo: Any, enc: Any) -> tuple[int, Any]:
        """:func:`plain_state` on this FC's held pipeline (:class:`fc.compiled_pipeline.HeldPipeline`),
        its estimate's state and parameters, the decoder's ``fo`` and the answer encoder's arrays."""
        return self._entry(data, system, held._ps, held._pp, held.io, held._law, es, ep, self.kf, self.ki, fo, self.dio, enc._bits,
                           enc._f32, enc.consts, enc.name, enc.out, self.rec)  # type: ignore[no-any-return]  # fmt: skip
