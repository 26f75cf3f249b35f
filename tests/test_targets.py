"""One validation for every target source (smcpilot.limits): finite, not below ground, inside the
geofence (FENCE_ENABLE, FENCE_RADIUS, FENCE_ALT_MAX), addressed to this system and component.

The rule itself against an oracle (hypothesis), then every source on the flight controller's
ground protocol in-process (the real :class:`fc.gcs.GcsHandler` and flight core on the
rigid-body plant, messages encoded and decoded by pymavlink): LOCAL_NED and GLOBAL_INT
set-points, DO_REPOSITION, take-off, guided mission items, mission uploads, plan steps, and the
mission-file schema on the ground. Refusals are counted and said in a STATUSTEXT.
"""

from __future__ import annotations

import math
import tomllib

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc.config import FcConfig
from fc.core import FlightCore
from fc.gcs import GcsHandler
from fc.mission import MissionProtocol
from fc.params import ParamStore
from fc.streams import StreamScheduler
from fc.telemetry import snapshot
from ground.missions.schema import MissionFileError, parse_mission
from lab.runner import wire_state
from sim_bridge.plants.rigid_body import RigidBodyPlant
from smcpilot.geo import Home, ned_to_global
from smcpilot.limits import DEFAULT_FENCE, HARD_LIMITS, Fence, takeoff_refusal, target_refusal
from smcpilot.plan import PlanStep
from smcpilot.protocol import Mode
from smcpilot.vehicle import DEFAULT_VEHICLE

M = mavlink
HOME = Home()
ADDR = ("127.0.0.1", 14550)

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
anything = st.floats(allow_nan=True, allow_infinity=True)


@given(n=anything, e=anything, alt=anything, on=st.booleans(), r=st.floats(10, 10_000), a=st.floats(1, 500))
def test_rule_matches_its_oracle(n: float, e: float, alt: float, on: bool, r: float, a: float) -> None:
    fence = Fence(on, r, a)
    radius, alt_max = (r, a) if on else (HARD_LIMITS.radius_m, HARD_LIMITS.alt_max_m)
    ok = all(math.isfinite(v) for v in (n, e, alt)) and 0.0 <= alt <= alt_max and math.hypot(n, e) <= radius
    why = target_refusal(n, e, alt, fence)
    assert (why is None) == ok, (n, e, alt, fence, why)
    if why is not None:
        assert len(why) < 120 and "nan" not in why.lower()


def test_default_fence_is_on_with_ardupilot_values() -> None:
    assert DEFAULT_FENCE == Fence(True, 300.0, 100.0)
    cfg = FcConfig()
    assert cfg.fence == DEFAULT_FENCE
    store = ParamStore(cfg)
    assert (store.value("FENCE_ENABLE"), store.value("FENCE_RADIUS"), store.value("FENCE_ALT_MAX")) == (1.0, 300.0, 100.0)
    assert takeoff_refusal(1000.0) == "altitude 1000 m is above fence FENCE_ALT_MAX 100 m"
    assert takeoff_refusal(0.2) is not None and takeoff_refusal(3.0) is None


# -- every source on the ground protocol -------------------------------------------------------------
class Fc:
    """The flight core and the ground-protocol handler, in-process, on the rigid-body plant."""

    def __init__(self, config: FcConfig = FcConfig()) -> None:
        self.texts: list[str] = []
        self.store = ParamStore(config)
        mav = M.MAVLink(None)
        self.core = FlightCore(config, DEFAULT_VEHICLE, home=HOME, event=lambda sev, text: self.texts.append(text))
        self.mission = MissionProtocol(self.core.commander.mission, mav, lambda m, a: None, home=lambda: self.core.commander.home,
                                       fence=lambda: self.core.config.fence)  # fmt: skip
        self.streams = StreamScheduler(config.telemetry_rate_hz)
        self.handler = GcsHandler(
            core=self.core, mission=self.mission, params=self.store, streams=self.streams, link=None,
            event=lambda sev, text: self.texts.append(text), log=lambda line: None,
            snapshot=lambda: snapshot(self.core, time_us=self.t_us, state=self.core.state, body_rates=(0.0, 0.0, 0.0), overruns=0),
            apply_config=self.core.reconfigure, wall_s=lambda: self.wall_s,
        )  # fmt: skip
        self.plant = RigidBodyPlant(DEFAULT_VEHICLE)
        self.t_us = 0
        self.wall_s = 0.0
        self.gcs = M.MAVLink(None, srcSystem=255, srcComponent=190)
        self.run(0.01)

    def run(self, seconds: float) -> None:
        for _ in range(max(1, int(round(seconds / 0.002)))):
            s = wire_state(self.plant.observe())
            self.core.set_state(s)
            out = self.core.tick(self.t_us, s)
            self.plant.step(self.t_us * 1e-6, 0.002, out.motors, out.armed)
            self.t_us += 2000
            self.wall_s += 0.002

    def send(self, msg: mavlink.MAVLink_message) -> None:
        """Encode as a ground station would, decode as the FC's link does, hand to the handler."""
        self.wall_s += 1.1  # past the one-a-second STATUSTEXT limit per reason
        decoded = M.MAVLink(None).parse_char(msg.pack(self.gcs))
        assert decoded is not None
        self.handler.handle(decoded, ADDR)

    @property
    def target(self) -> tuple[float, float, float]:
        return self.core.flight.target

    def fly_up(self) -> None:
        c = self.core.commander
        assert c.set_mode(Mode.GUIDED) is None and c.arm() is None and c.takeoff(3.0) is None
        self.run(4.0)

    def local(self, n: float, e: float, d: float, *, component: int = 1, system: int = 1) -> None:
        self.send(self.gcs.set_position_target_local_ned_encode(0, system, component, M.MAV_FRAME_LOCAL_NED, 0b0000_1111_1111_1000, n, e, d,
                                                                0, 0, 0, 0, 0, 0, 0, 0))  # fmt: skip

    def global_int(self, lat_int: int, lon_int: int, alt: float) -> None:
        self.send(self.gcs.set_position_target_global_int_encode(0, 1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0b0000_1111_1111_1000,
                                                                 lat_int, lon_int, alt, 0, 0, 0, 0, 0, 0, 0, 0))  # fmt: skip


def _lat_lon_int(n: float, e: float) -> tuple[int, int]:
    lat, lon, _ = ned_to_global(HOME, n, e, 0.0)
    return int(round(lat * 1e7)), int(round(lon * 1e7))


@pytest.fixture(scope="module")
def flying() -> Fc:
    fc = Fc()
    fc.fly_up()
    return fc


def test_local_ned_targets_inside_the_fence_fly_the_rest_are_refused_and_counted(flying: Fc) -> None:
    fc = flying
    fc.local(5.0, 2.0, -4.0)
    assert fc.target == pytest.approx((5.0, -2.0, 4.0))  # NED -> paper frame (x north, y west, z up)
    cases = [
        ((1e30, 0.0, -3.0), "outside fence FENCE_RADIUS 300 m"),
        ((1e6, 0.0, -3.0), "outside fence FENCE_RADIUS 300 m"),
        ((0.0, 0.0, 5.0), "below ground"),
        ((0.0, 0.0, -150.0), "above fence FENCE_ALT_MAX 100 m"),
        ((math.nan, 0.0, -3.0), "not a finite number"),
    ]
    for (n, e, d), words in cases:
        before = fc.handler.rejected["setpoint_refused"]
        fc.local(n, e, d)
        assert fc.target == pytest.approx((5.0, -2.0, 4.0)), (n, e, d)  # unchanged: not flown
        assert words in fc.texts[-1] and fc.texts[-1].startswith("Set-point refused"), fc.texts[-1]
        assert fc.handler.rejected["setpoint_refused"] == before + 1


def test_set_points_for_another_component_or_system_are_not_flown(flying: Fc) -> None:
    fc = flying
    fc.local(1.0, 1.0, -3.0)
    start = fc.target
    fc.local(20.0, 0.0, -3.0, component=99)
    assert fc.target == start and fc.handler.rejected["other_component"] == 1
    assert "component 99 not flown" in fc.texts[-1]
    fc.local(20.0, 0.0, -3.0, system=7)
    assert fc.target == start and fc.handler.rejected["other_system"] >= 1


def test_global_targets_and_reposition_pass_the_same_rule(flying: Fc) -> None:
    fc = flying
    lat, lon = _lat_lon_int(10.0, 0.0)
    fc.global_int(lat, lon, 3.0)
    assert fc.target == pytest.approx((10.0, 0.0, 3.0), abs=0.02)
    fc.global_int(2**31 - 1, lon, 3.0)  # 214.7 degrees of latitude
    assert fc.target == pytest.approx((10.0, 0.0, 3.0), abs=0.02) and "latitude/longitude out of range" in fc.texts[-1]
    far_lat, far_lon = _lat_lon_int(400.0, 0.0)
    fc.global_int(far_lat, far_lon, 3.0)
    assert fc.target == pytest.approx((10.0, 0.0, 3.0), abs=0.02) and "outside fence" in fc.texts[-1]
    c = fc.core.commander
    refusal = c.reposition(far_lat * 1e-7, far_lon * 1e-7, 3.0, True, math.nan)
    assert refusal is not None and "outside fence FENCE_RADIUS" in refusal.reason
    assert c.mode == Mode.GUIDED and fc.target == pytest.approx((10.0, 0.0, 3.0), abs=0.02)


def test_fence_parameters_apply_at_once(flying: Fc) -> None:
    fc = flying
    fc.send(fc.gcs.param_set_encode(1, 1, b"FENCE_RADIUS", 50.0, M.MAV_PARAM_TYPE_REAL32))
    fc.local(60.0, 0.0, -3.0)
    assert "outside fence FENCE_RADIUS 50 m" in fc.texts[-1]
    fc.send(fc.gcs.param_set_encode(1, 1, b"FENCE_ENABLE", 0.0, M.MAV_PARAM_TYPE_INT32))
    fc.local(60.0, 0.0, -3.0)
    assert fc.target == pytest.approx((60.0, 0.0, 3.0))
    fc.local(20_000.0, 0.0, -3.0)  # the absolute limit holds with the fence off
    assert "outside the absolute limit 10000 m" in fc.texts[-1]
    fc.send(fc.gcs.param_set_encode(1, 1, b"FENCE_ENABLE", 1.0, M.MAV_PARAM_TYPE_INT32))
    fc.send(fc.gcs.param_set_encode(1, 1, b"FENCE_RADIUS", 300.0, M.MAV_PARAM_TYPE_REAL32))
    fc.local(1.0, 1.0, -3.0)


def test_takeoff_and_guided_items_and_plan_steps_use_the_rule() -> None:
    fc = Fc()
    c = fc.core.commander
    assert c.set_mode(Mode.GUIDED) is None and c.arm() is None
    refusal = c.takeoff(1000.0)
    assert refusal is not None and refusal.reason == "Takeoff refused: altitude 1000 m is above fence FENCE_ALT_MAX 100 m"
    assert len(refusal.reason) > 50  # needs STATUSTEXT chunking to arrive whole (test_statustext_chunks)
    assert c.takeoff(3.0) is None
    fc.run(3.0)
    # a guided-mode mission item (current = 2) outside the fence
    lat, lon = _lat_lon_int(500.0, 0.0)
    fc.send(fc.gcs.mission_item_int_encode(1, 1, 0, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_WAYPOINT, 2, 0,
                                           0, 0, 0, 0, lat, lon, 3.0, M.MAV_MISSION_TYPE_MISSION))  # fmt: skip
    assert "outside fence" in fc.texts[-1] and fc.handler.rejected["guided_item_refused"] == 1
    # a timed plan step below ground
    c.apply_plan_step(PlanStep(1.0, "goto", north_m=0.0, east_m=0.0, alt_m=-2.0))
    assert "below ground" in fc.texts[-1] and fc.target[2] == pytest.approx(3.0)


def test_a_mission_upload_with_an_item_outside_the_fence_is_refused_with_the_reason() -> None:
    fc = Fc()
    acks: list[int] = []
    fc.mission._send_to = lambda m, a: acks.append(m.type) if m.get_type() == "MISSION_ACK" else None
    far = _lat_lon_int(350.0, 0.0)
    near = _lat_lon_int(10.0, 0.0)
    items = [(0, M.MAV_CMD_NAV_WAYPOINT, *near, 0.0), (1, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 3.0), (2, M.MAV_CMD_NAV_WAYPOINT, *near, 3.0),
             (3, M.MAV_CMD_NAV_WAYPOINT, *far, 3.0)]  # fmt: skip
    fc.send(fc.gcs.mission_count_encode(1, 1, len(items), M.MAV_MISSION_TYPE_MISSION))
    for seq, cmd, lat, lon, alt in items:
        fc.send(fc.gcs.mission_item_int_encode(1, 1, seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, cmd, 0, 1, 0, 0, 0, math.nan,
                                               lat, lon, alt, M.MAV_MISSION_TYPE_MISSION))  # fmt: skip
    assert acks == [M.MAV_MISSION_INVALID_PARAM5_X]
    assert fc.core.commander.mission.items == []  # nothing stored
    assert "Mission item 3 refused: 350 m from home is outside fence FENCE_RADIUS 300 m" in fc.texts[-1]
    assert fc.handler.rejected["mission_fence"] == 1


def _mission(text: str):
    return parse_mission(tomllib.loads(text), source="m.toml")


def test_mission_files_share_the_limits() -> None:
    with pytest.raises(MissionFileError, match="0.5"):
        _mission('[[item]]\ntype = "takeoff"\nalt_m = 0.2\n')
    with pytest.raises(MissionFileError, match="12727.9 m from home is outside the absolute limit 10000 m"):
        _mission('[[item]]\ntype = "takeoff"\nalt_m = 3\n[[item]]\ntype = "waypoint"\nnorth_m = 9000\neast_m = 9000\nalt_m = 3\n')
    with pytest.raises(MissionFileError, match="500"):
        _mission('[[item]]\ntype = "takeoff"\nalt_m = 600\n')
    assert _mission('[[item]]\ntype = "takeoff"\nalt_m = 3\n[[item]]\ntype = "waypoint"\nnorth_m = 90\neast_m = 0\nalt_m = 3\n')
