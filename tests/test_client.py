"""ground.client.Vehicle against the real flight controller (lockstep SITL over UDP on 127.0.0.1).

Waits are in simulated seconds; the lockstep simulation runs many times faster than real time,
so each flight here takes about a second of wall time. Pure helpers (mode names, mission items)
get plain unit tests; the GCS heartbeat is checked on a raw UDP socket.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.client import (
    COPTER_MODES,
    CommandDenied,
    CommandTimeout,
    ConnectTimeout,
    MissionError,
    MissionItem,
    ParamError,
    ParamRejected,
    Telemetry,
    UnknownModeError,
    Vehicle,
    VehicleTimeout,
    mode_name,
    mode_number,
)
from ground.sitl import Sitl, SitlOptions
from smcpilot.errors import ConfigError, SmcpilotError
from smcpilot.geo import Home, ned_to_global

LOOPBACK = "127.0.0.1"


@contextlib.contextmanager
def sitl_vehicle(tmp_path: Path, *, via: str = "udpin", vehicle_kw: dict[str, Any] | None = None, **sitl_kw: Any) -> Iterator[tuple[Sitl, Vehicle]]:
    """Lockstep SITL and a connected Vehicle.

    ``via="udpin"``: the vehicle listens on a free port and the FC sends its telemetry there
    (``--gcs udp:127.0.0.1:PORT``). ``via="udpout"``: the FC listens on a free port and the
    vehicle writes to it (``udpout:`` + ``Sitl.gcs_address``).
    """
    kw = dict(vehicle_kw or {})
    common = dict(lockstep=True, log_dir=tmp_path, tlog=tmp_path / "sitl.tlog")
    common.update(sitl_kw)
    if via == "udpin":
        vehicle = Vehicle(f"udpin:{LOOPBACK}:0", **kw).open()
        try:
            with Sitl(SitlOptions.of(gcs=f"udp:{LOOPBACK}:{vehicle.local_address[1]}", **common)) as sitl:
                vehicle.wait_heartbeat(20.0)
                yield sitl, vehicle
        finally:
            vehicle.close()
    else:
        with Sitl(SitlOptions.of(gcs=f"udpin:{LOOPBACK}:0", **common)) as sitl:
            assert sitl.gcs_address
            with Vehicle(f"udpout:{sitl.gcs_address}", connect_timeout_s=20.0, **kw) as vehicle:
                yield sitl, vehicle


@pytest.fixture
def fc(tmp_path: Path) -> Iterator[Vehicle]:
    with sitl_vehicle(tmp_path) as (_sitl, vehicle):
        yield vehicle


def take_off(v: Vehicle, alt_m: float = 2.0) -> None:
    v.arm()
    v.takeoff(alt_m)
    v.wait_altitude(alt_m, tol_m=0.3, timeout_sim_s=20.0)


# ------------------------------------------------------------------------------ pure helpers
def test_mode_names_and_numbers_are_arducopters() -> None:
    assert mode_number("guided") == 4 == COPTER_MODES["GUIDED"]
    assert mode_number(" Loiter ") == 5
    assert mode_number("9") == 9 and mode_number(6) == 6
    assert mode_name(3) == "AUTO" and mode_name(2) == "ALT_HOLD" and mode_name(99) == "MODE_99"
    assert mode_name(None) is None
    with pytest.raises(UnknownModeError, match="unknown flight mode 'hover'.*GUIDED") as info:
        mode_number("hover")
    assert isinstance(info.value, ConfigError)


def test_mission_item_builders_use_the_protocols_commands_and_frames() -> None:
    rel = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
    t = MissionItem.takeoff(3)
    assert (t.command, t.frame, t.alt_m, t.lat_deg, t.lon_deg) == (mavlink.MAV_CMD_NAV_TAKEOFF, rel, 3.0, 0.0, 0.0)
    w = MissionItem.waypoint(-35.1, 149.2, 4.0, hold_s=2.0, acceptance_radius_m=0.5)
    assert (w.command, w.param1, w.param2, w.alt_m) == (mavlink.MAV_CMD_NAV_WAYPOINT, 2.0, 0.5, 4.0)
    assert math.isnan(w.param4), "no yaw = NaN on the wire (keep the heading)"
    assert MissionItem.waypoint(0.1, 0.2, 1.0, yaw_deg=90).param4 == 90.0
    lt = MissionItem.loiter_time(5.0, alt_m=2.0)
    assert (lt.command, lt.param1, lt.alt_m) == (mavlink.MAV_CMD_NAV_LOITER_TIME, 5.0, 2.0)
    assert MissionItem.land().command == mavlink.MAV_CMD_NAV_LAND
    assert MissionItem.rtl().command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH
    sp = MissionItem.change_speed(2.5)
    assert (sp.command, sp.frame, sp.param2) == (mavlink.MAV_CMD_DO_CHANGE_SPEED, mavlink.MAV_FRAME_MISSION, 2.5)
    home = MissionItem.home(None)
    assert (home.command, home.frame) == (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_FRAME_GLOBAL)
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.alt_m = 5.0  # type: ignore[misc]


def test_mission_item_survives_the_wire_to_1e7_degrees() -> None:
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    item = MissionItem.waypoint(-35.36326149, 149.16523051, 3.25, hold_s=1.5, yaw_deg=-45.0)
    msg = item.to_message(mav, 4, 1, 1)
    assert (msg.seq, msg.x, msg.y, msg.frame) == (4, -353632615, 1491652305, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT)
    decoded = mav.decode(bytearray(msg.pack(mav)))
    back = MissionItem.from_message(decoded)
    assert back.close_to(item)
    assert not back.close_to(MissionItem.waypoint(-35.3632, 149.16523051, 3.25, hold_s=1.5, yaw_deg=-45.0))
    # An *_INT frame means the same as its plain twin.
    assert MissionItem.land().close_to(MissionItem(mavlink.MAV_CMD_NAV_LAND, frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT))


def test_command_denied_says_what_and_why() -> None:
    err = CommandDenied(mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_RESULT_DENIED, "Takeoff: arm first")
    assert str(err) == "MAV_CMD_NAV_TAKEOFF refused with MAV_RESULT_DENIED: Takeoff: arm first"
    assert (err.result_name, err.reason) == ("MAV_RESULT_DENIED", "Takeoff: arm first")
    assert isinstance(err, SmcpilotError)


def test_empty_telemetry_is_json_ready() -> None:
    t = Telemetry()
    assert t.mode_name is None and t.altitude_m is None and t.landed_state_name is None
    json.dumps(t.as_dict())


def test_gcs_heartbeat_is_sent_at_1hz_as_system_255_component_190() -> None:
    """No vehicle needed: a raw UDP socket plays the FC's port and reads what the client sends."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((LOOPBACK, 0))
    sock.settimeout(3.0)
    parser = mavlink.MAVLink(None)
    vehicle = Vehicle(f"udpout:{LOOPBACK}:{sock.getsockname()[1]}").open()
    try:
        stamps = []
        while len(stamps) < 3:
            data, _ = sock.recvfrom(65535)
            for m in parser.parse_buffer(data) or []:
                if m.get_type() == "HEARTBEAT":
                    assert (m.get_srcSystem(), m.get_srcComponent()) == (255, 190)
                    assert (m.type, m.autopilot) == (mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID)
                    stamps.append(time.monotonic())
        gaps = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
        assert all(0.5 < g < 2.5 for g in gaps), gaps
    finally:
        vehicle.close()
        sock.close()


def test_no_vehicle_raises_connect_timeout_naming_the_port() -> None:
    vehicle = Vehicle(f"udpin:{LOOPBACK}:0", connect_timeout_s=0.3)
    t0 = time.monotonic()
    with pytest.raises(ConnectTimeout, match=r"no HEARTBEAT from a vehicle within 0.3 s wall, listening on 127\.0\.0\.1:\d+"):
        vehicle.connect()
    assert time.monotonic() - t0 < 3.0
    assert vehicle._link is None, "a failed connect closes the link"


def test_bad_settings_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="ack_timeout_s"):
        Vehicle(f"udpin:{LOOPBACK}:0", ack_timeout_s=0)
    with pytest.raises(ConfigError, match="command_tries"):
        Vehicle(f"udpin:{LOOPBACK}:0", command_tries=0)
    with pytest.raises(ConfigError, match="endpoint"):
        Vehicle("tcp:1.2.3.4:5").open()


# ------------------------------------------------------------------------- the real FC: link
@pytest.mark.parametrize("via", ["udpin", "udpout"])
@pytest.mark.slow
def test_connects_and_reads_heartbeat_mode_and_telemetry(tmp_path: Path, via: str) -> None:
    with sitl_vehicle(tmp_path, via=via) as (_sitl, v):
        t = v.wait_for(
            lambda s: s.position_ned_m is not None and s.attitude_rad is not None and len(s.chi) == 4 and s.landed_state is not None,
            5.0,
            what="full telemetry",
        )
        assert (t.system_id, t.component_id) == (1, 1)
        assert t.mode_name == "GUIDED" and v.mode == "GUIDED", "the FC starts disarmed in GUIDED"
        assert not t.armed and t.prearm_ok
        assert t.landed_state_name == "ON_GROUND"
        assert set(t.chi) == set(t.sigma) == {"PHI", "THETA", "PSI", "Z"}
        assert t.sim_time_s is not None and t.sim_time_s >= 0.0
        assert abs(t.altitude_m) < 0.2
        home = v.get_home()
        assert (home.lat_deg, home.lon_deg, home.alt_amsl_m) == pytest.approx((-35.363261, 149.165230, 584.0), abs=1e-6)
        start = v.sim_time_s
        v.sleep_sim(2.0)
        assert v.sim_time_s >= start + 2.0


@pytest.mark.slow
def test_subscriptions_deliver_to_queues_and_callbacks(fc: Vehicle) -> None:
    seen: list[str] = []
    with fc.subscribe("HEARTBEAT", callback=lambda m: seen.append(m.get_type())), fc.subscribe(["STATUSTEXT", "COMMAND_ACK"]) as sub:
        with pytest.raises(CommandDenied):
            fc.takeoff(2.0)
        types = [m.get_type() for m in sub]
        assert "COMMAND_ACK" in types and "STATUSTEXT" in types
        fc.sleep_sim(1.5)
    assert "HEARTBEAT" in seen and set(seen) == {"HEARTBEAT"}


# ------------------------------------------------------------------------ the real FC: flying
@pytest.mark.slow
def test_arm_takeoff_goto_land_with_waits_in_simulated_seconds(fc: Vehicle) -> None:
    t_start = fc.sim_time_s
    fc.arm()
    assert fc.armed
    fc.takeoff(2.0)
    t = fc.wait_altitude(2.0, tol_m=0.25, timeout_sim_s=20.0)
    assert t.sim_time_s - t_start < 20.0
    fc.goto_ned(3.0, -2.0, -2.5, yaw_deg=90.0)
    t = fc.wait_position_ned(3.0, -2.0, -2.5, tol_m=0.3, timeout_sim_s=20.0, max_speed_mps=0.5)
    fc.wait_for(lambda s: abs((s.yaw_deg - 90.0 + 180.0) % 360.0 - 180.0) < 5.0, 10.0, what="heading 90°", value=lambda s: s.yaw_deg)
    assert fc.mode == "GUIDED"
    fc.land()
    fc.wait_mode("LAND", 3.0)
    t = fc.wait_disarmed(timeout_sim_s=30.0)
    assert t.altitude_m < 0.15
    assert fc.wait_landed_state("ON_GROUND", 5.0).landed_state_name == "ON_GROUND"
    texts = [s.text for s in fc.statustexts]
    assert any("Armed" in x for x in texts)


@pytest.mark.slow
def test_goto_global_repositions_through_home(fc: Vehicle) -> None:
    take_off(fc, 2.0)
    home = fc.get_home()
    lat, lon, _ = ned_to_global(Home(home.lat_deg, home.lon_deg, home.alt_amsl_m), -2.0, 3.0, 0.0)
    fc.goto_global(lat, lon, 3.0)
    fc.wait_position_ned(-2.0, 3.0, -3.0, tol_m=0.3, timeout_sim_s=20.0)
    t = fc.wait_for(lambda s: s.lat_deg is not None, 2.0, what="GLOBAL_POSITION_INT")
    assert (t.lat_deg, t.lon_deg) == pytest.approx((lat, lon), abs=5e-6)
    assert t.relative_alt_m == pytest.approx(3.0, abs=0.3)


@pytest.mark.slow
def test_rtl_returns_home_lands_and_disarms(fc: Vehicle) -> None:
    take_off(fc, 2.0)
    fc.goto_ned(4.0, 0.0, -2.0)
    fc.wait_position_ned(4.0, 0.0, -2.0, tol_m=0.4, timeout_sim_s=20.0)
    fc.rtl()
    fc.wait_mode("RTL", 3.0)
    t = fc.wait_disarmed(timeout_sim_s=60.0)
    n, e, _ = t.position_ned_m
    assert math.hypot(n, e) < 0.5


@pytest.mark.slow
def test_set_mode_waits_for_the_heartbeat(fc: Vehicle) -> None:
    take_off(fc, 2.0)
    fc.set_mode("LOITER")
    assert fc.mode == "LOITER"
    fc.set_mode("guided")
    assert fc.telemetry.mode_number == 4


# ---------------------------------------------------------------------- denials and timeouts
@pytest.mark.slow
def test_takeoff_while_disarmed_is_denied_with_the_fcs_reason(fc: Vehicle) -> None:
    with pytest.raises(CommandDenied) as info:
        fc.takeoff(2.0)
    err = info.value
    assert err.result_name == "MAV_RESULT_DENIED"
    assert err.reason and "arm" in err.reason.lower()
    assert "MAV_CMD_NAV_TAKEOFF refused with MAV_RESULT_DENIED: " in str(err)


@pytest.mark.slow
def test_unflyable_mode_is_denied_and_unknown_mode_never_sent(fc: Vehicle) -> None:
    with pytest.raises(CommandDenied) as info:
        fc.set_mode("STABILIZE")
    assert info.value.result_name == "MAV_RESULT_DENIED" and info.value.reason
    with pytest.raises(UnknownModeError):
        fc.set_mode("HOVER")
    assert fc.mode == "GUIDED"


@pytest.mark.slow
def test_raw_commands_return_the_result_instead_of_raising(fc: Vehicle) -> None:
    assert fc.command_long(mavlink.MAV_CMD_NAV_TAKEOFF, param7=2.0) == mavlink.MAV_RESULT_DENIED
    assert fc.command_long(31999) == mavlink.MAV_RESULT_UNSUPPORTED
    assert fc.command_int(31999, check=False) == mavlink.MAV_RESULT_UNSUPPORTED
    with pytest.raises(CommandDenied, match="MAV_RESULT_UNSUPPORTED"):
        fc.command_long(31999, check=True)


@pytest.mark.slow
def test_disarm_in_the_air_needs_force(fc: Vehicle) -> None:
    take_off(fc, 2.0)
    with pytest.raises(CommandDenied) as info:
        fc.disarm()
    assert info.value.reason
    assert fc.armed


@pytest.mark.slow
def test_wait_timeout_counts_simulated_seconds_and_says_what_and_last_value(fc: Vehicle) -> None:
    start = fc.sim_time_s
    with pytest.raises(VehicleTimeout) as info:
        fc.wait_altitude(50.0, tol_m=0.5, timeout_sim_s=3.0)
    err = info.value
    assert err.what == "altitude 50 ± 0.5 m"
    assert err.sim_time_s is not None and err.sim_time_s - start >= 3.0
    msg = str(err)
    assert msg.startswith("timed out after 3 s simulated waiting for altitude 50 ± 0.5 m; last value ")
    assert " m; sim time " in msg


@pytest.mark.slow
def test_wait_gives_up_when_the_simulator_stops(tmp_path: Path) -> None:
    with sitl_vehicle(tmp_path, vehicle_kw=dict(stall_timeout_s=1.0, ack_timeout_s=0.2, command_tries=2)) as (sitl, v):
        v.sleep_sim(0.5)
        sitl.terminate()
        t0 = time.monotonic()
        with pytest.raises(VehicleTimeout, match="nothing from the vehicle for .* wall .*waiting for armed; last value disarmed; sim time"):
            v.wait_armed(timeout_sim_s=1000.0)
        assert time.monotonic() - t0 < 5.0
        with pytest.raises(CommandTimeout, match="no COMMAND_ACK for MAV_CMD_COMPONENT_ARM_DISARM after 2 tries"):
            v.arm()


# ------------------------------------------------------------------------------ parameters
@pytest.mark.slow
def test_param_get_set_round_trip_and_refusal(fc: Vehicle) -> None:
    old = fc.get_param("WP_RADIUS_M")
    assert isinstance(old, float)
    assert fc.set_param("wp_radius_m", 0.75) == pytest.approx(0.75)
    assert fc.get_param("WP_RADIUS_M") == pytest.approx(0.75)
    assert isinstance(fc.get_param("ARMING_CHECK"), int), "INT32 parameters come back as int"
    with pytest.raises(ParamRejected) as info:
        fc.set_param("WP_RADIUS_M", -5.0)
    err = info.value
    assert err.value == pytest.approx(0.75) and err.requested == -5.0
    assert err.reason and "WP_RADIUS_M" in err.reason
    assert fc.get_param("WP_RADIUS_M") == pytest.approx(0.75)


@pytest.mark.slow
def test_unknown_param_fails_fast_with_the_fcs_word(fc: Vehicle) -> None:
    t0 = time.monotonic()
    with pytest.raises(ParamError, match="NO_SUCH_PARAM"):
        fc.get_param("NO_SUCH_PARAM")
    assert time.monotonic() - t0 < 3.0
    with pytest.raises(ConfigError, match="16 characters"):
        fc.get_param("A_VERY_LONG_PARAMETER_NAME")


@pytest.mark.slow
def test_list_params_returns_every_parameter_in_index_order(fc: Vehicle) -> None:
    params = fc.list_params()
    assert len(params) > 20
    assert "ARMING_CHECK" in params and "SMC_Z_KP" in params
    assert all(isinstance(v, (int, float)) for v in params.values())
    assert fc.get_param("SMC_Z_KP") == pytest.approx(params["SMC_Z_KP"])


# -------------------------------------------------------------------------------- missions
def _mission(home_lat: float, home_lon: float) -> list[MissionItem]:
    home = Home(home_lat, home_lon, 584.0)
    lat, lon, _ = ned_to_global(home, 3.0, 0.0, 0.0)
    return [
        MissionItem.takeoff(2.0),
        MissionItem.change_speed(2.0),
        MissionItem.waypoint(lat, lon, 2.0, hold_s=0.5),
        MissionItem.loiter_time(0.5, alt_m=2.0),
        MissionItem.land(),
    ]


@pytest.mark.slow
def test_mission_round_trip_inserts_and_strips_home(fc: Vehicle) -> None:
    home = fc.get_home()
    items = _mission(home.lat_deg, home.lon_deg)
    fc.upload_mission(items)
    back = fc.download_mission()
    assert len(back) == len(items)
    for sent, got in zip(items, back, strict=True):
        assert got.close_to(sent), (sent, got)
    raw = fc.download_mission(include_home=True)
    assert len(raw) == len(items) + 1
    assert raw[0].command == mavlink.MAV_CMD_NAV_WAYPOINT
    assert (raw[0].lat_deg, raw[0].lon_deg) == pytest.approx((home.lat_deg, home.lon_deg), abs=2e-7)
    fc.clear_mission()
    assert fc.download_mission() == []


@pytest.mark.slow
def test_refused_mission_item_raises_with_the_mission_result(fc: Vehicle) -> None:
    home = fc.get_home()
    good = _mission(home.lat_deg, home.lon_deg)
    fc.upload_mission(good)
    with pytest.raises(MissionError) as info:
        fc.upload_mission([MissionItem.takeoff(2.0), MissionItem(mavlink.MAV_CMD_DO_JUMP, frame=mavlink.MAV_FRAME_MISSION)])
    assert info.value.result_name == "MAV_MISSION_UNSUPPORTED"
    assert len(fc.download_mission()) == len(good), "a refused upload keeps the stored mission"


@pytest.mark.slow
def test_mission_flies_in_auto_and_set_current_item(fc: Vehicle) -> None:
    home = fc.get_home()
    fc.upload_mission(_mission(home.lat_deg, home.lon_deg))
    with pytest.raises(CommandDenied):
        fc.set_current_item(99)
    fc.set_current_item(1)
    fc.wait_for(lambda s: s.mission_current == 1, 3.0, what="mission item 1", value=lambda s: s.mission_current)
    fc.arm()
    fc.start_mission()
    fc.wait_mode("AUTO", 3.0)
    fc.wait_for(lambda s: (s.mission_reached or 0) >= 3, 30.0, what="waypoint reached", value=lambda s: s.mission_reached)
    assert fc.telemetry.position_ned_m[0] == pytest.approx(3.0, abs=0.6)
    t = fc.wait_disarmed(timeout_sim_s=40.0)
    assert t.altitude_m < 0.15


# ------------------------------------------------------- retries, against a lossy protocol peer
class LossyVehicle:
    """A minimal vehicle on a real UDP socket that drops chosen requests, to exercise the
    client's retries (the real FC never loses a message on loopback). It sends a HEARTBEAT when
    asked (:meth:`beat`) and answers on its own thread."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((LOOPBACK, 0))
        self.sock.settimeout(0.05)
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.parser = mavlink.MAVLink(None)
        self.peer: tuple[str, int] | None = None
        self.received: list[Any] = []
        self.drop: dict[str, int] = {}  # message type -> how many more to ignore
        self.params = [("P_A", 1.0), ("P_B", 2.0), ("P_C", 3.0), ("P_D", 4.0)]
        self.skip_list_index = 2  # PARAM_REQUEST_LIST answers leave this index out
        self.mission_count = 0
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"udpout:{LOOPBACK}:{self.sock.getsockname()[1]}"

    def send(self, msg: Any) -> None:
        if self.peer is not None:
            self.sock.sendto(msg.pack(self.mav), self.peer)

    def _param(self, i: int) -> Any:
        name, value = self.params[i]
        return self.mav.param_value_encode(name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32, len(self.params), i)

    def _run(self) -> None:
        while not self._stop:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (TimeoutError, OSError):
                if self.peer is not None:
                    self.send(self.mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 1, 4, 3))
                continue
            self.peer = addr
            for m in self.parser.parse_buffer(data) or []:
                t = m.get_type()
                self.received.append(m)
                if self.drop.get(t, 0) > 0:
                    self.drop[t] -= 1
                    continue
                if t == "COMMAND_LONG":
                    self.send(self.mav.command_ack_encode(m.command, mavlink.MAV_RESULT_ACCEPTED, 0, 0, 255, 190))
                    if m.command == mavlink.MAV_CMD_GET_HOME_POSITION:
                        self.send(self.mav.home_position_encode(470000000, 80000000, 400000, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0))
                elif t == "PARAM_REQUEST_LIST":
                    for i in range(len(self.params)):
                        if i != self.skip_list_index:
                            self.send(self._param(i))
                elif t == "PARAM_REQUEST_READ":
                    self.send(self._param(m.param_index))
                elif t == "MISSION_COUNT":
                    self.mission_count = m.count
                    self.send(self.mav.mission_request_int_encode(255, 190, 0, 0))
                elif t == "MISSION_ITEM_INT":
                    if m.seq + 1 < self.mission_count:
                        self.send(self.mav.mission_request_int_encode(255, 190, m.seq + 1, 0))
                    else:
                        self.send(self.mav.mission_ack_encode(255, 190, mavlink.MAV_MISSION_ACCEPTED, 0))

    def close(self) -> None:
        self._stop = True
        self._thread.join(timeout=2.0)
        self.sock.close()


@pytest.fixture
def lossy() -> Iterator[tuple[LossyVehicle, Vehicle]]:
    peer = LossyVehicle()
    vehicle = Vehicle(peer.url, ack_timeout_s=0.2, param_timeout_s=0.2, mission_timeout_s=0.2, connect_timeout_s=5.0)
    try:
        vehicle.connect()
        yield peer, vehicle
    finally:
        vehicle.close()
        peer.close()


def test_lost_command_is_resent_with_confirmation_plus_one(lossy: tuple[LossyVehicle, Vehicle]) -> None:
    peer, v = lossy
    peer.drop["COMMAND_LONG"] = 2
    assert v.command_long(mavlink.MAV_CMD_DO_SET_MODE, 1, 4) == mavlink.MAV_RESULT_ACCEPTED
    sent = [m for m in peer.received if m.get_type() == "COMMAND_LONG"]
    assert [m.confirmation for m in sent] == [0, 1, 2]
    peer.drop["COMMAND_LONG"] = 10
    with pytest.raises(CommandTimeout, match="after 5 tries"):
        v.command_long(mavlink.MAV_CMD_DO_SET_MODE, 1, 4)


def test_param_list_re_requests_the_missing_index(lossy: tuple[LossyVehicle, Vehicle]) -> None:
    peer, v = lossy
    assert v.list_params() == {"P_A": 1.0, "P_B": 2.0, "P_C": 3.0, "P_D": 4.0}
    reads = [m for m in peer.received if m.get_type() == "PARAM_REQUEST_READ"]
    assert [m.param_index for m in reads] == [2]


def test_mission_count_is_resent_until_the_vehicle_requests(lossy: tuple[LossyVehicle, Vehicle]) -> None:
    peer, v = lossy
    peer.drop["MISSION_COUNT"] = 2
    v.upload_mission([MissionItem.takeoff(2.0), MissionItem.land()])
    counts = [m for m in peer.received if m.get_type() == "MISSION_COUNT"]
    assert len(counts) == 3 and counts[-1].count == 3
    items = [m for m in peer.received if m.get_type() == "MISSION_ITEM_INT"]
    assert [m.seq for m in items] == [0, 1, 2]
    assert (items[0].x, items[0].y, items[0].z) == (470000000, 80000000, 400.0), "item 0 is the vehicle's home"
    peer.drop["MISSION_COUNT"] = 100
    with pytest.raises(MissionError, match="without requesting any item"):
        v.upload_mission([MissionItem.land()])


# ------------------------------------------------------------------------------ faults, end to end
@pytest.mark.slow
def test_live_sim_parameters_and_inject_failure_reach_the_real_simulator(fc: Vehicle) -> None:
    """FC and simulator processes in lockstep: a ground station's SIM_* change and a
    MAV_CMD_INJECT_FAILURE are forwarded to the simulator, which announces the fault (relayed to
    the ground), and the adaptive PID-SMC holds its altitude with the weak motor."""
    take_off(fc, 2.0)
    n = len(fc.statustexts)
    assert fc.set_param("SIM_ENGINE_FAIL", 1) == 1
    assert fc.set_param("SIM_ENGINE_MUL", 0.7) == pytest.approx(0.7)
    fc.wait_statustext("SIM: motor 1 at 70%", timeout_sim_s=5.0, since=n)
    t0 = fc.sim_time_s
    assert t0 is not None
    fc.wait_sim_time(t0 + 5.0)
    ned = fc.position_ned_m
    assert ned is not None and abs(-ned[2] - 2.0) < 0.3 and math.hypot(ned[0], ned[1]) < 0.3, ned
    n = len(fc.statustexts)
    assert fc.set_param("SIM_ENGINE_MUL", 1.0) == pytest.approx(1.0)
    fc.wait_statustext("SIM: motor 1 ok", timeout_sim_s=5.0, since=n)
    # MAV_CMD_INJECT_FAILURE: refused until SYS_FAILURE_EN = 1, then carried out by the simulator
    motor, off, ok = mavlink.FAILURE_UNIT_SYSTEM_MOTOR, mavlink.FAILURE_TYPE_OFF, mavlink.FAILURE_TYPE_OK
    assert fc.command_long(mavlink.MAV_CMD_INJECT_FAILURE, motor, off, 2) == mavlink.MAV_RESULT_DENIED
    fc.set_param("SYS_FAILURE_EN", 1)
    n = len(fc.statustexts)
    assert fc.command_long(mavlink.MAV_CMD_INJECT_FAILURE, motor, off, 2) == mavlink.MAV_RESULT_ACCEPTED
    fc.wait_statustext("SIM: motor 2", timeout_sim_s=5.0, since=n)
    assert fc.get_param("SIM_MOT_OFF") == 2
    assert fc.command_long(mavlink.MAV_CMD_INJECT_FAILURE, motor, ok, 2) == mavlink.MAV_RESULT_ACCEPTED
    assert fc.get_param("SIM_MOT_OFF") == 0
    assert fc.command_long(mavlink.MAV_CMD_INJECT_FAILURE, mavlink.FAILURE_UNIT_SENSOR_MAG, off, 0) == mavlink.MAV_RESULT_UNSUPPORTED
