"""The in-process flight's ``.tlog`` (``smcpilot run`` without ``--sitl``) carries what the SITL
FC's does: with every state, the sensed IMU (``HIGHRES_IMU``) and the plant's truth (``ODOMETRY``),
so ``smcpilot log summary`` scores the truth of an in-process flight too.

Oracles: the SITL flight of the same scenario (the simulator process sends the IMU and the truth,
the FC logs them: the same messages, field for field); ``smcpilot compare``'s scoring of the true
state in-process (:class:`lab.metrics.MetricsRecorder` rows of the truth); the project's MAVLink
encoders (:mod:`smcpilot.fastcodec`, themselves checked against pymavlink) for the recorder's own
framing; the CPython flight for the compiled one (the same file, byte for byte).
"""

from __future__ import annotations

import math
import random
from pathlib import Path

import pytest

from fc.core import FlightCore
from fc.params import config_for, options_for
from ground.logs import load_log, summarize
from lab.fast.flight import FastRecord
from lab.metrics import MetricsRecorder
from lab.run import fly, fly_in_process
from lab.runner import simulate
from sim_bridge.build import plant_for
from smcpilot import fastcodec
from smcpilot.fastcodec import TickRecords
from smcpilot.faults import FaultSpec
from smcpilot.plan import PlanStep
from smcpilot.protocol import COV_UNKNOWN, IMU_FIELDS_UPDATED, SMC_ARRAY_ID, SMC_ARRAY_NAME, TRUTH_ESTIMATOR_TYPE, TRUTH_FRAME, TRUTH_QUALITY
from smcpilot.scenario import EnvironmentSpec, Scenario
from smcpilot.tlog import read_tlog

ROOT = Path(__file__).resolve().parents[1]


def _scenario(duration_s: float = 6.0, faults: tuple[FaultSpec, ...] = ()) -> Scenario:
    return Scenario(name="inproc-log", duration_s=duration_s, seed=5, plan=(PlanStep(0.0, "takeoff", alt_m=2.0),), faults=faults,
                    environment=EnvironmentSpec(noise=True, gust_std_n=0.1))  # fmt: skip


def _fields(m) -> tuple:  # type: ignore[no-untyped-def]
    """A message's fields, NaN comparable (as text)."""
    return tuple(repr(getattr(m, f)) for f in m.fieldnames)


def _by_time(tlog: Path, kind: str) -> dict[int, tuple]:
    out = {}
    for _, m in read_tlog(tlog):
        if m.get_type() == kind:
            assert m.time_usec not in out, f"two {kind} at {m.time_usec} us"
            out[m.time_usec] = _fields(m)
    return out


# -- what the log holds --------------------------------------------------------------------------------
def test_every_in_process_state_comes_with_the_imu_and_the_truth_in_the_sitl_order(tmp_path: Path) -> None:
    sc = _scenario(6.0)
    res = fly_in_process(sc, tmp_path / "f.tlog")
    assert res.status == "ok"
    kinds = [(m.get_type(), m.get_srcComponent()) for _, m in read_tlog(res.tlog)]
    tick = [("ATTITUDE", 200), ("LOCAL_POSITION_NED", 200), ("HIGHRES_IMU", 200), ("ODOMETRY", 200),
            ("HIL_ACTUATOR_CONTROLS", 1), ("DEBUG_FLOAT_ARRAY", 1)]  # fmt: skip
    first = kinds.index(("ATTITUDE", 200))
    ticks = [kinds[i : i + 6] for i in range(first, first + 6 * sc.n_ticks, 6)]
    assert all(t == tick for t in ticks[:50])  # (events come between ticks later)
    odo = [m for _, m in read_tlog(res.tlog) if m.get_type() == "ODOMETRY"]
    imu = [m for _, m in read_tlog(res.tlog) if m.get_type() == "HIGHRES_IMU"]
    assert len(odo) == len(imu) == sc.n_ticks == res.ticks
    assert all(m.fields_updated == IMU_FIELDS_UPDATED for m in imu)
    assert (imu[0].xacc, imu[0].yacc, imu[0].zacc) == pytest.approx((0.0, 0.0, -sc.vehicle.gravity_mps2), abs=1e-5)  # at rest
    m = odo[-1]
    assert (m.frame_id, m.child_frame_id, m.estimator_type, m.quality) == (TRUTH_FRAME, TRUTH_FRAME, TRUTH_ESTIMATOR_TYPE, TRUTH_QUALITY)
    assert math.isnan(m.pose_covariance[0]) and math.isnan(m.velocity_covariance[0])
    assert -m.z == pytest.approx(2.0, abs=0.1)  # hovering at 2 m (NED down)
    # the truth is the plant's, not the noisy state the FC flew on
    lpn = {mm.time_boot_ms: mm for _, mm in read_tlog(res.tlog) if mm.get_type() == "LOCAL_POSITION_NED"}
    assert any(abs(lpn[o.time_usec // 1000].x - o.x) > 1e-4 for o in odo[1000:1100])


def test_log_summary_scores_the_truth_of_an_in_process_flight_as_compare_does(tmp_path: Path) -> None:
    """A position bias from 3 s: the FC holds the biased position, the truth shows the vehicle
    0.3 m off; the log's truth metrics are those of the in-process scoring of the true state."""
    bias = FaultSpec(kind="sensor", start_s=3.0, sensor="position", mode="bias", value=(0.3, 0.0, 0.0))
    sc = _scenario(6.0, (bias,))
    res = fly(sc, tmp_path / "run")
    assert res.status == "ok", res.message
    s = summarize(load_log(res.tlog))
    sensed, truth = s["metrics"], s["truth_metrics"]
    assert truth is not None and s["metrics_sources"]["truth_metrics"].startswith("true state: ODOMETRY")
    core = FlightCore(config_for(sc), sc.vehicle, plan=sc.plan, estimator=options_for(sc).estimator)
    rec = MetricsRecorder(core)
    simulate(core, plant_for(sc), sc.n_ticks, rate_hz=sc.rate_hz, physics_hz=sc.physics_hz, record=FastRecord(rec, 1, truth=True))
    ours = rec.metrics(fault_starts_s=[3.0])
    for key in ("iae_pos_m_s", "ise_pos_m2_s", "itae_pos_m_s2", "iae_att_rad_s", "effort_u2_s", "motor_tv", "max_tilt_deg", "flight_time_s"):
        assert truth[key] == pytest.approx(ours[key], rel=1e-4, abs=1e-6), key
    assert truth["fault_start_s"] == pytest.approx(3.0, abs=0.002)
    assert truth["iae_pos_m_s"] > sensed["iae_pos_m_s"] + 0.3


def test_the_recorders_framing_is_the_projects_mavlink_encoding() -> None:
    """Random values, zeros (trimmed), NaN, all-zero payloads: the same packets as smcpilot.fastcodec."""
    enc = TickRecords(3)
    r = random.Random(7)
    for k in range(2000):
        v = [r.choice((0.0, -0.0, math.nan, 1e-40, r.uniform(-50, 50))) if k % 3 == 0 else r.uniform(-50, 50) for _ in range(13)]
        if k % 5 == 0:
            v = [0.0] * 13
        t_us = r.choice((0, r.randrange(2**40)))
        t_ms = r.choice((0, r.randrange(2**32)))
        seq = r.randrange(256)
        mode = r.choice((0, 128))
        data = [r.choice((0.0, math.nan, r.uniform(-1, 1))) for _ in range(31)] + [0.0] * 27
        if k % 4 == 0:
            data = [0.0] * 58
        assert enc.attitude(seq, t_ms, *v[:6]) == fastcodec.encode_attitude(seq, 3, 200, t_ms, *v[:6]), k
        assert enc.local_position_ned(seq, t_ms, *v[:6]) == fastcodec.encode_local_position_ned(seq, 3, 200, t_ms, *v[:6]), k
        assert enc.highres_imu(seq, t_us, *v[:6]) == fastcodec.encode_highres_imu(seq, 3, 200, t_us, *v[:6], IMU_FIELDS_UPDATED), k
        assert enc.odometry(seq, t_us, *v) == fastcodec.encode_odometry(
            seq, 3, 200, t_us, TRUTH_FRAME, TRUTH_FRAME, *v[:3], v[3:7], *v[7:], COV_UNKNOWN, COV_UNKNOWN, 0,
            TRUTH_ESTIMATOR_TYPE, TRUTH_QUALITY), k  # fmt: skip
        assert enc.actuators(seq, t_us, v[:4], mode) == fastcodec.encode_hil_actuator_controls(seq, 3, 1, t_us, v[:4] + [0.0] * 12, mode, 1), k
        assert enc.smc(seq, t_us, data) == fastcodec.encode_debug_float_array(seq, 3, 1, t_us, SMC_ARRAY_NAME, SMC_ARRAY_ID, data), k


# -- the same as SITL ----------------------------------------------------------------------------------
@pytest.mark.slow
def test_in_process_and_sitl_logs_carry_the_same_imu_and_truth(tmp_path: Path) -> None:
    """Noise, gusts and an accelerometer bias: every tick's HIGHRES_IMU and ODOMETRY, field for
    field, in the in-process log and in the SITL FC's log of the same flight."""
    bias = FaultSpec(kind="sensor", start_s=2.0, sensor="accel", mode="bias", value=(0.0, 0.0, 1.5))
    sc = _scenario(4.0, (bias,))
    a = fly(sc, tmp_path / "inproc")
    b = fly(sc, tmp_path / "sitl", sitl=True)
    assert a.status == b.status == "ok", (a.message, b.message)
    for kind in ("HIGHRES_IMU", "ODOMETRY"):
        ia, ib = _by_time(a.tlog, kind), _by_time(b.tlog, kind)
        assert len(ia) == sc.n_ticks and ia == ib, kind
    sa, sb = summarize(load_log(a.tlog)), summarize(load_log(b.tlog))
    assert sa["truth_metrics"] == sb["truth_metrics"]
