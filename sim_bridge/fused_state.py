"""A vehicle's physics span and its state datagram in one compiled call (the lockstep swarm's per-vehicle work).

In a lockstep swarm the simulator, as soon as a vehicle's FC answers, flies that vehicle one control
period (:meth:`sim_bridge.plants.compiled_physics.CompiledPhysics.fly`, one plant a call) and sends
it its next state (:meth:`sim_bridge.app.SimVehicle.make_state`: the observation and the truth made
in CPython, copied into the encoder's inputs, then :func:`sim_bridge.state_encoder.encode_state`).
:func:`fly_and_encode` does both from the compiled physics' row array: the span
(:func:`~sim_bridge.plants.compiled_physics.physics_span`), the truth's Euler angles
(:func:`smcpilot.frames.euler_from_quat`, roll and yaw through :func:`smcpilot.frames.wrap_pi`, as
:meth:`RigidBodyPlant.truth` makes them), the encoder's inputs (the observation being the truth)
and the datagram's bytes. :meth:`CompiledPhysics.fly_state` calls it when the observation is the
truth (:func:`~sim_bridge.plants.compiled_physics.plain_observation`: no sensor noise, no sensor
fault acting) and the span is steady, and leaves the plant as the old path does (state, time,
heading, truth memo, observation cache, the faults' observation bookkeeping); the same bytes,
bit for bit (``tests/test_fused_state.py``).

The compiled code is cached on disk with the physics' (``python -m sim_bridge.plants.compiled_physics``).
"""

from __future__ import annotations

from typing import Any

from sim_bridge.plants import rigid_body as rb
from sim_bridge.plants.compiled_physics import IO_ACCEL, IO_ACTIVE, IO_ARMED, IO_CMD, IO_EULER, SPAN_FUNCTIONS, physics_span
from sim_bridge.state_encoder import ENCODER_FUNCTIONS, V_ACCEL, V_GRAVITY, V_QUAT, V_TRUTH, encode_state
from smcpilot.frames import euler_from_quat, wrap_pi


def fly_and_encode(io, pp, t_us0, dt_us, dt_s, n_steps, out, row, c1, c2, c3, c4, armed, vin, gravity, t_us, seq, sysid, odo_tail, buf, bits,  # type: ignore[no-untyped-def]
                   f32):  # fmt: skip
    """:func:`physics_span` (``io`` … ``out``: the one active row ``row``, its motor commands ``c1`` …
    ``c4`` in [0, 1] and ``armed``, 0/1, put in the row here), then that vehicle's state
    datagram as :func:`encode_state` makes it (``vin`` … ``f32``; stamped ``t_us`` µs, packets from
    ``seq``) with the observation equal to the truth: the state's position (m, NWU), velocity (m/s,
    NWU), attitude (quaternion FLU in NWU; Euler angles ZYX, rad, roll and yaw in [-pi, pi), also
    written to ``io[row, IO_EULER:]``), body rates (rad/s, FLU), the last step's acceleration
    (m/s^2, NWU) and ``gravity`` (m/s^2). ``out[2]``: the steps completed (as the span returns).
    Returns the datagram's length in ``buf``; 0 when the span did not complete (divergence) or a
    value is NaN or beyond float32 (CPython makes it)."""
    io[row, IO_CMD] = c1
    io[row, IO_CMD + 1] = c2
    io[row, IO_CMD + 2] = c3
    io[row, IO_CMD + 3] = c4
    io[row, IO_ARMED] = armed
    io[row, IO_ACTIVE] = 1.0
    done = physics_span(io, pp, t_us0, dt_us, dt_s, n_steps, out)
    out[2] = done
    if done < n_steps:
        return 0
    qw = io[row, 6]
    qx = io[row, 7]
    qy = io[row, 8]
    qz = io[row, 9]
    phi, theta, psi = euler_from_quat((qw, qx, qy, qz))
    phi = wrap_pi(phi)
    psi = wrap_pi(psi)
    io[row, IO_EULER] = phi
    io[row, IO_EULER + 1] = theta
    io[row, IO_EULER + 2] = psi
    for j in range(2):  # the observation (V_OBS), then the truth (V_TRUTH): the same values
        b = V_TRUTH * j
        vin[b] = phi
        vin[b + 1] = theta
        vin[b + 2] = psi
        vin[b + 3] = io[row, 10]
        vin[b + 4] = io[row, 11]
        vin[b + 5] = io[row, 12]
        for m in range(6):
            vin[b + 6 + m] = io[row, m]
    vin[V_ACCEL] = io[row, IO_ACCEL]
    vin[V_ACCEL + 1] = io[row, IO_ACCEL + 1]
    vin[V_ACCEL + 2] = io[row, IO_ACCEL + 2]
    vin[V_QUAT] = qw
    vin[V_QUAT + 1] = qx
    vin[V_QUAT + 2] = qy
    vin[V_QUAT + 3] = qz
    vin[V_GRAVITY] = gravity
    return encode_state(vin, t_us, seq, sysid, odo_tail, buf, bits, f32)


#: this module's functions, compiled with everything they call (:data:`FUSED_ALL`).
FUSED_FUNCTIONS = (fly_and_encode,)
#: the closed set compiled together: the span's, the plant's, the encoder's and the truth's Euler angles.
FUSED_ALL = (*FUSED_FUNCTIONS, *SPAN_FUNCTIONS, *rb.PURE_FUNCTIONS, *ENCODER_FUNCTIONS, euler_from_quat, wrap_pi)

_TWINS: dict[Any, Any] = {}


def _twins() -> dict[Any, Any]:
    """The compiled twins (made once a process)."""
    if not _TWINS:
        from smcpilot.jit import compile_pure

        _TWINS.update(compile_pure(FUSED_ALL))
    return _TWINS


def _sig() -> tuple:
    from smcpilot.jit import numba_module

    t = numba_module().types
    arr2 = t.float64[:, ::1]
    f = t.float64
    return (arr2, arr2, t.int64, t.int64, f, t.int64, t.float64[::1], t.int64, f, f, f, f, f, t.float64[::1], f, t.int64, t.int64, t.int64,
            t.uint8[::1], t.uint8[::1], t.uint32[::1], t.float32[::1])  # fmt: skip


def compiled_fused(*, compile_new: bool) -> Any:
    """:func:`fly_and_encode`'s compiled entry point (for :attr:`CompiledPhysics.fused`), loaded from
    numba's on-disk cache or compiled first when ``compile_new`` (several seconds, once); None when
    it cannot be had (no numba, JIT off, not cached and not ``compile_new``, or it fails to compile)."""
    from smcpilot.jit import cached_entry, jit_unavailable_reason, say_once

    if jit_unavailable_reason() is not None:
        return None
    try:
        return cached_entry(_twins()[fly_and_encode], _sig(), compile_new=compile_new)
    except Exception as exc:  # numba's typing or lowering errors: the two calls as before, say why
        say_once(f"the fused physics and state could not be compiled ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})")
        return None
