"""DroneKit-Python (the maintained ``dronekit2`` fork) flies smcpilot unmodified (issue 13).

A real-time ``smcpilot sitl`` (lockstep at a few times real time) and a DroneKit script written as
its documentation teaches: ``connect(wait_ready=True)``, wait for ``is_armable`` (needs
``EKF_STATUS_REPORT``), GUIDED, arm, ``simple_takeoff``, ``simple_goto`` (a ``MISSION_ITEM`` with
``current = 2``), a mission uploaded with ``vehicle.commands`` (DroneKit answers only
``MISSION_REQUEST``), flown in AUTO while ``commands.next`` advances, downloaded back (DroneKit asks
for item 0, home), LAND.
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable

import pytest
from gcs_helpers import HOME_LAT, HOME_LON, LOOPBACK, download_mission, latlon_to_ne, ne_to_latlon, sitl_run
from pymavlink.dialects.v20 import ardupilotmega as M

#: end-to-end: the quick tier (`pytest -m "not slow"`) leaves this module to the full suite.
pytestmark = pytest.mark.slow

LOITER_MODE = M.COPTER_MODE_LOITER


def _wait(cond: Callable[[], bool], timeout_s: float, what: Callable[[], str]) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, what()
        time.sleep(0.1)


def _f32(v: float) -> float:
    """What a float32 field carries of ``v`` (DroneKit sends lat/lon as MISSION_ITEM floats)."""
    import struct

    return struct.unpack("<f", struct.pack("<f", v))[0]


@pytest.mark.interop
def test_dronekit_flies_guided_and_a_mission(tmp_path):
    dronekit = pytest.importorskip("dronekit", reason="DroneKit not installed (pip install dronekit2)")
    from dronekit import Command, LocationGlobalRelative, VehicleMode

    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind((LOOPBACK, 0))
    port = probe.getsockname()[1]
    probe.close()
    with sitl_run(tmp_path, "dronekit", speed=3.0, gcs_port=port):
        v = dronekit.connect(f"udpin:{LOOPBACK}:{port}", wait_ready=True, timeout=60, heartbeat_timeout=30)
        try:
            _wait(lambda: v.is_armable, 20, lambda: f"never armable: mode {v.mode.name}, gps {v.gps_0}, ekf_ok {v.ekf_ok}")

            def ne() -> tuple[float, float]:
                loc = v.location.global_relative_frame
                return latlon_to_ne(loc.lat, loc.lon)

            def alt() -> float:
                return v.location.global_relative_frame.alt or 0.0

            v.mode = VehicleMode("GUIDED")
            _wait(lambda: v.mode.name == "GUIDED", 10, lambda: f"mode {v.mode.name}")
            v.armed = True
            _wait(lambda: v.armed, 10, lambda: "never armed")
            v.simple_takeoff(3)
            _wait(lambda: alt() > 2.7, 20, lambda: f"no take-off: altitude {alt():.2f} m")

            # simple_goto: fly to the point as float32 carries it (up to ~0.7 m from the double)
            lat, lon = ne_to_latlon(4.0, -3.0)
            v.simple_goto(LocationGlobalRelative(lat, lon, 4.0))
            goal = latlon_to_ne(_f32(lat), _f32(lon))

            def off_goal() -> float:
                n, e = ne()
                return math.hypot(n - goal[0], e - goal[1])

            _wait(lambda: off_goal() < 1.0 and abs(alt() - 4.0) < 1.0, 20,
                  lambda: f"simple_goto not reached: {off_goal():.2f} m off, altitude {alt():.2f} m")  # fmt: skip

            # a 3-waypoint mission with vehicle.commands (float MISSION_ITEMs, MISSION_REQUEST only)
            cmds = v.commands
            cmds.download()
            cmds.wait_ready(timeout=15)
            cmds.clear()
            wps = [(0.0, 0.0, 3.0), (3.0, 3.0, 3.5), (0.0, 3.0, 3.0)]
            for n, e, a in wps:
                wlat, wlon = ne_to_latlon(n, e)
                cmds.add(Command(0, 0, 0, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_CMD_NAV_WAYPOINT,
                                 0, 0, 0, 0, 0, 0, wlat, wlon, a))  # fmt: skip
            cmds.upload(timeout=15)
            seen: list[int] = []

            def track() -> bool:
                if not seen or seen[-1] != cmds.next:
                    seen.append(cmds.next)
                n, e = ne()
                return cmds.next == 3 and math.hypot(n - wps[2][0], e - wps[2][1]) < 1.0

            v.mode = VehicleMode("AUTO")
            _wait(track, 40, lambda: f"mission not flown: next {seen}, at {ne()}")
            flown = [s for s in seen if s >= 1]
            assert flown[0] == 1 and flown == sorted(flown) and flown[-1] == 3, f"commands.next did not advance 1..3: {seen}"

            # ...downloaded back, home as item 0
            cmds.download()
            cmds.wait_ready(timeout=15)
            assert cmds.count == 3
            for cmd, (n, e, a) in zip(cmds, wps, strict=True):
                assert cmd.command == M.MAV_CMD_NAV_WAYPOINT
                got_n, got_e = latlon_to_ne(cmd.x, cmd.y)
                assert math.hypot(got_n - n, got_e - e) < 0.8 and cmd.z == pytest.approx(a)
            home = v.home_location
            assert home is not None and home.lat == pytest.approx(HOME_LAT, abs=1e-6) and home.lon == pytest.approx(HOME_LON, abs=1e-6)

            v.mode = VehicleMode("LAND")
            _wait(lambda: not v.armed, 30, lambda: f"never disarmed after LAND: altitude {alt():.2f} m")
        finally:
            v.close()


# == the pieces DroneKit needs, checked one by one ===================================================
def _snap(**kw):
    from fc.pipeline import VehicleState
    from fc.telemetry import TelemetrySnapshot
    from smcpilot.geo import Home

    base = dict(time_us=0, state=VehicleState(*([0.0] * 12)), body_rates=(0.0, 0.0, 0.0), armed=False,
                mode=M.COPTER_MODE_GUIDED, failsafe=False, prearm_ok=True, landed_state=M.MAV_LANDED_STATE_ON_GROUND,
                target=(0.0, 0.0, 0.0), yaw_target_rad=0.0, pipeline=None, overruns=0, mission_current=0,
                mission_count=0, home=Home(HOME_LAT, HOME_LON, 584.0), system_id=1)  # fmt: skip
    base.update(kw)
    return TelemetrySnapshot(**base)


def test_ekf_status_flags_follow_the_estimate():
    from fc import telemetry
    from fc.estimate import EST_ATTITUDE_LOST, EST_DEAD_RECKONING, EST_POSITION_LOST, MISSING_POSITION, MISSING_VELOCITY

    pos = M.EKF_POS_HORIZ_REL | M.EKF_POS_HORIZ_ABS | M.EKF_POS_VERT_ABS | M.EKF_POS_VERT_AGL | M.EKF_PRED_POS_HORIZ_REL | M.EKF_PRED_POS_HORIZ_ABS
    vel = M.EKF_VELOCITY_HORIZ | M.EKF_VELOCITY_VERT
    healthy = M.EKF_ATTITUDE | vel | pos
    assert healthy == 0x37F  # every flag but CONST_POS_MODE (0x80) and GPS_GLITCH / UNINITIALIZED
    cases = [
        (_snap(), healthy),
        (_snap(estimate_status=EST_DEAD_RECKONING, estimate_missing=MISSING_POSITION), M.EKF_ATTITUDE | vel),
        (_snap(estimate_status=EST_DEAD_RECKONING, estimate_missing=MISSING_VELOCITY), M.EKF_ATTITUDE | pos),
        (_snap(estimate_status=EST_POSITION_LOST, estimate_missing=MISSING_POSITION), M.EKF_ATTITUDE),
        (_snap(failsafe=True), M.EKF_ATTITUDE),
        (_snap(estimate_status=EST_ATTITUDE_LOST), 0),
        (_snap(state_fresh=False), 0),
        (_snap(state=None), 0),
    ]
    mav = M.MAVLink(None)
    for snap, flags in cases:
        assert telemetry.ekf_flags(snap) == flags, snap
        (msg,) = telemetry.build(M.MAVLINK_MSG_ID_EKF_STATUS_REPORT, snap, mav)
        assert msg.flags == flags
        assert msg.pos_horiz_variance == (telemetry.EKF_HEALTHY_VARIANCE if flags & M.EKF_POS_HORIZ_ABS else 1.0)
        assert msg.velocity_variance == (telemetry.EKF_HEALTHY_VARIANCE if flags & M.EKF_VELOCITY_HORIZ else 1.0)
        assert not msg.flags & M.EKF_CONST_POS_MODE


class _Recorder:
    def __init__(self) -> None:
        self.sent: list = []

    def __call__(self, msg, addr) -> None:
        self.sent.append((msg, addr))

    def types(self) -> list[str]:
        out = [m.get_type() for m, _a in self.sent]
        self.sent.clear()
        return out


def _protocol():
    from fc.mission import MissionProtocol, MissionStore
    from smcpilot.geo import Home

    rec = _Recorder()
    home = Home(HOME_LAT, HOME_LON, 584.0)
    return MissionProtocol(MissionStore(), M.MAVLink(None), rec, home=lambda: home), rec


def _item(mav, seq, *, as_int: bool, lat=HOME_LAT, lon=HOME_LON, alt=3.0, current=0):
    if as_int:
        return mav.mission_item_int_encode(1, 1, seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_WAYPOINT, current, 1,
                                           0, 0, 0, 0, int(lat * 1e7), int(lon * 1e7), alt)  # fmt: skip
    return mav.mission_item_encode(1, 1, seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_CMD_NAV_WAYPOINT, current, 1,
                                   0, 0, 0, 0, lat, lon, alt)  # fmt: skip


def test_mission_requests_follow_the_station_protocol_and_home_is_item_0():
    from fc.mission import REQUEST_TIMEOUT_S

    p, rec = _protocol()
    mav = M.MAVLink(None)
    a, b = ("127.0.0.1", 1), ("127.0.0.1", 2)
    # empty mission: count 0, but item 0 is home (both request kinds), item 1 is not
    p.on_request_list(mav.mission_request_list_encode(1, 1), a)
    assert [m.count for m, _ in rec.sent] == [0]
    rec.sent.clear()
    p.on_request(mav.mission_request_int_encode(1, 1, 0), a, True)
    (home_int, _), = rec.sent
    assert home_int.get_type() == "MISSION_ITEM_INT" and (home_int.x, home_int.y) == (round(HOME_LAT * 1e7), round(HOME_LON * 1e7))
    assert home_int.frame == M.MAV_FRAME_GLOBAL_INT and home_int.z == 584.0
    rec.sent.clear()
    p.on_request(mav.mission_request_encode(1, 1, 0), b, False)  # b now speaks the float protocol
    (home_f, _), = rec.sent
    assert home_f.get_type() == "MISSION_ITEM" and home_f.x == pytest.approx(HOME_LAT) and home_f.frame == M.MAV_FRAME_GLOBAL
    rec.sent.clear()
    p.on_request(mav.mission_request_int_encode(1, 1, 1), a, True)
    assert rec.sent[0][0].get_type() == "MISSION_ACK" and rec.sent[0][0].type == M.MAV_MISSION_INVALID_SEQUENCE
    rec.sent.clear()

    # an INT station is asked with MISSION_REQUEST_INT; a station that never answers, with both
    p.on_count(mav.mission_count_encode(1, 1, 2), a, 0.0)
    assert rec.types() == ["MISSION_REQUEST_INT"]
    p.tick(REQUEST_TIMEOUT_S + 0.01)
    assert rec.types() == ["MISSION_REQUEST_INT", "MISSION_REQUEST"]
    p.on_item(_item(mav, 0, as_int=True), a, 1.1)
    assert rec.types() == ["MISSION_REQUEST_INT"]
    p.tick(2.2)
    assert rec.types() == ["MISSION_REQUEST_INT"]  # it answered: the INT request only
    p.on_item(_item(mav, 1, as_int=True), a, 2.3)
    assert [(m.get_type(), m.type) for m, _ in rec.sent] == [("MISSION_ACK", M.MAV_MISSION_ACCEPTED)]
    rec.sent.clear()
    # non-empty: item 0 is the stored one, as before
    p.on_request(mav.mission_request_int_encode(1, 1, 0), a, True)
    assert rec.sent[0][0].z == 3.0
    rec.sent.clear()

    # a float-protocol station (b asked with MISSION_REQUEST above) is asked with MISSION_REQUEST only
    p.on_count(mav.mission_count_encode(1, 1, 2), b, 10.0)
    assert rec.types() == ["MISSION_REQUEST"]
    p.on_item(_item(mav, 0, as_int=False), b, 10.1)
    p.on_item(_item(mav, 1, as_int=False, alt=4.0), b, 10.2)
    assert rec.types() == ["MISSION_REQUEST", "MISSION_ACK"]
    assert [it.z for it in p.items] == [3.0, 4.0]


def test_guided_mission_item_flies_there_and_is_acked(tmp_path):
    with sitl_run(tmp_path, "guided") as run:
        _guided_item_checks(run.gcs)


def _guided_item_checks(g) -> None:
    mav = g.mav

    def send_guided(current: int, n: float, e: float, alt: float, frame=M.MAV_FRAME_GLOBAL_RELATIVE_ALT):
        lat, lon = ne_to_latlon(n, e)
        mark = g.mark()
        mav.mission_item_send(1, 1, 0, frame, M.MAV_CMD_NAV_WAYPOINT, current, 0, 0, 0, 0, 0, lat, lon, alt)
        return g.wait("MISSION_ACK", since=mark, what="MISSION_ACK of a guided item"), mark

    # EKF_STATUS_REPORT: streamed, healthy on the ground, and on request
    ekf = g.wait("EKF_STATUS_REPORT", sim_timeout_s=2.0, what="streamed EKF_STATUS_REPORT")
    assert ekf.flags & M.EKF_PRED_POS_HORIZ_ABS and ekf.flags & M.EKF_POS_HORIZ_ABS and not ekf.flags & M.EKF_CONST_POS_MODE
    mark = g.mark()
    g.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_EKF_STATUS_REPORT)
    g.wait("EKF_STATUS_REPORT", since=mark, what="requested EKF_STATUS_REPORT")
    # a position dropout: the position flags go (dead reckoning, then lost), and come back with it
    pos_flags = M.EKF_POS_HORIZ_ABS | M.EKF_POS_HORIZ_REL | M.EKF_POS_VERT_ABS | M.EKF_PRED_POS_HORIZ_ABS
    g.param_set("SIM_POS_FAULT", 4)
    ekf = g.wait("EKF_STATUS_REPORT", lambda m: not m.flags & pos_flags, sim_timeout_s=3.0, what="position flags cleared")
    assert ekf.flags & M.EKF_ATTITUDE and ekf.pos_horiz_variance == 1.0
    g.param_set("SIM_POS_FAULT", 0)
    ekf = g.wait("EKF_STATUS_REPORT", lambda m: m.flags & pos_flags == pos_flags, sim_timeout_s=3.0, what="position back")
    assert ekf.pos_horiz_variance < 0.1

    # refused while not flying in GUIDED: MAV_MISSION_ERROR with a reason; a bad frame: UNSUPPORTED_FRAME
    ack, mark = send_guided(2, 2.0, 0.0, 3.0)
    assert ack.type == M.MAV_MISSION_ERROR
    assert "not armed" in g.wait("STATUSTEXT", since=mark, what="reason").text
    ack, _ = send_guided(2, 2.0, 0.0, 3.0, frame=M.MAV_FRAME_LOCAL_NED)
    assert ack.type == M.MAV_MISSION_UNSUPPORTED_FRAME
    g.set_mode(LOITER_MODE)
    g.wait_mode(LOITER_MODE)
    g.run_wall(1.1)  # refusal texts are rate-limited to one a second per reason
    ack, mark = send_guided(2, 2.0, 0.0, 3.0)
    assert ack.type == M.MAV_MISSION_ERROR
    assert "GUIDED" in g.wait("STATUSTEXT", since=mark, what="reason").text
    g.set_mode(M.COPTER_MODE_GUIDED)
    g.wait_mode(M.COPTER_MODE_GUIDED)

    g.arm()
    g.takeoff(3.0)
    g.wait_altitude(3.0, tol_m=0.3)
    ack, _ = send_guided(2, 4.0, -2.0, 3.0)
    assert ack.type == M.MAV_MISSION_ACCEPTED
    g.until(lambda: math.dist(g.ne(), (4.0, -2.0)) < 0.3, sim_timeout_s=15, what="guided waypoint reached")
    ack, _ = send_guided(3, 0.0, 0.0, 5.0)  # altitude only: lat/lon ignored
    assert ack.type == M.MAV_MISSION_ACCEPTED
    g.wait_altitude(5.0, tol_m=0.3)
    assert math.dist(g.ne(), (4.0, -2.0)) < 0.3
    assert download_mission(g) == []  # a guided item is not stored as a mission
