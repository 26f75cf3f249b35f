"""The FC's ground-protocol pieces without processes: parameters, streams, mission validation, and
the commander flying modes (RTL, AUTO, ALT_HOLD, failsafes) in-process on the rigid-body plant."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc.config import FcConfig
from fc.core import FlightCore
from fc.mission import MissionItem, validate
from fc.modes import Refusal
from fc.params import PARAMS, ParamError, ParamStore, defaults_table, param_table
from fc.streams import StreamScheduler
from lab.runner import wire_state
from sim_bridge.environment import Environment, EnvironmentParams
from sim_bridge.plants.rigid_body import RigidBodyPlant
from smcpilot.geo import Home, ned_to_global
from smcpilot.protocol import Mode
from smcpilot.vehicle import DEFAULT_VEHICLE

M = mavlink
HOME = Home()


# -- parameters ------------------------------------------------------------------------------------
def test_every_parameter_round_trips_its_default_and_has_a_sane_range() -> None:
    store = ParamStore(FcConfig())
    for p in PARAMS:
        v = store.value(p.name)
        assert p.lo <= v <= p.hi, p.name
        assert len(p.name) <= 16
        store.set(p.name, v, persist=False)  # setting the default changes nothing
        assert store.value(p.name) == pytest.approx(v, rel=1e-12), p.name
    assert store.config == FcConfig()


def test_gain_parameter_changes_the_live_law_and_bad_values_are_refused() -> None:
    store = ParamStore(FcConfig())
    cfg = store.set("SMC_Z_KD", 2.0, persist=False)
    assert cfg.gains[3].kd == 2.0 and cfg.gains[0].kd == 1.0
    for bad in (0.0, -1.0, math.nan, math.inf, 1e9):
        with pytest.raises(ParamError, match="SMC_Z_KD"):
            store.set("SMC_Z_KD", bad, persist=False)
    assert store.config.gains[3].kd == 2.0  # unchanged by the refusals
    with pytest.raises(ParamError, match="whole number"):
        store.set("FS_GCS_ENABLE", 1.5, persist=False)
    with pytest.raises(ParamError, match="unknown parameter"):
        store.set("NOPE", 1.0, persist=False)
    # Cross-field validation: the projection bounds must stay ordered.
    with pytest.raises(ParamError, match="chi_hat_max must be >= chi_hat_min"):
        store.set("SMC_CHI_MIN", 50.0, persist=False)


def test_restart_parameters_wait_for_the_next_start(tmp_path: Path) -> None:
    path = tmp_path / "p.parm"
    store = ParamStore(FcConfig(), path)
    live = store.set("FC_RATE_HZ", 250.0)
    assert live.rate_hz == 500.0 and store.pending.rate_hz == 250.0
    assert store.value("FC_RATE_HZ") == 250.0  # what the next start uses
    again = ParamStore(FcConfig(), path)
    again.load()
    assert again.config.rate_hz == 250.0


def test_parameter_file_is_written_whole_and_loads_back(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "fc.parm"
    store = ParamStore(FcConfig(), path)
    store.set("SMC_R_NU", 0.7)
    store.set("ARMING_CHECK", 0)
    lines = [ln for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    assert len(lines) == len(param_table().specs) >= len(PARAMS)  # every parameter of this process (plug-in laws loaded by other tests too), one per line
    assert "ARMING_CHECK 0" in lines
    assert not list(path.parent.glob("*.tmp"))  # no temporary file left behind
    fresh = ParamStore(FcConfig(), path)
    assert fresh.load() == []
    assert fresh.config.gains[0].nu == 0.7 and fresh.config.arming_check is False


@pytest.mark.parametrize(
    ("text", "needle"),
    [("SMC_R_NU\n", "expected 'NAME VALUE'"), ("SMC_R_NU abc\n", "not a number"), ("SMC_R_DELTA 2\n", "out of range")],
)
def test_broken_parameter_file_names_the_line(tmp_path: Path, text: str, needle: str) -> None:
    path = tmp_path / "bad.parm"
    path.write_text("# comment\n" + text)
    with pytest.raises(ParamError, match=rf"bad\.parm:2: .*{needle}"):
        ParamStore(FcConfig(), path).load()


def test_unknown_parameter_in_file_is_a_warning(tmp_path: Path) -> None:
    path = tmp_path / "old.parm"
    path.write_text("RETIRED_PARAM 3\nSMC_Z_NU 0.2\n")
    store = ParamStore(FcConfig(), path)
    warnings = store.load()
    assert len(warnings) == 1 and "RETIRED_PARAM" in warnings[0]
    assert store.config.gains[3].nu == 0.2


def test_defaults_table_documents_every_parameter() -> None:
    rows = defaults_table()
    assert [r["name"] for r in rows] == [p.name for p in PARAMS]
    assert all(r["description"] and r["min"] <= r["default"] <= r["max"] for r in rows)


# -- streams ---------------------------------------------------------------------------------------
def _count(s: StreamScheduler, msg_id: int, seconds: float, dt_us: int = 2000) -> int:
    """How often ``msg_id`` is due over the next ``seconds`` of ticks (the scheduler's clock goes on)."""
    t0 = getattr(s, "_test_t_us", 0)
    t1 = t0 + int(seconds * 1e6)
    s._test_t_us = t1  # type: ignore[attr-defined]
    return sum(msg_id in s.due(t) for t in range(t0, t1, dt_us))


def test_stream_rates_follow_defaults_and_message_interval() -> None:
    s = StreamScheduler(10.0)
    assert _count(s, M.MAVLINK_MSG_ID_HEARTBEAT, 5.0) == 5
    s = StreamScheduler(10.0)
    assert _count(s, M.MAVLINK_MSG_ID_ATTITUDE, 2.0) == 20
    s = StreamScheduler(10.0)
    assert s.set_interval(M.MAVLINK_MSG_ID_ATTITUDE, 20_000)  # 50 Hz
    assert _count(s, M.MAVLINK_MSG_ID_ATTITUDE, 1.0) == 50
    assert s.set_interval(M.MAVLINK_MSG_ID_ATTITUDE, -1)  # off
    assert _count(s, M.MAVLINK_MSG_ID_ATTITUDE, 1.0) == 0
    assert s.set_interval(M.MAVLINK_MSG_ID_ATTITUDE, 0)  # back to the default
    assert _count(s, M.MAVLINK_MSG_ID_ATTITUDE, 1.0) == 10
    assert not s.set_interval(M.MAVLINK_MSG_ID_HEARTBEAT, -1)  # the heartbeat stays on
    assert not s.set_interval(M.MAVLINK_MSG_ID_RAW_IMU, 1000)  # not something we stream


def test_request_data_stream_switches_a_group() -> None:
    s = StreamScheduler(10.0)
    s.request_stream(M.MAV_DATA_STREAM_POSITION, 0, False)
    assert _count(s, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 1.0) == 0
    assert _count(s, M.MAVLINK_MSG_ID_ATTITUDE, 1.0) == 10  # other groups untouched
    s.request_stream(M.MAV_DATA_STREAM_ALL, 2, True)
    assert _count(s, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 1.0) == 2


# -- mission item validation -----------------------------------------------------------------------
def _item(seq: int = 1, command: int = M.MAV_CMD_NAV_WAYPOINT, frame: int = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, **kw: float) -> MissionItem:
    base = dict(param1=0.0, param2=0.0, param3=0.0, param4=math.nan, x=-353632610, y=1491652300, z=3.0)
    base.update(kw)
    return MissionItem(seq, frame, command, 0, 1, base["param1"], base["param2"], base["param3"], base["param4"],
                       int(base["x"]), int(base["y"]), base["z"])  # fmt: skip


@pytest.mark.parametrize(
    ("item", "code"),
    [
        (_item(), M.MAV_MISSION_ACCEPTED),
        (_item(command=M.MAV_CMD_DO_SET_SERVO), M.MAV_MISSION_UNSUPPORTED),
        (_item(frame=M.MAV_FRAME_LOCAL_NED), M.MAV_MISSION_UNSUPPORTED_FRAME),
        (_item(z=math.nan), M.MAV_MISSION_INVALID_PARAM7),
        (_item(param1=math.nan), M.MAV_MISSION_INVALID_PARAM1),
        (_item(x=95 * 10**7), M.MAV_MISSION_INVALID_PARAM5_X),
        (_item(y=-181 * 10**7), M.MAV_MISSION_INVALID_PARAM6_Y),
        (_item(command=M.MAV_CMD_DO_CHANGE_SPEED, frame=M.MAV_FRAME_MISSION, param2=math.nan), M.MAV_MISSION_INVALID_PARAM2),
        (_item(command=M.MAV_CMD_DO_CHANGE_SPEED, frame=M.MAV_FRAME_MISSION, param2=2.0), M.MAV_MISSION_ACCEPTED),
        (_item(command=M.MAV_CMD_NAV_TAKEOFF, z=0.1), M.MAV_MISSION_INVALID_PARAM7),
        (_item(command=M.MAV_CMD_NAV_RETURN_TO_LAUNCH, frame=M.MAV_FRAME_MISSION), M.MAV_MISSION_ACCEPTED),
    ],
)
def test_mission_items_are_validated_with_the_protocol_codes(item: MissionItem, code: int) -> None:
    assert validate(item) == code


# -- the commander, flying in-process ----------------------------------------------------------------
class Rig:
    """The flight core on the rigid-body plant, ticked at 500 Hz in simulated time."""

    def __init__(self, config: FcConfig = FcConfig(), env: EnvironmentParams | None = None) -> None:
        self.events: list[str] = []
        self.reached: list[int] = []
        self.core = FlightCore(
            config, DEFAULT_VEHICLE, home=HOME, event=lambda sev, text: self.events.append(text),
            item_reached=self.reached.append,
        )  # fmt: skip
        self.flight = self.core.flight
        self.commander = self.core.commander
        self.plant = RigidBodyPlant(DEFAULT_VEHICLE, Environment(env) if env else None)
        self.t_us = 0
        self.wall_s = 0.0
        self.observe()

    def observe(self):
        st = wire_state(self.plant.observe())
        self.core.set_state(st)
        return st

    @property
    def t_s(self) -> float:
        return self.t_us * 1e-6

    def run(self, seconds: float, gcs_heartbeats: bool = False) -> None:
        dt = 0.002
        for _ in range(int(round(seconds / dt))):
            st = self.observe()
            if gcs_heartbeats and int(self.wall_s * 500) % 500 == 0:
                self.core.on_gcs_heartbeat(self.wall_s)
            out = self.core.tick(self.t_us, st, wall_s=self.wall_s)
            self.plant.step(self.t_s, dt, out.motors, out.armed)
            self.t_us += 2000
            self.wall_s += dt

    @property
    def pos(self) -> tuple[float, float, float]:
        o = self.plant.truth()
        return o.position_m

    def takeoff(self, alt: float = 3.0) -> None:
        c = self.commander
        assert c.set_mode(Mode.GUIDED) is None  # None: accepted
        assert c.arm() is None
        assert c.takeoff(alt) is None
        self.run(8.0)
        assert self.pos[2] == pytest.approx(alt, abs=0.05)


def test_arming_checks_and_takeoff_preconditions() -> None:
    rig = Rig()
    c = rig.commander
    refusal = c.takeoff(3.0)
    assert isinstance(refusal, Refusal) and refusal.code == M.MAV_RESULT_DENIED and "arm first" in refusal.reason
    c.set_mode(Mode.RTL)
    refusal = c.arm()
    assert isinstance(refusal, Refusal) and refusal.code == M.MAV_RESULT_DENIED and "RTL" in refusal.reason
    c.set_mode(Mode.AUTO)  # refused: no mission
    assert c.mode == Mode.RTL
    c.set_mode(Mode.GUIDED)
    c.state_fresh = False
    assert "stale" in c.arm().reason
    c.state_fresh = True
    assert c.arm() is None
    assert c.takeoff(math.nan).code == M.MAV_RESULT_DENIED
    assert c.takeoff(1000.0).code == M.MAV_RESULT_DENIED


def test_disarm_delay_disarms_an_idle_armed_vehicle() -> None:
    rig = Rig(FcConfig(disarm_delay_s=2.0))
    rig.commander.arm()
    rig.run(1.5)
    assert rig.flight.armed
    rig.run(1.0)
    assert not rig.flight.armed and "Disarming: no take-off" in rig.events


def test_air_disarm_needs_force_and_rtl_comes_home_and_lands() -> None:
    rig = Rig(FcConfig(rtl_alt_m=5.0))
    rig.takeoff(3.0)
    c = rig.commander
    assert c.goto_local(4.0, 3.0, 3.0, None) is None
    rig.run(10.0)
    assert c.disarm().code == M.MAV_RESULT_DENIED
    assert c.rtl() is None
    max_z = 0.0
    for _ in range(40):
        rig.run(0.5)
        max_z = max(max_z, rig.pos[2])
        if not rig.flight.armed:
            break
    assert not rig.flight.armed, "RTL must land and disarm"
    assert max_z == pytest.approx(5.0, abs=0.15)  # climbed to RTL_ALT_M first
    assert math.hypot(rig.pos[0], rig.pos[1]) < 0.3  # at home
    assert rig.pos[2] < 0.05


def test_auto_flies_the_mission_and_reports_each_item() -> None:
    rig = Rig()
    c = rig.commander

    def global_item(seq: int, command: int, n: float, e: float, alt: float, hold: float = 0.0) -> MissionItem:
        lat, lon, _ = ned_to_global(HOME, n, e, 0.0)
        return _item(seq, command, param1=hold, x=round(lat * 1e7), y=round(lon * 1e7), z=alt)

    c.mission.items = [
        global_item(0, M.MAV_CMD_NAV_WAYPOINT, 0.0, 0.0, 0.0),  # home
        global_item(1, M.MAV_CMD_NAV_TAKEOFF, 0.0, 0.0, 2.5),
        _item(2, M.MAV_CMD_DO_CHANGE_SPEED, M.MAV_FRAME_MISSION, param2=1.0),
        global_item(3, M.MAV_CMD_NAV_WAYPOINT, 3.0, 0.0, 2.5, hold=1.0),
        global_item(4, M.MAV_CMD_NAV_WAYPOINT, 3.0, 3.0, 2.5),
        _item(5, M.MAV_CMD_NAV_LAND, x=0, y=0, z=0.0),
    ]
    assert c.set_mode(Mode.AUTO) is None
    assert c.arm() is None
    for _ in range(120):
        rig.run(0.5)
        if not rig.flight.armed:
            break
    assert rig.reached == [1, 2, 3, 4, 5]  # MISSION_ITEM_REACHED for each item, the landing on touchdown
    assert c.mission.current == 5  # MISSION_CURRENT stays on the last item
    assert not rig.flight.armed and c.mission_complete
    n, e = rig.pos[0], -rig.pos[1]  # landed "here": where item 4 was reached (within WP_RADIUS_M)
    assert math.hypot(n - 3.0, e - 3.0) < FcConfig().wp_radius_m + 0.05


def test_alt_hold_holds_altitude_but_not_position_in_wind() -> None:
    rig = Rig(env=EnvironmentParams(wind_force_n=(0.3, 0.0, 0.0)))
    rig.takeoff(3.0)
    x0 = rig.pos[0]
    assert rig.commander.set_mode(Mode.ALT_HOLD) is None
    rig.run(4.0)
    assert rig.pos[2] == pytest.approx(3.0, abs=0.05)
    assert rig.pos[0] - x0 > 0.5  # drifts downwind: no position hold in ALT_HOLD
    rig.commander.set_mode(Mode.LOITER)  # holds where it is from now on
    here = rig.pos[0]
    rig.run(6.0)
    assert rig.pos[0] == pytest.approx(here, abs=0.6)


def test_gcs_loss_failsafe_after_a_station_was_heard() -> None:
    rig = Rig(FcConfig(fs_gcs_enable=1, fs_gcs_timeout_s=2.0))
    c = rig.commander
    c.set_mode(Mode.GUIDED)
    c.arm()
    c.takeoff(3.0)
    rig.run(6.0)  # flying, but no ground station was ever heard: no failsafe
    assert c.mode == Mode.GUIDED
    rig.run(2.0, gcs_heartbeats=True)
    assert c.mode == Mode.GUIDED
    rig.run(2.5)  # the station goes quiet for longer than FS_GCS_TIMEOUT
    assert c.mode == Mode.RTL and any("GCS lost" in e for e in rig.events)


def test_gcs_heartbeats_keep_the_failsafe_away() -> None:
    rig = Rig(FcConfig(fs_gcs_enable=2, fs_gcs_timeout_s=2.0))
    c = rig.commander
    c.on_gcs_heartbeat(0.0)
    assert c.set_mode(Mode.GUIDED) is None and c.arm() is None
    c.takeoff(3.0)
    rig.run(10.0, gcs_heartbeats=True)
    assert c.mode == Mode.GUIDED and rig.flight.armed
    rig.run(3.0)  # heartbeats stop
    assert c.mode == Mode.LAND
