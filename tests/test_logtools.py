"""ground.logtools: reading FC .tlog files into arrays, summarising and plotting them.

Every log here is synthesised with TlogWriter and pymavlink encoders the way fc.app writes them
(simulator state from component 200 stamped one tick early in lockstep, actuators and the per-tick
DEBUG_FLOAT_ARRAY "SMC" from component 1), so the expected numbers are known exactly.
"""

from __future__ import annotations

import argparse
import json
import math
import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground import logtools
from ground.logtools import LogError, load_log, plot_log, print_summary, summarize
from smcpilot.errors import SmcpilotError
from smcpilot.fastcodec import encode_debug_float_array
from smcpilot.frames import euler_frd_to_flu, ned_to_nwu
from smcpilot.protocol import FLAG_ARMED, FLAG_LANDING, FLAG_POSITION_HOLD, SMC_ARRAY_ID, SMC_FIELDS
from smcpilot.tlog import TlogWriter

NAN = float("nan")
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
IDX = {name: i for i, name in enumerate(SMC_FIELDS)}


class LogBuilder:
    """Writes a lockstep-style FC log: one tick = state (sim), actuators, SMC array."""

    def __init__(self, path: Path, t0_us: int = 0) -> None:
        self.writer = TlogWriter(path)
        self.sim = mavlink.MAVLink(None, srcSystem=1, srcComponent=200)
        self.fc = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.t0_us = t0_us
        self.prev_us = t0_us

    def _write(self, t_us: int, mav: mavlink.MAVLink, msg: mavlink.MAVLink_message) -> None:
        self.writer.write(t_us, msg.pack(mav))
        mav.seq = (mav.seq + 1) & 0xFF

    def state(
        self,
        t_us: int,
        ned_m: Sequence[float],
        rpy_rad: Sequence[float] = (0.0, 0.0, 0.0),
        vel_ned_mps: Sequence[float] = (0.0, 0.0, 0.0),
        rates_radps: Sequence[float] = (0.0, 0.0, 0.0),
        mav: mavlink.MAVLink | None = None,
        stamp_us: int | None = None,
    ) -> None:
        """Simulator state of simulated time t_us, stamped (like fc.app in lockstep) one tick early."""
        mav = mav or self.sim
        stamp = self.prev_us if stamp_us is None else stamp_us
        boot_ms = t_us // 1000
        self._write(stamp, mav, mav.attitude_encode(boot_ms, *rpy_rad, *rates_radps))
        self._write(stamp, mav, mav.local_position_ned_encode(boot_ms, *ned_m, *vel_ned_mps))

    def actuators(self, t_us: int, motors: Sequence[float], armed: bool, lockstep: bool = True) -> None:
        mode = mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
        self._write(t_us, self.fc, self.fc.hil_actuator_controls_encode(t_us, list(motors) + [0.0] * 12, mode, int(lockstep)))

    def smc(self, t_us: int, **fields: float) -> None:
        """A DEBUG_FLOAT_ARRAY "SMC" with the named SMC_FIELDS entries (others NaN / 0 like fc.telemetry)."""
        data = [NAN] * 29 + [0.0] * 29
        data[IDX["limited_mask"]] = 0.0
        for name, value in fields.items():
            data[IDX[name]] = value
        self.writer.write(t_us, encode_debug_float_array(self.fc.seq, 1, 1, t_us, b"SMC", SMC_ARRAY_ID, data))
        self.fc.seq = (self.fc.seq + 1) & 0xFF

    def event(self, t_us: int, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        self._write(t_us, self.fc, self.fc.statustext_encode(severity, text.encode()))

    def named_float(self, t_us: int, name: str, value: float) -> None:
        self._write(t_us, self.fc, self.fc.named_value_float_encode(t_us // 1000, name.encode(), value))

    def named_int(self, t_us: int, name: str, value: int) -> None:
        self._write(t_us, self.fc, self.fc.named_value_int_encode(t_us // 1000, name.encode(), value))

    def end_tick(self, t_us: int) -> None:
        self.prev_us = t_us

    def close(self) -> None:
        self.writer.close()


def paper_target(north_m: float, east_m: float, alt_m: float, yaw_ned_deg: float) -> dict[str, float]:
    """SMC target fields (paper frame) for a NED set-point, via smcpilot.frames."""
    x, y, z = ned_to_nwu((north_m, east_m, -alt_m))
    return {"target_x": x, "target_y": y, "target_z": z, "target_yaw": euler_frd_to_flu(0, 0, math.radians(yaw_ned_deg))[2]}


# -- a synthetic flight with known errors ------------------------------------------------------------
DT_US = 20_000  # 50 Hz keeps the files small
N_TICKS = 1350  # 0 .. 26.98 s
LANDING_K = 1250  # "Landing" at 25.0 s
DISARM_K = 1300  # disarmed from 26.0 s


def write_flight(path: Path, *, cascade: bool = False, flags: bool = False) -> None:
    """Hold (0, 0, 3 m) 0.1 m too high; at 10 s go to N 4, E -3, yaw 170 and from 18 s sit 0.2 m
    west of it with yaw -175 (15 deg past the set-point across ±180); land at 25 s, disarm at 26 s."""
    b = LogBuilder(path)
    b.event(0, "Armed")
    b.event(0, "Takeoff to 3.0 m")
    for k in range(N_TICKS):
        t_us = k * DT_US
        armed = k < DISARM_K
        if k < 500:
            ned, yaw_deg, target = (0.0, 0.0, -3.1), 0.0, paper_target(0.0, 0.0, 3.0, 0.0)
        else:
            target = paper_target(4.0, -3.0, 3.0, 170.0)
            if k < 900:
                ned, yaw_deg = (2.0, -1.5, -3.0), 90.0  # on the way: large error, never settled
            elif k < LANDING_K:
                ned, yaw_deg = (4.0, -3.2, -3.0), -175.0
            else:
                ned, yaw_deg = (4.0, -3.2, -1.0), -175.0  # descending: excluded
        roll, pitch = (math.radians(20.0), math.radians(15.0)) if k == 600 else (0.0, 0.0)
        b.state(t_us, ned, (roll, pitch, math.radians(yaw_deg)))
        b.actuators(t_us, [0.5, 0.5, 0.5, 0.5] if armed else [0.0] * 4, armed)
        fields = dict(target)
        fields.update(ref_phi=0.0, ref_theta=0.0, ref_psi=0.0, ref_z=3.0)
        if 500 <= k < 520:
            fields["limited_mask"] = 8.0  # the mixer limits thrust right after the set-point jump
        if not cascade and armed:
            sig = (0.01, -0.02, 0.03, -0.04) if 900 <= k < LANDING_K else (1.0, 1.0, 1.0, 1.0)
            if k >= LANDING_K:
                sig = (5.0, 5.0, 5.0, 5.0)
            fields.update({f"sigma_{c}": v for c, v in zip(logtools.CHANNELS, sig)})
            fields.update({f"chi_{c}": 0.5 + k * 1e-4 * (j + 1) for j, c in enumerate(logtools.CHANNELS)})
        if flags:  # the FC's per-tick state bits instead of the "Landing" event
            fields["flags"] = float(
                FLAG_POSITION_HOLD | (FLAG_ARMED if armed else 0) | (FLAG_LANDING if armed and k >= LANDING_K else 0)
            )
        b.smc(t_us, **fields)
        if k == LANDING_K and not flags:
            b.event(t_us, "Landing")
        if k == DISARM_K:
            b.event(t_us, "Landed: disarmed")
        if k % 50 == 0:
            b.named_int(t_us, "OVERRUN", k // 500)
        b.end_tick(t_us)
    b.close()


@pytest.fixture
def flight_log(tmp_path: Path) -> Path:
    path = tmp_path / "flight.tlog"
    write_flight(path)
    return path


# -- conversions -------------------------------------------------------------------------------------
def test_known_ned_state_and_paper_frame_targets_convert(tmp_path: Path) -> None:
    path = tmp_path / "conv.tlog"
    b = LogBuilder(path, t0_us=5_000_000)
    for k in range(3):
        t_us = 5_000_000 + k * 2000
        b.state(t_us, (1.0, 2.0, -3.0), (0.1, -0.2, 3.0), (0.5, -0.25, -1.0), (0.01, 0.02, -0.03))
        b.actuators(t_us, [0.1, 0.2, 0.3, 0.4], armed=True)
        # Paper frame (NWU/FLU): target 4 m north, 3 m WEST, 5 m up, psi = 170 deg (left turn).
        b.smc(
            t_us,
            target_x=4.0, target_y=3.0, target_z=5.0, target_yaw=math.radians(170.0),
            ref_phi=0.1, ref_theta=0.2, ref_psi=0.3, ref_z=2.0,
            chi_phi=0.5, sigma_z=-0.25, limited_mask=9.0,
        )  # fmt: skip
        b.end_tick(t_us)
    b.close()

    log = load_log(path)
    # Times from the first record; lockstep state on its own simulated time (time_boot_ms).
    assert log.lockstep is True
    np.testing.assert_allclose(log.att_t_s, [0.0, 0.002, 0.004])
    np.testing.assert_allclose(log.smc_t_s, [0.0, 0.002, 0.004])
    np.testing.assert_allclose(log.act_t_s, [0.0, 0.002, 0.004])
    # NED position -> north, east, altitude up; velocities stay NED.
    assert (log.north_m[0], log.east_m[0], log.alt_m[0]) == pytest.approx((1.0, 2.0, 3.0))
    assert (log.v_north_mps[0], log.v_east_mps[0], log.v_down_mps[0]) == pytest.approx((0.5, -0.25, -1.0))
    # Attitude in degrees, NED/FRD as logged.
    assert log.roll_deg[0] == pytest.approx(math.degrees(0.1), rel=1e-6)
    assert log.pitch_deg[0] == pytest.approx(math.degrees(-0.2), rel=1e-6)
    assert log.yaw_deg[0] == pytest.approx(math.degrees(3.0), rel=1e-6)
    assert log.yaw_rate_dps[0] == pytest.approx(math.degrees(-0.03), rel=1e-5)
    # Paper-frame targets -> north / east / altitude and compass heading (clockwise from north).
    assert (log.target_north_m[0], log.target_east_m[0], log.target_alt_m[0]) == pytest.approx((4.0, -3.0, 5.0))
    assert log.target_yaw_deg[0] == pytest.approx(-170.0, abs=1e-4)
    # Paper references -> NED angles: roll kept, pitch and yaw negated; z is already up.
    assert log.ref_roll_deg[0] == pytest.approx(math.degrees(0.1), rel=1e-6)
    assert log.ref_pitch_deg[0] == pytest.approx(-math.degrees(0.2), rel=1e-6)
    assert log.ref_yaw_deg[0] == pytest.approx(-math.degrees(0.3), rel=1e-6)
    assert log.ref_alt_m[0] == pytest.approx(2.0)
    # Raw arrays, actuators.
    assert log.chi_hat[0, 0] == pytest.approx(0.5) and np.isnan(log.chi_hat[0, 1])
    assert log.sigma[0, 3] == pytest.approx(-0.25)
    assert log.limited_mask[0] == 9
    np.testing.assert_allclose(log.motors[0], [0.1, 0.2, 0.3, 0.4], rtol=1e-6)
    assert log.armed.all()
    assert log.message_counts == {
        "ATTITUDE": 3, "DEBUG_FLOAT_ARRAY": 3, "HIL_ACTUATOR_CONTROLS": 3, "LOCAL_POSITION_NED": 3,
    }  # fmt: skip
    assert log.ctrl_source == "DEBUG_FLOAT_ARRAY SMC"
    assert "component 200" in (log.state_source or "")


def test_simulator_state_is_preferred_over_the_gcs_copy(tmp_path: Path) -> None:
    path = tmp_path / "both.tlog"
    b = LogBuilder(path)
    for k in range(4):
        t_us = k * 2000
        b.state(t_us, (1.0, 1.0, -1.0))
        # The copy sent to a GCS (component 1), with different values and even more records.
        b.state(t_us, (9.0, 9.0, -9.0), mav=b.fc, stamp_us=t_us)
        b.end_tick(t_us)
    b.state(8000, (9.0, 9.0, -9.0), mav=b.fc, stamp_us=8000)
    b.close()
    log = load_log(path)
    assert log.north_m.tolist() == [1.0] * 4
    assert log.message_counts["ATTITUDE"] == 9


# -- summary -----------------------------------------------------------------------------------------
def test_summary_of_a_flight_with_known_errors(flight_log: Path) -> None:
    s = summarize(load_log(flight_log), settle_s=7.99)  # 7.99: no tick sits on the boundary
    json.dumps(s, allow_nan=False)  # JSON-ready: no NaN anywhere

    assert s["duration_s"] == pytest.approx((N_TICKS - 1) * DT_US * 1e-6)
    assert s["armed_time_s"] == pytest.approx(DISARM_K * DT_US * 1e-6)
    assert s["overruns"] == 2
    assert s["max_tilt_deg"] == pytest.approx(math.degrees(math.acos(math.cos(math.radians(20)) * math.cos(math.radians(15)))), rel=1e-5)
    # Settled: 8.0..9.98 s (100 ticks at 0.1 m) and 18.0..24.98 s (350 ticks at 0.2 m); landing excluded.
    assert s["settled_time_s"] == pytest.approx(450 * DT_US * 1e-6)
    assert s["position_error_rms_m"] == pytest.approx(math.sqrt((100 * 0.1**2 + 350 * 0.2**2) / 450), rel=1e-5)
    assert s["position_error_max_m"] == pytest.approx(0.2, rel=1e-5)
    # Final: the last tick before "Landing", not the descent and not after disarm.
    assert s["position_error_final_m"] == pytest.approx(0.2, rel=1e-5)
    assert s["position_error_final_ned_m"]["east"] == pytest.approx(-0.2, rel=1e-5)
    assert s["position_error_final_ned_m"]["north"] == pytest.approx(0.0, abs=1e-6)
    # Yaw -175 vs set-point 170: +15 deg across ±180, not -345.
    assert s["yaw_error_final_deg"] == pytest.approx(15.0, abs=1e-3)
    assert s["yaw_error_rms_deg"] == pytest.approx(math.sqrt(350 * 15.0**2 / 450), rel=1e-4)  # 0 in window 1
    # chi_hat: last finite value (the tick before disarm); sigma over the 5 s before landing: a
    # constant sigma (from 18 s, the low-pass long settled) is all "LPF", no dither.
    last = DISARM_K - 1
    assert s["chi_hat_final"] == pytest.approx([0.5 + last * 1e-4 * (j + 1) for j in range(4)], rel=1e-6)
    assert s["sigma_lpf_rms"] == pytest.approx([0.01, 0.02, 0.03, 0.04], rel=1e-5)
    assert s["sigma_dither_rms"] == pytest.approx([0.0] * 4, abs=1e-8)
    # The metrics see the same window and the same numbers.
    assert s["metrics"]["sigma_lpf_rms"] == s["sigma_lpf_rms"] and s["metrics"]["sigma_dither_rms"] == s["sigma_dither_rms"]
    assert [e["text"] for e in s["events"]] == ["Armed", "Takeoff to 3.0 m", "Landing", "Landed: disarmed"]
    assert s["events"][2]["t_s"] == pytest.approx(25.0)
    assert s["events"][2]["severity"] == "INFO"
    assert s["message_counts"]["DEBUG_FLOAT_ARRAY"] == N_TICKS
    assert s["truncated"] is False


def test_logged_flags_mark_landing_without_any_event(tmp_path: Path) -> None:
    """Logs with the FC's per-tick flags need no event text to tell the landing apart."""
    path = tmp_path / "flags.tlog"
    write_flight(path, flags=True)
    s = summarize(load_log(path), settle_s=7.99)
    assert "Landing" not in [e["text"] for e in s["events"]]
    assert s["settled_time_s"] == pytest.approx(450 * DT_US * 1e-6)
    assert s["position_error_final_m"] == pytest.approx(0.2, rel=1e-5)  # the descent is not "final"


def test_default_settle_time_is_8_s(flight_log: Path) -> None:
    s = summarize(load_log(flight_log))
    # Whatever the boundary tick does, the window is about 2 s + 7 s and only 0.1/0.2 m errors count.
    assert s["settle_s"] == 8.0
    assert s["settled_time_s"] == pytest.approx(9.0, abs=2.5 * DT_US * 1e-6)
    assert 0.1 < s["position_error_rms_m"] < 0.2


def test_print_summary_is_readable(flight_log: Path) -> None:
    import io

    buf = io.StringIO()
    print_summary(summarize(load_log(flight_log)), buf)
    text = buf.getvalue()
    assert "flight.tlog" in text and "lockstep" in text
    assert "position error" in text and "final 0.2 m" in text
    assert "+15 deg" in text
    assert "25.000 s  INFO      Landing" in text


# -- damaged and unusual logs -----------------------------------------------------------------------
def test_truncated_last_record_keeps_what_was_read(flight_log: Path) -> None:
    data = flight_log.read_bytes()
    flight_log.write_bytes(data[:-5])
    log = load_log(flight_log)
    assert log.truncated
    assert "cut short" in (log.read_error or "")
    assert any("reading stopped" in w for w in log.warnings)
    assert log.smc_t_s.size == N_TICKS - 1  # the last record was the last SMC array
    assert log.att_t_s.size == N_TICKS
    s = summarize(log)
    assert s["truncated"] is True
    json.dumps(s, allow_nan=False)


def test_empty_file_gives_an_empty_log(tmp_path: Path) -> None:
    path = tmp_path / "empty.tlog"
    path.write_bytes(b"")
    log = load_log(path)
    assert log.records == 0 and log.att_t_s.size == 0 and log.t0_us is None
    assert "the log is empty" in log.warnings
    s = summarize(log)
    json.dumps(s, allow_nan=False)
    assert s["duration_s"] is None and s["position_error_final_m"] is None and s["message_counts"] == {}
    assert plot_log(log, tmp_path / "plots") == []


@pytest.mark.parametrize(
    "content",
    [b"time,x,y\n0,1,2\n1,2,3\n" * 10, b"abc", struct.pack(">Q", 1) + b"\x00" * 40],
    ids=["csv", "tiny", "zeros"],
)
def test_not_a_tlog_is_a_clear_error(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "data.csv"
    path.write_bytes(content)
    with pytest.raises(LogError, match=r"data\.csv is not a MAVLink telemetry log \(\.tlog\)") as info:
        load_log(path)
    assert isinstance(info.value, SmcpilotError)


def test_missing_file_and_directory_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(LogError, match="no such log file: .*nope.tlog"):
        load_log(tmp_path / "nope.tlog")
    with pytest.raises(LogError, match="is a directory"):
        load_log(tmp_path)


def test_log_without_smc_arrays_uses_named_value_floats(tmp_path: Path) -> None:
    """A ground-station-side log: 10 Hz state from component 1 and CHI_*/SIG_* telemetry."""
    path = tmp_path / "gcs.tlog"
    b = LogBuilder(path)
    for k in range(20):
        t_us = 1_000_000 + k * 100_000
        b.state(t_us, (0.0, 0.0, -2.0), mav=b.fc, stamp_us=t_us)
        for j, tag in enumerate(("PHI", "THETA", "PSI", "Z")):
            b.named_float(t_us, f"CHI_{tag}", 0.5 + 0.01 * k + j)
            b.named_float(t_us, f"SIG_{tag}", 0.1 * (j + 1))
    b.close()
    log = load_log(path)
    assert not log.has_smc
    assert log.ctrl_source == "NAMED_VALUE_FLOAT"
    assert log.ctrl_t_s.size == 20 and log.ctrl_t_s[0] == 0.0
    assert log.chi_hat[-1] == pytest.approx([0.69, 1.69, 2.69, 3.69], rel=1e-6)
    assert "component 1" in (log.state_source or "")
    assert log.lockstep is None  # no actuator messages: record times are used
    assert log.att_t_s[1] == pytest.approx(0.1)
    s = summarize(log)
    json.dumps(s, allow_nan=False)
    assert s["chi_hat_final"] == pytest.approx([0.69, 1.69, 2.69, 3.69], rel=1e-6)
    assert s["sigma_lpf_rms"] == pytest.approx([0.1, 0.2, 0.3, 0.4], rel=1e-6)
    assert s["sigma_dither_rms"] == pytest.approx([0.0] * 4, abs=1e-9)
    assert s["metrics"] is None  # no set-points without SMC arrays
    assert s["position_error_final_m"] is None  # no set-points without SMC arrays
    assert s["controller_data"] == "NAMED_VALUE_FLOAT"
    assert set(log.named_floats) == {f"{p}_{t}" for p in ("CHI", "SIG") for t in ("PHI", "THETA", "PSI", "Z")}


def test_cascade_pid_log_has_no_sigma_and_plots_without_it(tmp_path: Path) -> None:
    path = tmp_path / "cascade.tlog"
    write_flight(path, cascade=True)
    log = load_log(path)
    assert np.isnan(log.sigma).all() and np.isnan(log.chi_hat).all()
    s = summarize(log)
    json.dumps(s, allow_nan=False)
    assert s["chi_hat_final"] is None and s["sigma_lpf_rms"] is None and s["sigma_dither_rms"] is None
    assert s["metrics"]["sigma_lpf_rms"] is None and s["metrics"]["iae_pos_m_s"] > 0.0
    assert s["position_error_final_m"] == pytest.approx(0.2, rel=1e-5)  # tracking still assessed
    names = [p.name for p in plot_log(log, tmp_path / "plots")]
    assert names == ["position.png", "attitude.png", "motors.png", "track.png"]


# -- command line ------------------------------------------------------------------------------------
def _parser(add: object, handler: object) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser()
    add(p)  # type: ignore[operator]
    p.set_defaults(handler=handler)
    return p


def test_plot_cli_writes_pngs_next_to_the_log(flight_log: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = _parser(logtools.add_plot_arguments, logtools.plot_main).parse_args([str(flight_log)])
    assert args.handler(args) == 0
    out_dir = flight_log.with_name("flight-plots")
    expected = ["position.png", "attitude.png", "motors.png", "controller.png", "track.png"]
    assert sorted(p.name for p in out_dir.iterdir()) == sorted(expected)
    for name in expected:
        data = (out_dir / name).read_bytes()
        assert data.startswith(PNG_SIGNATURE) and len(data) > 10_000
    assert capsys.readouterr().out.split() == [str(out_dir / n) for n in expected]


def test_log_summary_cli_prints_text_and_writes_json(flight_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s.json"
    p = _parser(logtools.add_log_arguments, logtools.log_main)
    args = p.parse_args(["summary", str(flight_log), "--json", str(out)])
    assert args.handler(args) == 0
    assert "Tracking" in capsys.readouterr().out
    data = json.loads(out.read_text())
    assert data["log"] == "flight.tlog" and data["overruns"] == 2

    args = p.parse_args(["summary", str(flight_log), "--json", "-"])
    assert args.handler(args) == 0
    assert json.loads(capsys.readouterr().out)["position_error_final_m"] == pytest.approx(0.2, rel=1e-5)

    with pytest.raises(SystemExit):  # the subcommand is required
        p.parse_args([])
    args = p.parse_args(["summary", str(tmp_path / "missing.tlog")])
    with pytest.raises(LogError, match="no such log file"):
        args.handler(args)
