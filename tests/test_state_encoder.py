"""The simulator's compiled state encoder (:mod:`sim_bridge.state_encoder`) against what the
simulator makes in CPython: :meth:`sim_bridge.app.SimVehicle.make_state`'s conversions and
:class:`smcpilot.fastcodec.TickRecords` (itself tested against pymavlink byte for byte). The same
bytes for any values; None exactly where CPython must make the state itself (a NaN, whose sign
compiled arithmetic does not give as CPython does, or a value beyond float32, which ``struct``
refuses). The simulator process flying with it gives the FC the same log:
``tests/test_compiled_physics.py`` (``--jit wait`` against ``--jit off``)."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from bits_helpers import needs_jit
from hypothesis import example, given, settings
from hypothesis import strategies as st

from sim_bridge import state_encoder as se
from sim_bridge.app import SimVehicle
from sim_bridge.environment import Environment, EnvironmentParams
from sim_bridge.plants.rigid_body import RigidBodyPlant
from sim_bridge.sensors import SensorNoiseParams, specific_force_frd
from smcpilot.fastcodec import TickRecords
from smcpilot.frames import quat_nwu_flu_to_ned_frd
from smcpilot.vehicle import DEFAULT_VEHICLE
from smcpilot.wire import wire_of_paper

_VALUE = st.one_of(
    st.floats(-20.0, 20.0), st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, math.nan, math.inf, -math.inf, 3.4028235e38, 3.5e38, 1e-46]),
)  # fmt: skip


def _cpython(v: list[float], t_us: int, seq: int, sysid: int) -> bytes | None:
    """make_state's CPython path for the inputs ``v`` (:data:`sim_bridge.state_encoder.V_OBS` …);
    None where the encoder must leave the state to it (a NaN on the wire, or ``struct`` refusing a value)."""
    rec = TickRecords(sysid)
    wire = wire_of_paper(*v[0:12])
    quat = (v[15], v[16], v[17], v[18])
    force = specific_force_frd((v[12], v[13], v[14]), quat, v[31])
    truth = wire_of_paper(*v[19:31])
    qned = quat_nwu_flu_to_ned_frd(quat)
    if any(x != x for x in (*wire, *force, *truth[3:], *qned)):
        return None
    roll, pitch, yaw, p, q, r, x, y, z, vx, vy, vz = wire
    _, _, _, tp, tq, tr, tx, ty, tz, tvx, tvy, tvz = truth
    t_ms = (t_us // 1000) & 0xFFFFFFFF
    try:
        return b"".join((
            rec.attitude(seq, t_ms, roll, pitch, yaw, p, q, r),
            rec.highres_imu((seq + 1) & 0xFF, t_us, *force, p, q, r),
            rec.odometry((seq + 2) & 0xFF, t_us, tx, ty, tz, *qned, tvx, tvy, tvz, tp, tq, tr),
            rec.local_position_ned((seq + 3) & 0xFF, t_ms, x, y, z, vx, vy, vz),
        ))  # fmt: skip
    except OverflowError:  # (struct: a finite value beyond float32)
        return None


def _encode(fn, v: list[float], t_us: int, seq: int, sysid: int) -> bytes | None:  # type: ignore[no-untyped-def]
    out = np.zeros(se.OUT_BYTES, dtype=np.uint8)
    bits = np.zeros(1, dtype=np.uint32)
    tail = np.frombuffer(TickRecords(sysid).odo_tail, dtype=np.uint8).copy()
    n = fn(np.array(v, dtype=np.float64), t_us, seq, sysid, tail, out, bits, bits.view(np.float32))
    return out[:n].tobytes() if n else None


@pytest.fixture(scope="module")
def compiled():  # type: ignore[no-untyped-def]
    enc = se.compiled_encoder(1, compile_new=True)
    assert enc is not None
    return enc._entry


_HOVER = [0.1, -0.05, 1.2, 0.01, 0.02, -0.03, 1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.0, 0.0, -0.1,
          0.99, 0.05, -0.04, 0.1, 0.11, -0.09, 0.2, 0.02, 0.0, -0.01, 1.01, 2.02, 3.03, 0.1, 0.2, 0.3, 9.81]  # fmt: skip


@needs_jit
@settings(max_examples=400, deadline=None)
@given(st.lists(_VALUE, min_size=se.V_SIZE, max_size=se.V_SIZE), st.integers(0, 2**53), st.integers(0, 255), st.integers(1, 255))
@example([0.0] * se.V_SIZE, 0, 0, 1)  # every payload trimmed as far as it goes
@example(_HOVER, 2**32 * 1000 + 7, 255, 9)  # the millisecond stamp wraps; the sequence numbers too
def test_the_compiled_encoder_makes_the_cpython_bytes(compiled, v: list[float], t_us: int, seq: int, sysid: int) -> None:  # type: ignore[no-untyped-def]
    assert _encode(compiled, v, t_us, seq, sysid) == _cpython(v, t_us, seq, sysid)


@settings(max_examples=25, deadline=None)
@given(st.lists(_VALUE, min_size=se.V_SIZE, max_size=se.V_SIZE), st.integers(0, 2**40), st.integers(0, 255))
@example(_HOVER, 123_456_789, 3)
def test_the_pure_function_in_cpython_gives_the_same(v: list[float], t_us: int, seq: int) -> None:
    with np.errstate(all="ignore"):  # (numpy scalars in CPython: NaN and overflow are what is tested)
        assert _encode(se.encode_state, v, t_us, seq, 4) == _cpython(v, t_us, seq, 4)


def _vehicle(seed: int) -> SimVehicle:
    env = Environment(EnvironmentParams(sensor_noise=SensorNoiseParams(position_std_m=0.02, attitude_std_rad=0.01, body_rate_std_radps=0.02,
                                                                       velocity_std_mps=0.03, accel_std_mps2=0.1)),  # fmt: skip
                      rng=random.Random(seed))
    plant = RigidBodyPlant(DEFAULT_VEHICLE, env)
    return SimVehicle(plant, fc_url="udp:127.0.0.1:9", system_id=3, clock_us=lambda: int(round(plant.t_s * 1e6)))


@needs_jit
def test_a_vehicle_makes_the_same_states_with_the_encoder_and_without() -> None:
    """Two vehicles, the same plant and noise, one with the encoder: the same datagrams (the four
    packets, one datagram), the same sequence numbers after, through a climb with noise."""
    plain, fast = _vehicle(7), _vehicle(7)
    try:
        fast.encoder = se.compiled_encoder(3, compile_new=True)
        assert fast.fast_states_ok() and fast.encoder is not None
        for k in range(300):
            for v in (plain, fast):
                v.plant.step(v.plant.t_s, 0.002, (0.62, 0.62, 0.62, 0.62), True)
                v.make_state()
            assert b"".join(fast.last_state) == b"".join(plain.last_state), k
            assert len(fast.last_state) == 1 and len(plain.last_state) == 4
            assert fast.link.peek_seq() == plain.link.peek_seq()
        assert fast.encoder.made == 300
    finally:
        plain.link.close()
        fast.link.close()


def test_without_the_jit_there_is_no_encoder(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setenv("SMCPILOT_JIT", "0")
    assert se.compiled_encoder(1, compile_new=True) is None
