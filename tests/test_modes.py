"""The flight modes one class each (fc.modes), the inbound adapter (fc.inbound), refusals as a
domain type and their mapping to COMMAND_ACK at the ground edge (fc.gcs), and telemetry built
from a frozen snapshot (fc.telemetry). In-process, no sockets; paper frame (x north, y west, z up)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc import inbound, telemetry
from fc.config import FcConfig
from fc.core import FlightCore
from fc.estimate import HoldPoint
from fc.flight import FlightControl, VehicleState
from fc.gcs import GcsHandler
from fc.mission import MissionItem, MissionProtocol, MissionStore
from fc.modes import (
    AltHoldMode,
    AutoMode,
    AutoPhase,
    FlightMode,
    GuidedMode,
    LandMode,
    LoiterMode,
    Refusal,
    RtlMode,
    RtlPhase,
    build_modes,
)
from fc.params import ParamStore
from fc.streams import StreamScheduler
from smcpilot.frames import euler_flu_to_frd, nwu_to_ned, wrap_pi
from smcpilot.geo import Home, ned_to_global
from smcpilot.plan import PlanStep
from smcpilot.protocol import ARMABLE_MODES, FORCE_ARM_MAGIC, Mode
from smcpilot.vehicle import DEFAULT_VEHICLE

M = mavlink
HOME = Home()
FAR_HOME = Home(47.397742, 8.545594, 488.0)
_coord = st.floats(-2000.0, 2000.0, allow_nan=False)
_yaw = st.floats(-3.0 * math.pi, 3.0 * math.pi, allow_nan=False)


def _state(x: float = 0.0, y: float = 0.0, z: float = 0.0, vz: float = 0.0, psi: float = 0.0) -> VehicleState:
    return VehicleState(x, y, z, 0.0, 0.0, vz, 0.0, 0.0, psi, 0.0, 0.0, 0.0)


def _item(seq: int, command: int, *, frame: int = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, n: float = 0.0, e: float = 0.0,
          alt: float = 3.0, p1: float = 0.0, p2: float = 0.0, p4: float = math.nan, here: bool = False) -> MissionItem:  # fmt: skip
    if here:
        x = y = 0
    else:
        lat, lon, _ = ned_to_global(HOME, n, e, 0.0)
        x, y = round(lat * 1e7), round(lon * 1e7)
    return MissionItem(seq, frame, command, 0, 1, p1, p2, 0.0, p4, x, y, alt)


# -- the inbound adapter ---------------------------------------------------------------------------
def _angle_close(a: float, b: float) -> bool:
    return abs(wrap_pi(a - b)) < 1e-12


@settings(max_examples=60, deadline=None)
@given(_coord, _coord, _coord, _yaw)
def test_local_ned_target_converts_and_converts_back(n: float, e: float, d: float, yaw_frd: float) -> None:
    t = inbound.local_ned_target(n, e, d, yaw_frd)
    assert (t.x_m, t.y_m, t.z_m) == (n, -e, -d)  # x north, y west, z up
    assert nwu_to_ned((t.x_m, t.y_m, t.z_m)) == (n, e, d)
    assert _angle_close(euler_flu_to_frd(0.0, 0.0, t.yaw_rad)[2], yaw_frd)
    assert inbound.local_ned_target(n, e, d, None).yaw_rad is None


def test_frd_and_compass_yaw_become_counter_clockwise_flu_yaw() -> None:
    assert inbound.yaw_of_frd(math.pi / 2) == pytest.approx(-math.pi / 2)  # east: a quarter turn clockwise
    assert inbound.yaw_of_compass_deg(90.0) == pytest.approx(-math.pi / 2)
    assert inbound.yaw_of_compass_deg(-90.0) == pytest.approx(math.pi / 2)  # west
    assert inbound.yaw_of_compass_deg(0.0) == 0.0


@settings(max_examples=60, deadline=None)
@given(st.floats(-1500.0, 1500.0), st.floats(-1500.0, 1500.0), st.floats(-50.0, 300.0), st.booleans(), st.sampled_from([HOME, FAR_HOME]))
def test_global_target_round_trips_through_geo(n: float, e: float, up: float, relative: bool, home: Home) -> None:
    lat, lon, alt_amsl = ned_to_global(home, n, e, -up)
    alt = alt_amsl - home.alt_m if relative else alt_amsl
    t = inbound.global_target(home, lat, lon, alt, relative, None)
    assert t.x_m == pytest.approx(n, abs=1e-6) and t.y_m == pytest.approx(-e, abs=1e-6)
    assert t.z_m == pytest.approx(up, abs=1e-9)
    back = ned_to_global(home, *nwu_to_ned((t.x_m, t.y_m, t.z_m)))
    assert back[0] == pytest.approx(lat, abs=1e-12) and back[1] == pytest.approx(lon, abs=1e-12)
    assert back[2] == pytest.approx(alt_amsl, abs=1e-9)
    assert t.yaw_rad is None
    assert inbound.global_target(home, lat, lon, alt, relative, math.nan).yaw_rad is None  # NaN: keep the heading
    assert inbound.global_target(home, lat, lon, alt, relative, 0.5).yaw_rad == pytest.approx(-0.5)


def test_reposition_target_takes_a_compass_heading_in_degrees() -> None:
    lat, lon, _ = ned_to_global(HOME, 10.0, -5.0, 0.0)
    t = inbound.reposition_target(HOME, lat, lon, 7.0, True, 45.0)
    assert (t.x_m, t.y_m, t.z_m) == pytest.approx((10.0, 5.0, 7.0), abs=1e-6)
    assert math.degrees(euler_flu_to_frd(0.0, 0.0, t.yaw_rad)[2]) == pytest.approx(45.0)
    assert inbound.reposition_target(HOME, lat, lon, 7.0, True, math.nan).yaw_rad is None
    amsl = inbound.reposition_target(HOME, lat, lon, HOME.alt_m + 7.0, False, math.nan)
    assert amsl.z_m == pytest.approx(7.0, abs=1e-9)


def test_plan_steps_are_north_east_altitude_with_a_compass_heading() -> None:
    t = inbound.plan_step_target(PlanStep(10.0, "goto", north_m=4.0, east_m=-3.0, alt_m=3.0, yaw_deg=170.0))
    assert (t.x_m, t.y_m, t.z_m) == (4.0, 3.0, 3.0)
    assert t.yaw_rad == pytest.approx(math.radians(-170.0))
    assert nwu_to_ned((t.x_m, t.y_m, t.z_m)) == (4.0, -3.0, -3.0)
    assert inbound.plan_step_target(PlanStep(0.0, "goto", 1.0, 2.0, 3.0)).yaw_rad is None
    assert inbound.plan_step_yaw(PlanStep(0.0, "takeoff", alt_m=3.0)) is None


def test_mission_items_convert_in_their_frame() -> None:
    rel = _item(1, M.MAV_CMD_NAV_WAYPOINT, n=3.0, e=-2.0, alt=2.5, p4=90.0)
    assert inbound.mission_item_position(HOME, rel) == pytest.approx((3.0, 2.0, 2.5), abs=0.02)  # 1e-7 deg grid
    assert inbound.mission_item_yaw(rel) == pytest.approx(-math.pi / 2)
    amsl = _item(1, M.MAV_CMD_NAV_TAKEOFF, frame=M.MAV_FRAME_GLOBAL_INT, alt=HOME.alt_m + 4.0)
    assert inbound.mission_item_altitude(HOME, amsl) == pytest.approx(4.0)
    assert inbound.mission_item_altitude(HOME, _item(1, M.MAV_CMD_NAV_TAKEOFF, alt=4.0)) == 4.0
    # param4 is a heading only for waypoints; NaN keeps the heading
    assert inbound.mission_item_yaw(_item(1, M.MAV_CMD_NAV_LOITER_TIME, p4=90.0)) is None
    assert inbound.mission_item_yaw(_item(1, M.MAV_CMD_NAV_WAYPOINT)) is None


# -- the mode classes ------------------------------------------------------------------------------
class Host:
    """A vehicle for the modes alone: a real pipeline and mission store, recorded events."""

    def __init__(self, config: FcConfig = FcConfig(), items: list[MissionItem] | None = None) -> None:
        self.flight = FlightControl(config, DEFAULT_VEHICLE)
        self.home = HOME
        self.mission = MissionStore()
        self.mission.items = list(items or [])
        self.mission.current = 1 if len(self.mission.items) > 1 else 0
        self.in_air = True
        self.events: list[str] = []
        self.reached: list[int] = []

    @property
    def config(self) -> FcConfig:
        return self.flight.config

    def flying(self) -> bool:
        return self.flight.armed and self.in_air

    def say(self, text: str, severity: int = M.MAV_SEVERITY_INFO) -> None:
        self.events.append(text)

    def item_reached(self, seq: int) -> None:
        self.reached.append(seq)

    def here(self, st: VehicleState) -> HoldPoint:
        return HoldPoint(st.x_m, st.y_m, st.z_m, st.psi_rad)


def test_one_object_per_flown_mode_and_the_contracts_agree() -> None:
    modes = build_modes(Host())
    assert set(modes) == set(Mode)
    kinds = {Mode.GUIDED: GuidedMode, Mode.LOITER: LoiterMode, Mode.ALT_HOLD: AltHoldMode, Mode.LAND: LandMode,
             Mode.RTL: RtlMode, Mode.AUTO: AutoMode}  # fmt: skip
    for number, mode in modes.items():
        assert isinstance(mode, kinds[number]) and isinstance(mode, FlightMode)
        assert mode.number == number and mode.name == number.name
        assert mode.allows_arming == (number in ARMABLE_MODES)
        assert mode.position_hold == (number != Mode.ALT_HOLD)
    assert modes[Mode.AUTO]._rtl is modes[Mode.RTL]  # AUTO flies RTL items with the RTL object
    assert modes[Mode.RTL].prearm_failure() == "PreArm: cannot arm in RTL"
    assert modes[Mode.LAND].prearm_failure() == "PreArm: cannot arm in LAND"
    assert modes[Mode.GUIDED].prearm_failure() is None
    assert modes[Mode.LAND].is_landing and not modes[Mode.GUIDED].is_landing


def test_hold_modes_hold_where_they_are_entered() -> None:
    h = Host()
    f = h.flight
    f.arm(_state(1.0, 2.0, 0.0))
    f.set_target(9.0, 9.0, 3.0)
    LoiterMode(h).enter(Mode.GUIDED, _state(4.0, -1.0, 2.5))
    assert f.target == (4.0, -1.0, 2.5)
    GuidedMode(h).enter(Mode.GUIDED, _state(7.0, 7.0, 7.0))  # same mode: the set-point stays
    assert f.target == (4.0, -1.0, 2.5)
    h.in_air = False  # on the ground: the altitude set-point is kept
    AltHoldMode(h).enter(Mode.LOITER, _state(5.0, 5.0, 0.0))
    assert f.target == (5.0, 5.0, 2.5)


def test_land_descends_where_it_is_when_armed() -> None:
    h = Host()
    land = LandMode(h)
    land.enter(Mode.GUIDED, _state(1.0, 1.0, 3.0))
    assert not h.flight.landing  # disarmed: nothing to do
    h.flight.arm(_state())
    land.enter(Mode.GUIDED, _state(1.0, -2.0, 3.0))
    assert h.flight.landing and h.flight.target == (1.0, -2.0, 3.0)


def test_rtl_climbs_flies_home_and_lands_phase_by_phase() -> None:
    h = Host(FcConfig(rtl_alt_m=5.0))
    f = h.flight
    f.arm(_state())
    rtl = RtlMode(h)
    rtl.enter(Mode.GUIDED, _state(6.0, 8.0, 3.0))
    assert rtl.phase is RtlPhase.START and not rtl.is_landing
    rtl.run(_state(6.0, 8.0, 3.0), 0.0, 0.002)
    assert rtl.phase is RtlPhase.CLIMB and f.target == (6.0, 8.0, 5.0)  # max(altitude, RTL_ALT_M) where it is
    rtl.run(_state(6.0, 8.0, 4.5), 1.0, 0.002)
    assert rtl.phase is RtlPhase.CLIMB  # not within 0.3 m yet
    rtl.run(_state(6.0, 8.0, 4.8), 2.0, 0.002)
    assert rtl.phase is RtlPhase.HOME and f.target == (0.0, 0.0, 5.0)
    rtl.run(_state(0.4, 0.4, 5.0), 3.0, 0.002)
    assert rtl.phase is RtlPhase.HOME and not f.landing  # 0.57 m from home: not yet
    rtl.run(_state(0.3, 0.3, 5.0), 4.0, 0.002)
    assert rtl.phase is RtlPhase.LAND and f.landing and rtl.is_landing
    assert rtl.on_touchdown() is Mode.GUIDED and rtl.phase is RtlPhase.START
    # Higher than RTL_ALT_M: it returns at its altitude.
    rtl.run(_state(1.0, 1.0, 8.0), 5.0, 0.002)
    assert f.target == (1.0, 1.0, 8.0)
    rtl.exit(Mode.LOITER)
    assert rtl.phase is RtlPhase.START


def test_auto_flies_items_through_explicit_phases() -> None:
    items = [
        _item(0, M.MAV_CMD_NAV_WAYPOINT, alt=0.0),
        _item(1, M.MAV_CMD_NAV_TAKEOFF, alt=2.0),
        _item(2, M.MAV_CMD_DO_CHANGE_SPEED, frame=M.MAV_FRAME_MISSION, p2=1.5),
        _item(3, M.MAV_CMD_NAV_WAYPOINT, n=3.0, alt=2.0, p1=1.0),
        _item(4, M.MAV_CMD_NAV_RETURN_TO_LAUNCH, frame=M.MAV_FRAME_MISSION),
    ]
    h = Host(FcConfig(rtl_alt_m=4.0), items)
    f = h.flight
    rtl = RtlMode(h)
    auto = AutoMode(h, rtl)
    assert auto.refuse_entry() is None and auto.prearm_failure() is None
    f.arm(_state())
    auto.enter(Mode.GUIDED, _state())
    auto.run(_state(), 0.0, 0.002)
    assert auto.phase is AutoPhase.FLY and f.target == (0.0, 0.0, 2.0)
    auto.run(_state(z=1.8), 1.0, 0.002)  # take-off done within 0.3 m
    assert h.reached == [1] and h.mission.current == 2
    auto.run(_state(z=2.0), 1.1, 0.002)  # DO_CHANGE_SPEED is done at once
    assert f.speed_xy_mps == 1.5 and h.reached == [1, 2] and h.mission.current == 3
    auto.run(_state(z=2.0), 1.2, 0.002)
    assert auto.phase is AutoPhase.FLY and f.target == pytest.approx((3.0, 0.0, 2.0), abs=0.02)
    auto.run(_state(2.6, 0.0, 2.0), 1.9, 0.002)
    assert auto.phase is AutoPhase.FLY  # 0.4 m away: WP_RADIUS_M is 0.3 m
    auto.run(_state(2.8, 0.0, 2.0), 2.0, 0.002)  # within WP_RADIUS_M: hold param1 = 1 s
    assert auto.phase is AutoPhase.HOLD
    auto.run(_state(2.9, 0.0, 2.0), 2.9, 0.002)
    assert auto.phase is AutoPhase.HOLD and h.reached == [1, 2]
    auto.run(_state(3.0, 0.0, 2.0), 3.0, 0.002)
    assert h.reached == [1, 2, 3] and h.mission.current == 4
    auto.run(_state(3.0, 0.0, 2.0), 3.1, 0.002)  # the RTL item: the RTL object takes over
    assert auto.phase is AutoPhase.RTL and rtl.phase is RtlPhase.START
    auto.run(_state(3.0, 0.0, 2.0), 3.2, 0.002)
    assert rtl.phase is RtlPhase.CLIMB and f.target == (3.0, 0.0, 4.0)
    auto.restart_item()  # a set-current does not interrupt a return in progress
    auto.run(_state(3.0, 0.0, 3.9), 4.0, 0.002)
    assert rtl.phase is RtlPhase.HOME and auto.phase is AutoPhase.RTL
    auto.run(_state(0.1, 0.0, 4.0), 5.0, 0.002)
    assert auto.is_landing and f.landing
    assert auto.on_touchdown() is None  # AUTO stays AUTO; the landing item is reached on touchdown
    assert h.reached == [1, 2, 3, 4] and auto.complete and h.events == ["Mission complete"]
    assert auto.phase is not AutoPhase.RTL and rtl.phase is RtlPhase.START
    auto.exit(Mode.GUIDED)
    assert f.speed_xy_mps is None


def test_auto_needs_a_mission() -> None:
    auto = AutoMode(Host(), RtlMode(Host()))
    assert auto.refuse_entry() == Refusal("AUTO: no mission loaded", M.MAV_RESULT_DENIED)
    assert auto.prearm_failure() == "PreArm: AUTO without a mission"


def test_auto_land_item_descends_where_the_target_is_reached() -> None:
    items = [_item(0, M.MAV_CMD_NAV_WAYPOINT, alt=0.0), _item(1, M.MAV_CMD_NAV_LAND, here=True, alt=0.0)]
    h = Host(items=items)
    auto = AutoMode(h, RtlMode(h))
    h.flight.arm(_state(2.0, 1.0, 0.0))
    auto.run(_state(2.0, 1.0, 3.0), 0.0, 0.002)  # 0, 0: here, at the altitude it is at: reached at once
    assert h.flight.target == (2.0, 1.0, 3.0)
    assert auto.phase is AutoPhase.LANDING and h.flight.landing and auto.is_landing
    assert h.reached == []  # reached on touchdown
    auto.on_touchdown()
    assert h.reached == [1] and auto.complete


# -- the commander: refusals are values --------------------------------------------------------------
def _core(**cfg) -> FlightCore:
    core = FlightCore(FcConfig(**cfg), DEFAULT_VEHICLE, home=HOME)
    core.set_state(_state())
    return core


def test_commander_refusals_are_domain_values() -> None:
    c = _core().commander
    assert c.set_mode(Mode.LOITER) is None and c.mode == Mode.LOITER and c.current is c.modes[Mode.LOITER]
    refusal = c.set_mode(0)
    assert refusal == Refusal("Mode STABILIZE not supported") and refusal.code == M.MAV_RESULT_DENIED
    assert c.set_mode(Mode.AUTO) == Refusal("AUTO: no mission loaded")
    assert c.mode == Mode.LOITER
    assert c.takeoff(3.0) == Refusal("Takeoff: needs GUIDED, in LOITER")
    assert c.rtl() == Refusal("RTL: not armed")
    assert c.mission_start(0) == Refusal("Mission start: no mission loaded")
    assert c.set_mode(Mode.RTL) is None and c.arm() == Refusal("PreArm: cannot arm in RTL")
    assert c.arm(force=True) is None and c.flight.armed


def test_commander_switches_modes_with_exit_and_enter() -> None:
    core = _core()
    c = core.commander
    events: list[str] = []
    c._event = lambda sev, text: events.append(text)
    c.arm()
    assert c.set_mode(Mode.ALT_HOLD) is None and not c.flight.position_hold
    assert c.land() is None and c.flight.position_hold and c.flight.landing
    assert events == ["Armed", "Mode ALT_HOLD", "Mode LAND"]
    assert c.set_mode(Mode.LAND) is None and events[-1] == "Mode LAND" and len(events) == 3  # no news: same mode


# -- the ground edge: refusals become COMMAND_ACK + STATUSTEXT, telemetry from a snapshot ------------
class FakeLink:
    def __init__(self) -> None:
        self.mav = M.MAVLink(None, srcSystem=1, srcComponent=1)
        self.to: list[tuple[object, tuple[str, int]]] = []
        self.all: list[object] = []

    def send(self, msg) -> None:
        self.all.append(msg)

    def send_many(self, msgs, *, others_limit=None) -> int:
        self.all.extend(msgs)
        return 0

    def send_to(self, msg, addr) -> None:
        self.to.append((msg, addr))

    def send_many_to(self, msgs, addr) -> None:
        self.to.extend((m, addr) for m in msgs)


def _handler(core: FlightCore):
    link = FakeLink()
    events: list[tuple[int, str]] = []
    configs: list[FcConfig] = []
    params = ParamStore(core.config)
    streams = StreamScheduler(core.config.telemetry_rate_hz)

    def snap() -> telemetry.TelemetrySnapshot:
        return telemetry.snapshot(core, time_us=1_234_000, state=core.state, body_rates=(0.0, 0.0, 0.0), overruns=7)

    def apply(cfg: FcConfig) -> None:
        configs.append(cfg)
        core.reconfigure(cfg)

    mission = MissionProtocol(core.commander.mission, link.mav, link.send_to, home=lambda: core.commander.home,
                              fence=lambda: core.config.fence)  # fmt: skip
    h = GcsHandler(core=core, mission=mission, params=params, streams=streams, link=link,
                   event=lambda sev, text: events.append((sev, text)), log=lambda line: None, snapshot=snap,
                   apply_config=apply, wall_s=lambda: 0.0)  # fmt: skip
    return h, link, events, configs


def _command(h: GcsHandler, command: int, *params: float) -> None:
    p = list(params) + [0.0] * (7 - len(params))
    msg = M.MAVLink_command_long_message(1, 1, command, 0, *p)
    msg._header = M.MAVLink_header(msg.id, srcSystem=255, srcComponent=190)  # as if received
    h.handle(msg, ("127.0.0.1", 14550))


def test_gcs_handler_maps_refusals_to_command_ack_and_statustext() -> None:
    core = _core()
    h, link, events, _ = _handler(core)
    _command(h, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0)
    ack, addr = link.to[-1]
    assert ack.get_type() == "COMMAND_ACK" and ack.result == M.MAV_RESULT_DENIED and addr == ("127.0.0.1", 14550)
    assert events[-1] == (M.MAV_SEVERITY_WARNING, "Takeoff: arm first")
    _command(h, M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, FORCE_ARM_MAGIC)
    assert link.to[-1][0].result == M.MAV_RESULT_ACCEPTED and core.flight.armed
    n = len(events)
    _command(h, 31999)  # not a command we know: UNSUPPORTED, no STATUSTEXT
    assert link.to[-1][0].result == M.MAV_RESULT_UNSUPPORTED and len(events) == n
    assert h.rejected["unsupported_command"] == 1


def test_parameter_changes_reach_the_core_through_the_one_listener() -> None:
    core = _core()
    h, link, _events, configs = _handler(core)
    msg = M.MAVLink_param_set_message(1, 1, b"RTL_ALT_M", 12.0, M.MAV_PARAM_TYPE_REAL32)
    msg._header = M.MAVLink_header(msg.id, srcSystem=255, srcComponent=190)
    h.params.path = None
    h.handle(msg, ("127.0.0.1", 14550))
    assert len(configs) == 1 and configs[0].rtl_alt_m == 12.0 and core.config.rtl_alt_m == 12.0
    assert link.all[-1].get_type() == "PARAM_VALUE" and link.all[-1].param_value == 12.0


def test_telemetry_is_built_from_a_frozen_snapshot() -> None:
    core = _core()
    core.commander.arm()
    core.flight.set_target(1.0, 2.0, 3.0, 0.25)
    snap = telemetry.snapshot(core, time_us=5_000_000, state=_state(4.0, -3.0, 2.0, psi=0.5), body_rates=(0.0, 0.0, 0.0), overruns=2)
    with pytest.raises(AttributeError):
        snap.armed = False  # type: ignore[misc]
    mav = M.MAVLink(None)
    (hb,) = telemetry.build(M.MAVLINK_MSG_ID_HEARTBEAT, snap, mav)
    assert hb.custom_mode == Mode.GUIDED and hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    (pos,) = telemetry.build(M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, snap, mav)
    assert (pos.x, pos.y, pos.z) == (4.0, 3.0, -2.0) and pos.time_boot_ms == 5000
    (tgt,) = telemetry.build(M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED, snap, mav)
    assert (tgt.x, tgt.y, tgt.z) == (1.0, -2.0, -3.0) and tgt.yaw == pytest.approx(-0.25)
    (ovr,) = telemetry.build(M.MAVLINK_MSG_ID_NAMED_VALUE_INT, snap, mav)
    assert ovr.value == 2
    (gp,) = telemetry.build(M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, snap, mav)
    lat, lon, _ = ned_to_global(HOME, 4.0, 3.0, -2.0)
    assert gp.lat == round(lat * 1e7) and gp.lon == round(lon * 1e7) and gp.relative_alt == 2000
    assert gp.hdg == round(math.degrees(-0.5) % 360.0 * 100)
    assert telemetry.build(M.MAVLINK_MSG_ID_RAW_IMU, snap, mav) == []
    none = snap._replace(state=None, armed=False)
    assert telemetry.build(M.MAVLINK_MSG_ID_ATTITUDE, none, mav) == []
    assert telemetry.build(M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED, none, mav) == []
    assert len(telemetry.build(M.MAVLINK_MSG_ID_HOME_POSITION, none, mav)) == 1


def test_auto_hands_a_return_in_progress_to_rtl_mode_only() -> None:
    items = [_item(0, M.MAV_CMD_NAV_WAYPOINT, alt=0.0), _item(1, M.MAV_CMD_NAV_RETURN_TO_LAUNCH, frame=M.MAV_FRAME_MISSION)]
    for to, kept in ((Mode.RTL, True), (Mode.GUIDED, False), (Mode.LAND, False)):
        h = Host(FcConfig(rtl_alt_m=4.0), items)
        rtl = RtlMode(h)
        auto = AutoMode(h, rtl)
        h.flight.arm(_state())
        auto.run(_state(2.0, 0.0, 2.0), 0.0, 0.002)
        auto.run(_state(2.0, 0.0, 2.0), 0.1, 0.002)
        assert auto.phase is AutoPhase.RTL and rtl.phase is RtlPhase.CLIMB
        auto.exit(to)
        assert auto.phase is not AutoPhase.RTL
        assert (rtl.phase is RtlPhase.CLIMB) == kept, to


def test_a_parameter_list_goes_out_a_chunk_a_tick_and_at_most_four_lists_at_once() -> None:
    from fc.gcs import PARAM_LIST_CHUNK, PARAM_LISTS_AT_ONCE
    from fc.params import param_table

    h, link, _, _ = _handler(_core())
    n = param_table().count

    def request(addr: tuple[str, int]) -> None:
        msg = M.MAVLink_param_request_list_message(1, 1)
        msg._header = M.MAVLink_header(msg.id, srcSystem=255, srcComponent=190)
        h.handle(msg, addr)

    a = ("127.0.0.1", 14550)
    request(a)
    assert link.to == []  # nothing at once: the list goes out with the ticks
    sent_per_tick = []
    for k in range(20):
        before = len(link.to)
        h.on_tick(k * 2000)
        sent_per_tick.append(len(link.to) - before)
    assert max(sent_per_tick) == PARAM_LIST_CHUNK and sum(sent_per_tick) == n
    assert sorted(m.param_index for m, addr in link.to) == list(range(n)) and {addr for _, addr in link.to} == {a}
    # a repeated request starts its list again; a fifth station's request drops the oldest list
    link.to.clear()
    stations = [("127.0.0.1", 20000 + i) for i in range(PARAM_LISTS_AT_ONCE + 1)]
    for s in stations:
        request(s)
    assert h.rejected["param_list_dropped"] == 1
    h.on_tick(0)
    assert {addr for _, addr in link.to} == set(stations[1:]) and len(link.to) == PARAM_LISTS_AT_ONCE * PARAM_LIST_CHUNK
    # between ticks, with no deadline waiting, the rest goes at once
    h.send_param_lists(all_now=True)
    for s in stations[1:]:
        assert sorted(m.param_index for m, addr in link.to if addr == s) == list(range(n))
