"""The IMU on the wire: the simulator's HIGHRES_IMU (sensed specific force, body FRD) and ODOMETRY
(the plant's truth) with each state; the FC takes them only with their state, logs them, flies a
law that measures acceleration (INDI) on the accelerometer and never flies on the truth.

Oracles: pymavlink's reader for the log; the simulator's own conversion run backwards
(:func:`smcpilot.wire.accel_of_specific_force`); the same scenario flown in-process and as the two
processes (motor commands bit for bit); the law's step with the acceleration withheld (the
differencing it falls back to); over real UDP, the test playing the simulator.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sitl_helpers import TAKEOFF_3M, FakeSim, FcProcess, write_plan

from fc.control.indi import INDI, indi_consts, indi_initial_state, indi_step
from fc.params import config_for
from fc.pipeline import law_context
from lab.run import fly
from sim_bridge.sensors import specific_force_frd
from smcpilot.faults import FaultSpec
from smcpilot.frames import quat_from_euler
from smcpilot.plan import PlanStep
from smcpilot.protocol import IMU_FIELDS_UPDATED
from smcpilot.scenario import Scenario
from smcpilot.tlog import read_tlog
from smcpilot.wire import accel_of_specific_force

PERIOD_MS = 2
G = 9.81


def _scenario(controller: str, faults: tuple[FaultSpec, ...] = (), duration_s: float = 4.0) -> Scenario:
    return Scenario(
        name=f"imu-{controller}", controller=controller, duration_s=duration_s, seed=3,
        plan=(PlanStep(0.0, "takeoff", alt_m=2.0),), faults=faults,
    )  # fmt: skip


def _motors(tlog: Path) -> dict[int, tuple[float, ...]]:
    return {m.time_usec: tuple(m.controls[:4]) for _, m in read_tlog(tlog) if m.get_type() == "HIL_ACTUATOR_CONTROLS"}


def _messages(tlog: Path, kind: str) -> list[mavlink.MAVLink_message]:
    return [m for _, m in read_tlog(tlog) if m.get_type() == kind]


BIAS = FaultSpec(kind="sensor", start_s=2.0, sensor="accel", mode="bias", value=(0.0, 0.0, 1.5))


# -- frames ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("euler", [(0.0, 0.0, 0.0), (0.3, -0.2, 2.5), (-1.0, 0.7, -3.0)])
def test_the_fcs_conversion_undoes_the_simulators(euler: tuple[float, float, float]) -> None:
    """Specific force FRD (the simulator, with the true attitude) and back to the kinematic
    acceleration (the FC, with the attitude it flies on): the same vector, gravity removed once."""
    accel = (0.4, -1.2, 2.5)
    f = specific_force_frd(accel, quat_from_euler(*euler), G)
    assert accel_of_specific_force(*f, *euler, G) == pytest.approx(accel, abs=1e-12)
    level = specific_force_frd((0.0, 0.0, 0.0), quat_from_euler(0.0, 0.0, 1.0), G)
    assert level == pytest.approx((0.0, 0.0, -G), abs=1e-12)  # at rest: -g on FRD z
    nan = specific_force_frd((math.nan,) * 3, quat_from_euler(*euler), G)
    assert all(v != v for v in accel_of_specific_force(*nan, *euler, G))


def test_indi_takes_the_measured_vertical_acceleration_and_differences_without_it() -> None:
    k = indi_consts(law_context(config_for(_scenario("indi")), _scenario("indi").vehicle), INDI.default_params())
    meas = (0.01, 0.02, -0.01, 0.0, 0.3, 0.0, 2.0, 0.1)
    state = indi_initial_state(meas, k)
    ref = (0.0,) * 12 + (2.5, 0.0, 0.0, 0.0)
    u_prev = (0.0, 0.0, 0.0, 4.77)
    prev = indi_step(meas, ref, state, 0.002, k, (0.0,) * 4, u_prev)[1]
    meas2 = (0.01, 0.02, -0.01, 0.0, 0.3, 0.0, 2.0002, 0.12)
    plain = indi_step(meas2, ref, prev, 0.002, k, (0.0,) * 4, u_prev)
    nan = indi_step(meas2 + (math.nan,) * 3, ref, prev, 0.002, k, (0.0,) * 4, u_prev)
    assert repr(nan) == repr(plain)  # a dropout: the differencing, bit for bit
    sensed = indi_step(meas2 + (0.0, 0.0, 3.0), ref, prev, 0.002, k, (0.0,) * 4, u_prev)
    assert sensed[0][:3] == plain[0][:3]  # the attitude channels always difference the rates
    # measured +3 m/s^2 against the differenced +10: less acceleration seen, more thrust wanted
    assert sensed[0][3] > plain[0][3]
    assert INDI.measures_accel


# -- flights ----------------------------------------------------------------------------------------
@pytest.mark.slow
def test_indi_flies_the_same_in_process_and_as_sitl_with_an_accel_fault(tmp_path: Path) -> None:
    sc = _scenario("indi", (BIAS,))
    a = fly(sc, tmp_path / "inproc")
    b = fly(sc, tmp_path / "sitl", sitl=True)
    assert a.status == b.status == "ok", (a.message, b.message)
    ma, mb = _motors(a.tlog), _motors(b.tlog)
    assert len(ma) == sc.n_ticks
    assert ma == mb  # the IMU in-process is the simulator's, bit for bit
    assert [t for _, t in a.events] == [t for _, t in b.events]


def test_an_accel_bias_reaches_the_fc_and_changes_indi_but_no_other_law(tmp_path: Path) -> None:
    """SITL: the FC logs the IMU it received (the bias after its start) and the truth; INDI flies
    differently with the bias, the PID-SMC (no accelerometer) exactly the same."""
    clean = fly(_scenario("indi"), tmp_path / "clean", sitl=True)
    biased = fly(_scenario("indi", (BIAS,)), tmp_path / "biased", sitl=True)
    assert clean.status == biased.status == "ok"
    imu = _messages(biased.tlog, "HIGHRES_IMU")
    truth = _messages(biased.tlog, "ODOMETRY")
    n = _scenario("indi").n_ticks
    assert len(imu) == len(truth) == n
    assert all(m.fields_updated == IMU_FIELDS_UPDATED for m in imu)
    at_rest = imu[0]
    assert (at_rest.xacc, at_rest.yacc, at_rest.zacc) == pytest.approx((0.0, 0.0, -G), abs=1e-5)
    # the bias (1.5 m/s^2 NED down) from 2 s on: specific force vs the truth's acceleration
    before = [m for m in imu if m.time_usec < 2_000_000]
    after = [m for m in imu if m.time_usec >= 2_000_000]
    clean_imu = {m.time_usec: m for m in _messages(clean.tlog, "HIGHRES_IMU")}
    assert all(m.zacc == clean_imu[m.time_usec].zacc for m in before)
    assert after[0].zacc - clean_imu[after[0].time_usec].zacc == pytest.approx(1.5, abs=1e-4)
    mc, mb = _motors(clean.tlog), _motors(biased.tlog)
    assert all(mc[t] == mb[t] for t in mc if t < 2_000_000)
    assert any(mc[t] != mb[t] for t in mc if t >= 2_000_000), "the accel bias reached INDI"
    # the PID-SMC does not measure acceleration: the same motor commands, bit for bit
    p_clean = fly(_scenario("adaptive_pid_smc"), tmp_path / "pclean")
    p_biased = fly(_scenario("adaptive_pid_smc", (BIAS,)), tmp_path / "pbiased")
    assert _motors(p_clean.tlog) == _motors(p_biased.tlog)


def test_the_truth_is_logged_and_never_flown_on(tmp_path: Path) -> None:
    """With position noise the state the FC flies on is noisy, the logged truth is not; the truth
    is the plant's (a clean flight's truth equals its state, to float32)."""
    res = fly(_scenario("adaptive_pid_smc"), tmp_path / "sitl", sitl=True)
    lpn = {m.time_boot_ms * 1000: m for m in _messages(res.tlog, "LOCAL_POSITION_NED")}
    odo = _messages(res.tlog, "ODOMETRY")
    assert len(odo) == len(lpn)
    for m in odo[::50]:
        s = lpn[m.time_usec]
        assert (m.x, m.y, m.z, m.vx, m.vy, m.vz) == (s.x, s.y, s.z, s.vx, s.vy, s.vz)  # no noise: the same float32
        assert m.frame_id == m.child_frame_id == mavlink.MAV_FRAME_LOCAL_NED
        assert m.estimator_type == mavlink.MAV_ESTIMATOR_TYPE_MOCAP and math.isnan(m.pose_covariance[0])


# -- bad input, over real UDP ------------------------------------------------------------------------
def _imu(sim: FakeSim, t_us: int, acc: tuple[float, float, float] = (0.0, 0.0, -G), fields: int = IMU_FIELDS_UPDATED) -> bytes:
    mav = sim.mav()
    return bytes(mav.highres_imu_encode(t_us, *acc, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, fields).pack(mav))


def test_bad_imu_is_counted_dropped_and_said_once(tmp_path: Path) -> None:
    plan = write_plan(tmp_path / "plan.toml", TAKEOFF_3M)
    fc = FcProcess(["--sim", "udpin:127.0.0.1:0", "--gcs", "none", "--lockstep", "--plan", str(plan), "--controller", "indi",
                    "--tlog", str(tmp_path / "fc.tlog"), "--watchdog-s", "30"], cwd=tmp_path)  # fmt: skip
    sim = other = None
    try:
        host, port = fc.listening()["sim"].rsplit(":", 1)
        sim = FakeSim((host, int(port)), timeout_s=5.0)
        other = FakeSim((host, int(port)), timeout_s=5.0)
        t = 0
        kinds = ["good", "stale", "stale", "no_accel", "inf", "nan", "none", "foreign", "good"]
        for kind in kinds:
            att, pos = sim.state_packets(t)
            if kind == "good":
                imu = _imu(sim, t * 1000)
            elif kind == "stale":
                imu = _imu(sim, (t - PERIOD_MS) * 1000)
            elif kind == "no_accel":
                imu = _imu(sim, t * 1000, fields=0x38)
            elif kind == "inf":
                imu = _imu(sim, t * 1000, acc=(0.0, math.inf, -G))
            elif kind == "nan":
                imu = _imu(sim, t * 1000, acc=(math.nan,) * 3)
            else:
                imu = b""
            if kind == "foreign":
                other.send_raw(_imu(other, t * 1000, acc=(0.0, 0.0, 50.0)))
            sim.send_raw(att + imu + pos)
            msgs = sim.recv_actuators()
            assert [m.time_usec for m in msgs] == [t * 1000], kind
            t += PERIOD_MS
        assert fc.stop() == 0
    finally:
        for s in (sim, other):
            if s is not None:
                s.close()
        fc.kill()
    summary = fc.summary()
    assert summary["ticks"] == len(kinds)
    assert summary["imu_msgs"] == 4  # good, inf, nan, good: taken (the inf and the NaN as "not measured")
    assert summary["imu_accel_missing"] == 2
    assert summary["states_without_imu"] == 5  # 2 stale, no accel, none, foreign
    assert summary["foreign_imu"] == 1
    assert summary["sim_bad"] == {"imu_stamp": 2, "imu_no_accel": 1, "imu_nonfinite": 1}
    said = [ln for ln in fc.all_lines if ln.startswith("fc: dropped")]
    assert len(said) == 3, said  # one message per kind: the second stale stamp is counted, not said
    assert "HIGHRES_IMU stamped" in said[0] and "without the accelerometer (fields_updated 0x38)" in said[1]
    assert "infinite accelerometer value" in said[2]
    logged = _messages(tmp_path / "fc.tlog", "HIGHRES_IMU")
    assert len(logged) == 4 and not any(m.zacc == 50.0 for m in logged)


def test_a_stale_truth_is_dropped_and_never_logged(tmp_path: Path) -> None:
    fc = FcProcess(["--sim", "udpin:127.0.0.1:0", "--gcs", "none", "--lockstep", "--tlog", str(tmp_path / "fc.tlog"),
                    "--watchdog-s", "30"], cwd=tmp_path)  # fmt: skip
    sim = None
    try:
        host, port = fc.listening()["sim"].rsplit(":", 1)
        sim = FakeSim((host, int(port)), timeout_s=5.0)
        mav = sim.mav()
        cov = [math.nan] + [0.0] * 20
        for t, stamp in ((0, 0), (2, 0), (4, 4)):
            att, pos = sim.state_packets(t)
            odo = bytes(mav.odometry_encode(stamp * 1000, 1, 1, 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                                            cov, cov, 0, 6, 100).pack(mav))  # fmt: skip
            sim.send_raw(att + odo + pos)
            assert [m.time_usec for m in sim.recv_actuators()] == [t * 1000]
        assert fc.stop() == 0
    finally:
        if sim is not None:
            sim.close()
        fc.kill()
    s = fc.summary()
    assert s["truth_msgs"] == 2 and s["sim_bad"] == {"truth_stamp": 1}
    assert [m.time_usec for m in _messages(tmp_path / "fc.tlog", "ODOMETRY")] == [0, 4000]
    assert sum(ln.startswith("fc: dropped ODOMETRY stamped") for ln in fc.all_lines) == 1


def test_the_imus_float32_in_process_is_the_wires() -> None:
    """lab.runner.imu_accel rounds as HIGHRES_IMU does (float32)."""
    from lab.runner import imu_accel
    from sim_bridge.build import plant_for

    plant = plant_for(_scenario("indi"))
    f = imu_accel(plant.observe(), plant)
    assert f is not None
    assert f == struct.unpack("<3f", struct.pack("<3f", *f))
    assert f[2] == pytest.approx(-plant.vehicle.gravity_mps2, abs=1e-5)


# -- scoring the truth -------------------------------------------------------------------------------
@pytest.mark.slow
def test_log_summary_scores_the_truth_as_compare_does(tmp_path: Path) -> None:
    """A noisy flight with a position-sensor bias, as SITL: ``log summary``'s truth metrics are the
    in-process flight's scored on the true state (what ``smcpilot compare`` does, MetricsRecorder
    rows of the truth), and show what the sensed state hides (the vehicle held 0.3 m off)."""
    from fc.core import FlightCore
    from fc.params import options_for
    from ground.logs import load_log, summarize
    from lab.fast.flight import FastRecord
    from lab.metrics import MetricsRecorder
    from lab.runner import simulate
    from sim_bridge.build import plant_for
    from smcpilot.scenario import EnvironmentSpec

    bias = FaultSpec(kind="sensor", start_s=3.0, sensor="position", mode="bias", value=(0.3, 0.0, 0.0))
    sc = Scenario(name="truth", duration_s=6.0, seed=5, plan=(PlanStep(0.0, "takeoff", alt_m=2.0),), faults=(bias,),
                  environment=EnvironmentSpec(noise=True))  # fmt: skip
    res = fly(sc, tmp_path / "sitl", sitl=True)
    assert res.status == "ok", res.message
    s = summarize(load_log(res.tlog))
    sensed, truth = s["metrics"], s["truth_metrics"]
    assert truth is not None and s["metrics_sources"]["truth_metrics"].startswith("true state: ODOMETRY")
    core = FlightCore(config_for(sc), sc.vehicle, plan=sc.plan, estimator=options_for(sc).estimator)
    rec = MetricsRecorder(core)
    simulate(core, plant_for(sc), sc.n_ticks, rate_hz=sc.rate_hz, physics_hz=sc.physics_hz, record=FastRecord(rec, 1, truth=True))
    ours = rec.metrics(fault_starts_s=[3.0])
    for key in ("iae_pos_m_s", "ise_pos_m2_s", "iae_att_rad_s", "effort_u2_s", "max_tilt_deg", "flight_time_s"):
        assert truth[key] == pytest.approx(ours[key], rel=1e-4, abs=1e-6), key
    # the FC holds the biased position on target: the vehicle is 0.3 m off, which only the truth shows
    assert truth["iae_pos_m_s"] > sensed["iae_pos_m_s"] + 0.3
