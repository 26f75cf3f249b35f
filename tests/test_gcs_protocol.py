"""The FC's ground-station protocol (docs/gcs-protocol.md), tested as an outside ground station.

Every test talks to the real flight-controller process over UDP on 127.0.0.1 with raw pymavlink
(``mavutil``; see tests/gcs_helpers.py) — not through the project's own client — in lockstep SITL
capped at a few times real time where a ground station's real-time pacing matters (GCS timeouts,
heartbeats, retries run on the wall clock; flight runs on simulated time). Wall-clock limits only
turn hangs into failures; flight waits are bounded in simulated seconds.

Tests of behaviour the FC gets wrong are marked ``xfail(strict=True, reason="BUG ...")``: they
pass as soon as the FC is fixed, and then fail until the mark is removed.
"""

from __future__ import annotations

import contextlib
import math
import random
import socket
import struct
import threading
import time
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path

import pytest
from gcs_helpers import (
    FC_COMPID,
    FC_SYSID,
    GCS_COMPID,
    GCS_SYSID,
    HOME_ALT,
    HOME_LAT,
    HOME_LON,
    LOOPBACK,
    Gcs,
    Item,
    LossyProxy,
    download_mission,
    gpi_ne,
    ne_to_latlon,
    same_item,
    sitl_run,
    standard_mission,
    upload_mission,
    waypoint,
)
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as M

from ground.sitl import Sitl, SitlOptions

#: end-to-end: the quick tier (`pytest -m "not slow"`) leaves this module to the full suite.
pytestmark = pytest.mark.slow

NAN = math.nan
GUIDED, AUTO, LOITER, RTL, LAND, ALT_HOLD = (M.COPTER_MODE_GUIDED, M.COPTER_MODE_AUTO, M.COPTER_MODE_LOITER,
                                             M.COPTER_MODE_RTL, M.COPTER_MODE_LAND, M.COPTER_MODE_ALT_HOLD)  # fmt: skip
ACCEPTED, DENIED, UNSUPPORTED = M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_DENIED, M.MAV_RESULT_UNSUPPORTED
ARM = M.MAV_CMD_COMPONENT_ARM_DISARM
#: POSITION_TARGET_TYPEMASK: position only (velocity, acceleration, yaw, yaw rate ignored)
POS_ONLY = 0x0DF8
#: position and yaw (velocity, acceleration, yaw rate ignored)
POS_YAW = 0x09F8


@pytest.fixture
def fc(tmp_path: Path):
    """Factory: ``fc(speed=5, params={...})`` starts lockstep SITL with a raw-pymavlink GCS."""
    runs = []
    with ExitStack() as stack:

        def start(name: str = "fc", **kw):
            run = stack.enter_context(sitl_run(tmp_path, f"{name}{len(runs)}", **kw))
            runs.append(run)
            return run

        try:
            yield start
        finally:
            for run in runs:  # shown by pytest when the test fails
                print(f"--- last FC/simulator output ({run.param_file.stem}) ---\n{run.tail()}")


def no_msg(g: Gcs, type: str, pred=None, *, wall_s: float = 1.0, sim_s: float = 1.0, since: int | None = None) -> None:
    """Assert that no such message arrives within ``wall_s`` wall and ``sim_s`` simulated seconds."""
    mark = g.mark() if since is None else since
    g.run_wall(wall_s)
    g.run_sim(sim_s)
    got = g.since(mark, type, pred)
    assert not got, f"unexpected {type}: {got[:3]}"


def heartbeats(g: Gcs, since: int) -> list:
    return g.since(since, "HEARTBEAT", lambda m: m.get_srcSystem() == FC_SYSID)


def saved_value(path: Path, name: str, expected: float, wall_s: float = 5.0) -> float:
    """``name`` in the parameter file once it holds ``expected`` (the FC writes the file on a
    thread of its own, moments after the PARAM_VALUE echo), or what it holds after ``wall_s``."""
    deadline = time.monotonic() + wall_s
    while True:
        try:
            value = parse_param_file(path).get(name, math.nan)
        except FileNotFoundError:
            value = math.nan
        if value == pytest.approx(expected, rel=1e-6) or time.monotonic() > deadline:
            return value
        time.sleep(0.01)


def parse_param_file(path: Path) -> dict[str, float]:
    """The .parm file as {name: value}; raises on any line that is not ``NAME VALUE``."""
    values: dict[str, float] = {}
    for lineno, raw in enumerate(path.read_text(encoding="ascii").splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 2:
            raise ValueError(f"{path}:{lineno}: not 'NAME VALUE': {raw!r}")
        values[parts[0]] = float(parts[1])
    return values


def f32(v: float) -> float:
    return struct.unpack("<f", struct.pack("<f", v))[0]


# == 1. HEARTBEAT and modes ======================================================================
def test_heartbeat_identifies_an_arducopter_in_guided(fc):
    g = fc().gcs
    hb = g.heartbeat(since=0)  # the very first one
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (FC_SYSID, FC_COMPID)
    assert hb.type == M.MAV_TYPE_QUADROTOR
    assert hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.custom_mode == GUIDED
    assert mavutil.mode_string_v10(hb) == "GUIDED"
    assert g.conn.flightmode == "GUIDED"


def test_mode_changes_by_command_and_set_mode_message(fc):
    g = fc().gcs
    g.set_mode(LOITER)
    g.wait_mode(LOITER)
    assert g.conn.flightmode == "LOITER"

    # MAVSDK sends param1 = 129 (CUSTOM_MODE_ENABLED | SAFETY_ARMED) when it believes the vehicle
    # armed: the armed bit there is not an arm request.
    mark = g.mark()
    g.set_mode(ALT_HOLD, base_mode=129)
    g.wait_mode(ALT_HOLD)
    assert g.conn.flightmode == "ALT_HOLD"
    g.run_sim(2.5)
    hbs = heartbeats(g, mark)
    assert len(hbs) >= 2 and not any(h.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED for h in hbs), hbs
    assert not any("Armed" in t for t in g.texts(mark))

    # The SET_MODE message
    g.mav.set_mode_send(FC_SYSID, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED)
    g.wait_mode(GUIDED)
    assert g.conn.flightmode == "GUIDED"

    # pymavlink's own helper (what scripts call): DO_SET_MODE by name
    g.conn.set_mode("LOITER")
    g.wait_mode(LOITER)

    # Modes that need RC sticks are refused, with a reason
    for number, name in ((M.COPTER_MODE_STABILIZE, "STABILIZE"), (M.COPTER_MODE_ACRO, "ACRO")):
        mark = g.mark()
        g.set_mode(number, expect=DENIED)
        text = g.wait("STATUSTEXT", since=mark, what="STATUSTEXT for the refused mode")
        assert name in text.text, text.text
    mark = g.mark()
    g.run_sim(2.5)
    assert {h.custom_mode for h in heartbeats(g, mark)} == {LOITER}


# == 2. Commands ===================================================================================
def test_takeoff_refused_while_disarmed_and_unknown_commands(fc):
    g = fc().gcs
    mark = g.mark()
    g.takeoff(3.0, expect=DENIED)
    text = g.wait("STATUSTEXT", since=mark, what="reason for the refused take-off")
    assert "arm" in text.text.lower(), text.text
    g.run_sim(2.0)
    assert not g.armed() and abs(g.rel_alt()) < 0.1

    for cmd in (M.MAV_CMD_DO_SET_SERVO, M.MAV_CMD_DO_MOUNT_CONTROL, 31000):
        ack = g.command(cmd, 1, 2, 3, expect=UNSUPPORTED)
        assert ack.command == cmd
    # bad arguments: DENIED, not a crash
    g.command(ARM, 0.5, expect=DENIED)
    g.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, NAN, expect=DENIED)
    g.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, AUTO, expect=DENIED)  # no mission
    g.heartbeat()  # still alive


def test_arm_takeoff_land_and_disarm_by_itself(fc):
    g = fc().gcs
    g.arm()
    g.wait("HEARTBEAT", lambda m: m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, sim_timeout_s=3, what="armed HEARTBEAT")
    for bad in (NAN, 0.2, 150.0):  # needs a value in [0.5, 100] m
        mark = g.mark()
        g.takeoff(bad, expect=DENIED)
        assert g.wait("STATUSTEXT", since=mark, what=f"reason for refusing take-off to {bad}").text
    g.takeoff(3.0)
    g.wait_altitude(3.0, tol_m=0.15)
    ext = g.wait("EXTENDED_SYS_STATE")
    assert ext.landed_state == M.MAV_LANDED_STATE_IN_AIR
    mark = g.mark()
    g.run_sim(0.5)
    chi = {m.name: m.value for m in g.since(mark, "NAMED_VALUE_FLOAT")}
    assert len(chi) == 8 and all(math.isfinite(v) for v in chi.values()), f"adaptive controller in flight: {chi}"

    # Disarming in the air needs force
    mark = g.mark()
    g.command(ARM, 0, expect=DENIED)
    assert g.wait("STATUSTEXT", since=mark).text
    g.run_sim(1.5)
    assert g.armed() and abs(g.rel_alt() - 3.0) < 0.2

    # A live parameter change: a faster landing (the default LAND_SPD is 0.7 m/s)
    pv = g.param_set("LAND_SPD", 1.4)
    assert pv.param_value == pytest.approx(1.4, abs=1e-6)

    # NAV_LAND as MAVSDK sends it: unused parameters NaN
    mark = g.mark()
    g.command(M.MAV_CMD_NAV_LAND, NAN, NAN, NAN, NAN, NAN, NAN, NAN)
    g.wait_mode(LAND)
    g.wait_disarmed(sim_timeout_s=20)
    states = {m.landed_state for m in g.since(mark, "EXTENDED_SYS_STATE")}
    assert M.MAV_LANDED_STATE_LANDING in states, states
    descent = [m.vz for m in g.since(mark, "GLOBAL_POSITION_INT")]
    assert max(descent) > 120, f"fastest descent {max(descent)} cm/s: LAND_SPD 1.4 m/s not applied"
    g.run_sim(1.5)
    assert g.landed_state() == M.MAV_LANDED_STATE_ON_GROUND
    assert abs(g.rel_alt()) < 0.15
    assert not g.armed()


def test_command_int_works_like_command_long(fc):
    g = fc().gcs
    g.command_int(ARM, M.MAV_FRAME_GLOBAL, params=(1,))
    g.command_int(M.MAV_CMD_NAV_TAKEOFF, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, params=(0, 0, 0, NAN), z=3.0)
    g.wait_altitude(3.0)
    # MAVSDK's mode change while armed carries SAFETY_ARMED in param1: not a disarm either
    g.set_mode(GUIDED, base_mode=129)
    g.run_sim(1.5)
    assert g.armed()

    g.set_mode(LOITER)  # DO_REPOSITION switches to GUIDED by itself
    g.wait_mode(LOITER)
    lat, lon = ne_to_latlon(6.0, -4.0)
    g.command_int(M.MAV_CMD_DO_REPOSITION, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                  params=(-1, M.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, 0, NAN),
                  x=round(lat * 1e7), y=round(lon * 1e7), z=4.0)  # fmt: skip

    def there() -> bool:
        n, e = g.ne()
        return math.dist((n, e, g.rel_alt()), (6.0, -4.0, 4.0)) < 0.2

    g.until(there, sim_timeout_s=25, what="reposition to 6 m N, 4 m W, 4 m up")
    g.run_sim(2.0)
    assert there()
    assert g.mode() == GUIDED
    g.command_int(31000, M.MAV_FRAME_GLOBAL, expect=UNSUPPORTED)
    g.command_int(M.MAV_CMD_NAV_RETURN_TO_LAUNCH, M.MAV_FRAME_GLOBAL)
    g.wait_mode(RTL)


def test_nan_setpoints_are_refused_and_the_vehicle_holds(fc):
    g = fc().gcs
    g.take_off(3.0)
    mark = g.mark()
    send = g.mav.set_position_target_local_ned_send
    send(0, FC_SYSID, FC_COMPID, M.MAV_FRAME_LOCAL_NED, POS_ONLY, NAN, 0, -3, 0, 0, 0, 0, 0, 0, 0, 0)
    send(0, FC_SYSID, FC_COMPID, M.MAV_FRAME_LOCAL_NED, POS_ONLY, 2, 0, NAN, 0, 0, 0, 0, 0, 0, 0, 0)
    send(0, FC_SYSID, FC_COMPID, M.MAV_FRAME_LOCAL_NED, POS_YAW, 2, 0, -3, 0, 0, 0, 0, 0, 0, NAN, 0)
    lat, lon = ne_to_latlon(2.0, 0.0)
    g.mav.set_position_target_global_int_send(0, FC_SYSID, FC_COMPID, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, POS_ONLY,
                                              int(lat * 1e7), int(lon * 1e7), NAN, 0, 0, 0, 0, 0, 0, 0, 0)  # fmt: skip
    text = g.wait("STATUSTEXT", since=mark, what="reason for refusing the NaN set-points").text
    assert "set-point" in text.lower(), text
    g.run_sim(4.0)
    for m in g.since(mark, "GLOBAL_POSITION_INT"):
        n, e = gpi_ne(m)
        assert math.dist((n, e, m.relative_alt * 1e-3), (0.0, 0.0, 3.0)) < 0.1, f"moved after a NaN set-point: {m}"
    targets = g.since(mark, "POSITION_TARGET_LOCAL_NED")
    assert len(targets) >= 12, f"{len(targets)} POSITION_TARGET_LOCAL_NED in 4 sim s (4 Hz while armed)"
    for t in targets:  # the set-point being flown is still the take-off point
        assert math.dist((t.x, t.y, t.z), (0.0, 0.0, -3.0)) < 1e-3 and math.isfinite(t.yaw), t
    # A good set-point still works
    mark = g.mark()
    send(0, FC_SYSID, FC_COMPID, M.MAV_FRAME_LOCAL_NED, POS_ONLY, 2, 0, -3, 0, 0, 0, 0, 0, 0, 0, 0)
    t = g.wait("POSITION_TARGET_LOCAL_NED", lambda m: m.x > 1.0, since=mark, sim_timeout_s=2, what="the new set-point")
    assert (t.x, t.y, t.z) == pytest.approx((2.0, 0.0, -3.0), abs=1e-4)
    g.until(lambda: math.dist(g.ne(), (2.0, 0.0)) < 0.15, sim_timeout_s=15, what="good set-point 2 m north")


def test_garbage_datagrams_do_not_disturb_the_flight(fc):
    run = fc()
    g = run.gcs
    g.take_off(3.0)
    rng = random.Random(7)
    enc = M.MAVLink(None, srcSystem=GCS_SYSID, srcComponent=GCS_COMPID)
    land = bytearray(enc.command_long_encode(FC_SYSID, FC_COMPID, M.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0).pack(enc))
    land[-1] ^= 0xFF  # bad CRC: must not land
    disarm = bytearray(enc.command_long_encode(FC_SYSID, FC_COMPID, ARM, 0, 0, 21196, 0, 0, 0, 0, 0).pack(enc))
    disarm[-2] ^= 0x55  # bad CRC: must not fall out of the sky
    junk = [
        b"",
        b"\xfd",
        b"\xfe\xff" + bytes(300),
        bytes(land),
        bytes(disarm),
        bytes(land[:20]),
        b"\xfd\x09\x00\x00\x00\xff\xbe" + bytes(60),
        bytes(rng.randrange(256) for _ in range(65000)),
    ]
    junk += [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 600))) for _ in range(40)]
    junk += [b"\xfd" + bytes(rng.randrange(256) for _ in range(rng.randrange(1, 280))) for _ in range(40)]
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stranger.bind((LOOPBACK, 0))
    try:
        mark = g.mark()
        for i, data in enumerate(junk * 2):
            (stranger if i % 2 else g.conn.port).sendto(data, run.fc_address)
            if i % 20 == 0:
                g.pump(0.01)
        g.run_sim(3.0)
        # A good packet right behind garbage in one datagram still counts
        good = enc.param_request_read_encode(FC_SYSID, FC_COMPID, b"SMC_Z_KD", -1).pack(enc)
        m2 = g.mark()
        g.conn.port.sendto(b"\x00\x01garbage\xfd\x03" + good, run.fc_address)
        g.wait("PARAM_VALUE", lambda m: m.param_id == "SMC_Z_KD", since=m2, what="reply to a packet behind garbage")
    finally:
        stranger.close()
    for m in g.since(mark, "GLOBAL_POSITION_INT"):
        n, e = gpi_ne(m)
        assert math.dist((n, e, m.relative_alt * 1e-3), (0.0, 0.0, 3.0)) < 0.1, f"flight disturbed: {m}"
    for m in g.since(mark, "ATTITUDE"):
        assert abs(m.roll) < 0.05 and abs(m.pitch) < 0.05, m
    assert g.armed() and g.mode() == GUIDED
    assert run.sitl.poll() == (None, None)


def test_messages_for_another_system_are_ignored(fc):
    g = fc().gcs
    other = (2, 1)
    mark = g.mark()
    g.send_command(ARM, 1, target=other)
    g.send_command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, LOITER, target=other)
    g.mav.param_set_send(2, 1, b"SMC_Z_KD", 7.0, M.MAV_PARAM_TYPE_REAL32)
    g.mav.set_mode_send(2, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, LOITER)
    g.mav.mission_count_send(2, 1, 3, M.MAV_MISSION_TYPE_MISSION)
    no_msg(g, ("COMMAND_ACK", "PARAM_VALUE", "MISSION_REQUEST_INT", "MISSION_REQUEST"), wall_s=1.0, sim_s=2.0, since=mark)
    assert not g.armed() and g.mode() == GUIDED
    assert {h.custom_mode for h in heartbeats(g, mark)} == {GUIDED}
    assert g.param_read("SMC_Z_KD").param_value != pytest.approx(7.0)
    # target_system 0 is a broadcast: for us too
    g.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, LOITER, target=(0, 0))
    g.wait_mode(LOITER)


def test_prearm_health_bit_says_whether_arming_would_pass(fc):
    """SYS_STATUS PREARM_CHECK "healthy when arming would pass" (docs/gcs-protocol.md); MAVSDK's
    health.is_armable comes from it."""
    g = fc().gcs
    st = g.wait("SYS_STATUS")
    assert st.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK
    g.arm()
    g.command(ARM, 0)
    # NAV_LAND on the ground is accepted and leaves the vehicle in LAND, where it cannot arm
    g.command(M.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, NAN, NAN, NAN)
    g.wait_mode(LAND)
    ack = g.arm(expect=None)
    assert ack.result == DENIED, "arming in LAND should be refused"
    mark = g.mark()
    g.run_sim(2.5)
    st = g.since(mark, "SYS_STATUS")[-1]
    assert not st.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK, (
        "PREARM_CHECK reported healthy while arming is refused"
    )


# == 3. Parameters ===================================================================================
INT_PARAMS = {"ARMING_CHECK", "FS_GCS_ENABLE", "FC_CONTROLLER", "SYSID_THISMAV", "SYS_FAILURE_EN", "DOB_MODE", "DOB_LAG", "FENCE_ENABLE", "GEO_FF"} | {
    "SIM_ENGINE_FAIL", "SIM_MOT_OFF", "SIM_GYR_FAULT", "SIM_ACC_FAULT", "SIM_ATT_FAULT", "SIM_POS_FAULT", "SIM_VEL_FAULT", "SIM_PAPER_DIST"
}  # fmt: skip


def test_param_request_list_is_complete(fc):
    g = fc().gcs
    mark = g.mark()
    got = g.param_list()
    raw = g.since(mark, "PARAM_VALUE")
    counts = {m.param_count for m in raw}
    assert len(counts) == 1, f"param_count varies: {counts}"
    (n,) = counts
    assert sorted(got) == list(range(n)), f"indices missing: {sorted(set(range(n)) - set(got))}"
    assert len(raw) == n, "duplicates in the list"
    names = [m.param_id for m in got.values()]
    assert len(set(names)) == n
    for ch in "RPYZ":
        for gain in ("C1", "C2", "KP", "KI", "KD", "KAPPA", "DELTA", "NU", "CHI", "THETA"):
            assert f"SMC_{ch}_{gain}" in names
    documented = ("SMC_CHI_MIN", "SMC_CHI_MAX", "SMC_CHI_DZ", "SMC_CHI_LEAK", "SMC_CHI0", "PSC_SPD_XY", "ATT_FILT_W",
                  "YAW_FILT_W", "YAW_RATE_MAX", "FS_GCS_ENABLE", "FS_GCS_TIMEOUT", "ARMING_CHECK", "DISARM_DELAY",
                  "LAND_SPD", "RTL_ALT_M", "WP_RADIUS_M", "FC_RATE_HZ", "FC_CONTROLLER", "SYSID_THISMAV", "TELEM_RATE_HZ")  # fmt: skip
    assert not set(documented) - set(names), f"documented parameters missing: {sorted(set(documented) - set(names))}"
    assert any(x.startswith("PSC_") for x in names)
    for m in got.values():
        if m.param_id in INT_PARAMS:
            assert m.param_type == M.MAV_PARAM_TYPE_INT32, m
            assert m.param_value == int(m.param_value), m
        else:
            assert m.param_type == M.MAV_PARAM_TYPE_REAL32, m
        assert math.isfinite(m.param_value), m


def test_param_read_set_refuse_and_live_effect(fc):
    run = fc()
    g = run.gcs
    by_name = g.param_read("SMC_Z_KD")
    assert by_name.param_type == M.MAV_PARAM_TYPE_REAL32 and by_name.param_index >= 0
    by_index = g.param_read(index=by_name.param_index)
    assert by_index.param_id == "SMC_Z_KD" and by_index.param_value == by_name.param_value
    assert by_index.param_count == by_name.param_count

    new = f32(by_name.param_value * 1.5 + 0.01)
    pv = g.param_set("SMC_Z_KD", new)
    assert pv.param_value == new
    assert g.param_read("SMC_Z_KD").param_value == new
    assert saved_value(run.param_file, "SMC_Z_KD", new) == pytest.approx(new, rel=1e-6)

    for bad in (1000.0, -1.0, NAN, math.inf):
        mark = g.mark()
        pv = g.param_set("SMC_Z_KD", bad)
        assert pv.param_value == new, f"{bad}: the old value should come back, got {pv.param_value}"
        text = g.wait("STATUSTEXT", since=mark, what=f"reason for refusing SMC_Z_KD={bad}")
        assert "SMC_Z_KD" in text.text, text.text
        assert saved_value(run.param_file, "SMC_Z_KD", new) == pytest.approx(new, rel=1e-6)

    # integers: INT32 type, value carried as float
    pv = g.param_read("FS_GCS_ENABLE")
    assert pv.param_type == M.MAV_PARAM_TYPE_INT32 and pv.param_value == 0.0
    pv = g.param_set("FS_GCS_ENABLE", 2.0, M.MAV_PARAM_TYPE_INT32)
    assert pv.param_value == 2.0 and pv.param_type == M.MAV_PARAM_TYPE_INT32
    for bad in (1.5, 3.0):
        assert g.param_set("FS_GCS_ENABLE", bad, M.MAV_PARAM_TYPE_INT32).param_value == 2.0
    assert saved_value(run.param_file, "FS_GCS_ENABLE", 2.0) == 2.0
    assert g.param_set("FS_GCS_ENABLE", 0.0, M.MAV_PARAM_TYPE_INT32).param_value == 0.0

    # live: the telemetry rate changes at once
    assert g.param_set("TELEM_RATE_HZ", 20.0).param_value == 20.0
    g.run_sim(0.5)
    assert attitude_rate(g, 3.0) == pytest.approx(20.0, abs=1.5)


def attitude_rate(g: Gcs, sim_s: float) -> float:
    """ATTITUDE messages per simulated second over ``sim_s`` simulated seconds."""
    mark = g.mark()
    g.run_sim(sim_s + 0.3)
    stamps = sorted(m.time_boot_ms for m in g.since(mark, "ATTITUDE"))
    if len(stamps) < 2:
        return 0.0
    t0 = stamps[0] + 100
    t1 = t0 + int(sim_s * 1000) - 200
    inside = [t for t in stamps if t0 <= t < t1]
    return len(inside) / ((t1 - t0) / 1000.0)


def test_params_persist_across_restart_and_the_file_is_never_half_written(fc, tmp_path):
    pf = tmp_path / "persist.parm"
    run = fc("a", param_file=pf)
    g = run.gcs
    listed = {m.param_id for m in g.param_list().values()}
    # The simulator's SIM_* parameters are listed but volatile: never in the file.
    names = {n for n in listed if not n.startswith("SIM_")}
    assert len(listed - names) >= 20
    problems: list[str] = []
    reads = [0]
    stop = threading.Event()

    def reader() -> None:
        while not stop.is_set():
            try:
                values = parse_param_file(pf)
            except FileNotFoundError:
                continue
            except (ValueError, UnicodeDecodeError) as exc:
                problems.append(str(exc))
                continue
            reads[0] += 1
            if set(values) != names:
                problems.append(f"file has {len(values)} of {len(names)} parameters")

    th = threading.Thread(target=reader, daemon=True)
    th.start()
    try:
        for i in range(12):
            value = f32(0.2 + 0.05 * i)
            assert g.param_set("SMC_Z_KD", value).param_value == value
            assert saved_value(pf, "SMC_Z_KD", value) == pytest.approx(value, rel=1e-6)
        assert g.param_set("FS_GCS_TIMEOUT", 7.0).param_value == 7.0
        assert g.param_set("ARMING_CHECK", 0.0, M.MAV_PARAM_TYPE_INT32).param_value == 0.0
    finally:
        stop.set()
        th.join(5)
    assert not problems, problems[:5]
    assert reads[0] > 0
    run.sitl.terminate()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(pf.name) and p != pf], "temporary files left"

    values = parse_param_file(pf)
    assert values["SMC_Z_KD"] == pytest.approx(f32(0.2 + 0.05 * 11), rel=1e-6)
    g2 = fc("b", param_file=pf).gcs
    assert g2.param_read("SMC_Z_KD").param_value == f32(0.2 + 0.05 * 11)
    assert g2.param_read("FS_GCS_TIMEOUT").param_value == 7.0
    assert g2.param_read("ARMING_CHECK").param_value == 0.0


def test_sysid_set_by_a_gcs_survives_a_restart(fc, tmp_path):
    pf = tmp_path / "sysid.parm"
    run = fc("a", param_file=pf)
    pv = run.gcs.param_set("SYSID_THISMAV", 2.0, M.MAV_PARAM_TYPE_INT32)
    assert pv.param_value == 2.0 and pv.param_type == M.MAV_PARAM_TYPE_INT32
    run.sitl.terminate()
    g = Gcs()
    opts = SitlOptions.of(lockstep=True, speed=5.0, gcs=f"udp:{LOOPBACK}:{g.port}", tlog=tmp_path / "sysid-b.tlog",
                       param_file=pf, log_dir=tmp_path)  # fmt: skip
    sitl = Sitl(opts)
    try:
        sitl.start(ready_timeout_s=5.0)  # the FC's first tick needs the simulator's state
        hb = g.wait("HEARTBEAT", timeout=10)
        assert hb.get_srcSystem() == 2
    finally:
        sitl.terminate()
        g.close()


# == 4. Missions =======================================================================================
def assert_mission(g: Gcs, items) -> None:
    got = download_mission(g)
    assert len(got) == len(items), f"{len(got)} items stored, {len(items)} expected"
    diffs = [d for seq, (a, b) in enumerate(zip(got, items)) for d in same_item(a, b, seq)]
    assert not diffs, diffs


def float_roundtrip(it: Item) -> Item:
    """What an item becomes when sent as MISSION_ITEM (float32 degrees) and stored as 1e-7 degrees."""
    return replace(it, x=round(f32(it.x * 1e-7) * 1e7), y=round(f32(it.y * 1e-7) * 1e7))


def test_mission_upload_download_clear_and_set_current(fc):
    g = fc().gcs
    items = standard_mission()
    ack = upload_mission(g, items)
    assert ack.type == M.MAV_MISSION_ACCEPTED and ack.target_system == GCS_SYSID
    assert_mission(g, items)

    cur = g.wait("MISSION_CURRENT")
    assert (cur.seq, cur.total) == (1, len(items) - 1), f"after an upload: {cur}"  # total: items after home
    mark = g.mark()
    g.mav.mission_set_current_send(FC_SYSID, FC_COMPID, 3)
    assert g.wait("MISSION_CURRENT", since=mark).seq == 3
    mark = g.mark()
    g.mav.mission_set_current_send(FC_SYSID, FC_COMPID, 42)  # no such item
    assert g.wait("MISSION_CURRENT", since=mark).seq == 3

    mark = g.mark()
    g.command(M.MAV_CMD_DO_SET_MISSION_CURRENT, 2)
    assert g.wait("MISSION_CURRENT", since=mark).seq == 2
    g.command(M.MAV_CMD_DO_SET_MISSION_CURRENT, 42, expect=DENIED)

    # MISSION_ITEM (float) is accepted too (latitude/longitude as float32 degrees: ~0.4 m steps)
    assert upload_mission(g, items, as_float=True).type == M.MAV_MISSION_ACCEPTED
    assert_mission(g, [float_roundtrip(it) for it in items])

    # MISSION_REQUEST (float) gets MISSION_ITEM
    mark = g.mark()
    g.mav.mission_request_send(FC_SYSID, FC_COMPID, 2, M.MAV_MISSION_TYPE_MISSION)
    item = g.wait("MISSION_ITEM", lambda m: m.seq == 2, since=mark)
    assert item.frame == M.MAV_FRAME_GLOBAL_RELATIVE_ALT and item.command == M.MAV_CMD_NAV_WAYPOINT
    assert item.x == pytest.approx(items[2].x * 1e-7, abs=1e-5) and item.z == pytest.approx(3.0)

    mark = g.mark()
    g.mav.mission_clear_all_send(FC_SYSID, FC_COMPID, M.MAV_MISSION_TYPE_MISSION)
    assert g.wait("MISSION_ACK", since=mark).type == M.MAV_MISSION_ACCEPTED
    assert download_mission(g) == []
    assert g.wait("MISSION_CURRENT").total == 0xFFFF  # no mission

    # every supported item; frames relative, AMSL and MISSION
    every = standard_mission()[:3] + [
        Item(M.MAV_CMD_DO_CHANGE_SPEED, M.MAV_FRAME_MISSION, 0, 0, 0.0, (1.0, 2.5, -1.0, 0.0)),
        waypoint(4.0, 4.0, HOME_ALT + 4.0, frame=M.MAV_FRAME_GLOBAL_INT, params=(2.0, 0.5, 0.0, 90.0)),
        waypoint(0.0, 0.0, 0.0, command=M.MAV_CMD_NAV_LOITER_TIME, params=(3.0, 0.0, 0.0, NAN)),
        Item(M.MAV_CMD_NAV_RETURN_TO_LAUNCH, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT),
    ]
    assert upload_mission(g, every).type == M.MAV_MISSION_ACCEPTED
    assert_mission(g, every)
    mark = g.mark()
    g.mav.mission_count_send(FC_SYSID, FC_COMPID, 0, M.MAV_MISSION_TYPE_MISSION)  # an empty upload clears too
    assert g.wait("MISSION_ACK", since=mark).type == M.MAV_MISSION_ACCEPTED
    assert download_mission(g) == []


def test_bad_mission_items_are_refused_and_the_stored_mission_kept(fc):
    g = fc().gcs
    good = standard_mission()
    assert upload_mission(g, good).type == M.MAV_MISSION_ACCEPTED

    bad = list(good)
    bad[2] = Item(M.MAV_CMD_DO_SET_SERVO, M.MAV_FRAME_MISSION, 0, 0, 0.0, (5, 1500, 0, 0))
    assert upload_mission(g, bad).type == M.MAV_MISSION_UNSUPPORTED
    assert_mission(g, good)

    bad = list(good)
    bad[3] = waypoint(4.0, 4.0, NAN)
    assert upload_mission(g, bad).type == M.MAV_MISSION_INVALID_PARAM7
    assert_mission(g, good)

    bad = list(good)  # NaN latitude (only MISSION_ITEM, float, can carry it)
    bad[2] = Item(M.MAV_CMD_NAV_WAYPOINT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, NAN, HOME_LON, 3.0)  # type: ignore[arg-type]
    assert upload_mission(g, bad, as_float=True).type == M.MAV_MISSION_INVALID_PARAM5_X
    assert_mission(g, good)

    bad = list(good)
    bad[2] = waypoint(4.0, 0.0, 3.0, frame=M.MAV_FRAME_LOCAL_NED)
    assert upload_mission(g, bad).type == M.MAV_MISSION_UNSUPPORTED_FRAME
    assert_mission(g, good)


def test_fc_rerequests_a_mission_item_when_the_gcs_is_silent(fc):
    g = fc().gcs
    items = standard_mission()
    mark = g.mark()
    g.mav.mission_count_send(FC_SYSID, FC_COMPID, len(items), M.MAV_MISSION_TYPE_MISSION)
    g.wait("MISSION_REQUEST_INT", lambda m: m.seq == 0, since=mark)
    first = g.log[-1].wall
    for r in g.log[mark:]:
        if r.msg.get_type() == "MISSION_REQUEST_INT":
            first = r.wall
            break
    m2 = g.mark()
    g.wait("MISSION_REQUEST_INT", lambda m: m.seq == 0, since=m2, timeout=10, what="the re-request of item 0")
    again = next(r.wall for r in g.log[m2:] if r.msg.get_type() == "MISSION_REQUEST_INT")
    assert 0.7 <= again - first <= 4.0, f"re-request after {again - first:.2f} s (expected ~1 s)"
    # now answer: the upload completes
    ack = upload_mission_from_request(g, items)
    assert ack.type == M.MAV_MISSION_ACCEPTED
    assert_mission(g, items)


def upload_mission_from_request(g: Gcs, items) -> object:
    """Continue an upload the FC has started asking for: answer item 0, then the rest."""
    items[0].send(g, 0)
    seen = g.mark()
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        g.pump(0.02)
        for m in g.since(seen, ("MISSION_REQUEST_INT", "MISSION_ACK")):
            if m.get_type() == "MISSION_ACK":
                return m
            items[m.seq].send(g, m.seq)
        seen = g.mark()
    raise AssertionError("upload did not finish")


def test_a_resent_last_item_gets_the_lost_accept_again(fc):
    """The upload's final MISSION_ACK lost on the way: the station re-sends its last item and the
    FC, the upload already done, says ACCEPTED again (instead of ignoring it and leaving the
    station to time out); another item is still ignored."""
    g = fc().gcs
    good = standard_mission()
    assert upload_mission(g, good).type == M.MAV_MISSION_ACCEPTED
    mark = g.mark()
    good[-1].send(g, len(good) - 1)
    ack = g.wait("MISSION_ACK", since=mark, timeout=5, what="the repeated ACCEPTED")
    assert ack.type == M.MAV_MISSION_ACCEPTED
    mark = g.mark()
    good[0].send(g, 0)  # not the last item: ignored, as before
    time.sleep(0.5)
    g.pump(0.1)
    assert not g.since(mark, "MISSION_ACK")
    assert_mission(g, good)


def test_mission_upload_is_cancelled_after_eight_silent_retries(fc):
    g = fc().gcs
    good = standard_mission()
    assert upload_mission(g, good).type == M.MAV_MISSION_ACCEPTED
    mark = g.mark()
    g.mav.mission_count_send(FC_SYSID, FC_COMPID, 3, M.MAV_MISSION_TYPE_MISSION)
    ack = g.wait("MISSION_ACK", since=mark, timeout=30, what="MISSION_ACK after the retries")
    assert ack.type == M.MAV_MISSION_OPERATION_CANCELLED
    requests = g.since(mark, "MISSION_REQUEST_INT")
    from fc.mission import MAX_RETRIES

    assert len(requests) == 1 + MAX_RETRIES and {m.seq for m in requests} == {0}, requests
    assert_mission(g, good)


def test_mission_flown_in_auto(fc):
    g = fc(speed=8.0).gcs
    items = standard_mission(north1=4.0, east2=4.0)
    items[3] = waypoint(4.0, 4.0, HOME_ALT + 4.0, frame=M.MAV_FRAME_GLOBAL_INT)  # AMSL: 4 m above home
    assert upload_mission(g, items).type == M.MAV_MISSION_ACCEPTED
    mark = g.mark()
    g.arm()
    g.command(M.MAV_CMD_MISSION_START, 0, 0)
    g.wait_mode(AUTO)
    # An upload started (and abandoned) in flight does not disturb the mission being flown
    g.mav.mission_count_send(FC_SYSID, FC_COMPID, 2, M.MAV_MISSION_TYPE_MISSION)
    g.wait_disarmed(sim_timeout_s=90)
    g.run_sim(1.5)
    reached = [m.seq for m in g.since(mark, "MISSION_ITEM_REACHED")]
    n, e = g.ne()
    assert math.dist((n, e), (4.0, 4.0)) < 0.5, f"landed at {n:.2f} N {e:.2f} E, expected 4 N 4 E"
    assert abs(g.rel_alt()) < 0.15
    assert g.landed_state() == M.MAV_LANDED_STATE_ON_GROUND
    # the path went through the waypoints
    track = [(gpi_ne(m), m.relative_alt * 1e-3) for m in g.since(mark, "GLOBAL_POSITION_INT")]
    assert min(math.dist(ne, (4.0, 0.0)) + abs(alt - 3.0) for ne, alt in track) < 0.6
    assert max(alt for _, alt in track) == pytest.approx(4.0, abs=0.3)
    assert reached == [1, 2, 3, 4], f"MISSION_ITEM_REACHED for {reached}, expected each item after home"
    cur = g.wait("MISSION_CURRENT")
    assert (cur.seq, cur.total) == (4, 4), f"MISSION_CURRENT after the mission: {cur}"


# == 5. Several ground stations ========================================================================
def test_several_ground_stations(fc):
    run = fc()
    a = run.gcs
    b = Gcs(f"udpout:{run.sitl.gcs_address}", sysid=254, compid=191)
    try:
        b.send_heartbeat()
        b.wait("HEARTBEAT", lambda m: m.get_srcSystem() == FC_SYSID, timeout=10)
        b.wait("ATTITUDE")
        a.wait("ATTITUDE")
        ma, mb = a.mark(), b.mark()

        a.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, LOITER)
        a.command(31001, expect=UNSUPPORTED)
        b.pump(0.1)
        mb2 = b.mark()
        b.mav.param_request_read_send(FC_SYSID, FC_COMPID, b"FS_GCS_TIMEOUT", -1)
        pv = b.wait("PARAM_VALUE", lambda m: m.param_id == "FS_GCS_TIMEOUT", since=mb2)
        assert pv.param_value == 5.0
        b.command(31002, expect=UNSUPPORTED)
        ma2 = a.mark()
        assert b.param_set("FS_GCS_TIMEOUT", 6.0).param_value == 6.0
        # the PARAM_VALUE after an accepted PARAM_SET goes to every station (their caches stay right)
        assert a.wait("PARAM_VALUE", lambda m: m.param_id == "FS_GCS_TIMEOUT", since=ma2).param_value == 6.0
        assert upload_mission(b, standard_mission()).type == M.MAV_MISSION_ACCEPTED
        # both keep receiving telemetry
        b.wait("HEARTBEAT", lambda m: m.custom_mode == LOITER, since=mb)
        a.wait("HEARTBEAT", lambda m: m.custom_mode == LOITER, since=ma)
        for g in (a, b):
            g.run_wall(0.5)
            g.run_sim(1.0)
        b.run_wall(0.3)
        acks_b = [m.command for m in b.since(mb, "COMMAND_ACK")]
        acks_a = [m.command for m in a.since(ma, "COMMAND_ACK")]
        assert 31002 in acks_b and M.MAV_CMD_DO_SET_MODE not in acks_b and 31001 not in acks_b, acks_b
        assert 31001 in acks_a and 31002 not in acks_a, acks_a
        assert [m.param_id for m in a.since(ma, "PARAM_VALUE")] == ["FS_GCS_TIMEOUT"], "B's PARAM_VALUE (read) reached A"
        assert a.since(ma, "PARAM_VALUE")[0].param_value == 6.0
        assert not a.since(ma, ("MISSION_REQUEST_INT", "MISSION_ACK")), "B's mission transaction reached A"
        assert a.since(ma, "ATTITUDE") and b.since(mb, "ATTITUDE")
    finally:
        b.close()


def test_sixteen_live_stations_keep_their_telemetry_and_a_newcomer_waits_for_a_quiet_one(fc):
    run = fc()
    a = run.gcs
    a.heartbeats = False  # the FC's own destination: always served, and now the least recently heard
    a.run_wall(0.2)
    enc = M.MAVLink(None, srcSystem=GCS_SYSID, srcComponent=GCS_COMPID)
    hb = enc.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE).pack(enc)
    socks = []
    try:
        for _ in range(17):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind((LOOPBACK, 0))
            s.setblocking(False)
            socks.append(s)
            s.sendto(hb, run.fc_address)
            a.run_wall(0.03)

        def telemetry_reaches(sock: socket.socket) -> bool:
            """Drain the socket; True if ATTITUDE arrived after the FC had settled its peers."""
            got, parser = False, M.MAVLink(None)
            with contextlib.suppress(BlockingIOError):
                while True:
                    data = sock.recv(65535)
                    got = got or any(m.get_type() == "ATTITUDE" for m in parser.parse_buffer(data) or [])
            return got

        a.run_sim(0.5)
        for s in socks:
            telemetry_reaches(s)  # drain what came before the last station was added
        mark = a.mark()
        a.run_sim(1.0)
        reached = [telemetry_reaches(s) for s in socks]
        # A full table keeps the stations it has while they are live: the 17th is not served
        # (a flood of new addresses cannot evict known stations), its messages still handled.
        assert reached == [True] * 16 + [False], f"telemetry reached stations {[i for i, r in enumerate(reached) if r]}"
        assert a.since(mark, "ATTITUDE"), "the FC's configured destination lost its telemetry"
        a.run_wall(3.0)  # every station quiet for longer than PEER_QUIET_S
        socks[16].sendto(hb, run.fc_address)  # now it takes the place of the quietest
        a.run_sim(0.5)
        telemetry_reaches(socks[16])
        a.run_sim(1.0)
        assert telemetry_reaches(socks[16])
    finally:
        for s in socks:
            s.close()


# == 6. A lossy link ====================================================================================
def reliable_command(g: Gcs, cmd: int, *params: float, tries: int = 20, wait_s: float = 0.5):
    """Send a COMMAND_LONG until it is acked, incrementing the confirmation on each resend;
    (the ack, how many sends it took)."""
    for confirmation in range(tries):
        mark = g.send_command(cmd, *params, confirmation=confirmation)
        try:
            return g.ack(cmd, mark, timeout=wait_s), confirmation + 1
        except AssertionError:
            continue
    raise AssertionError(f"command {cmd} never acknowledged over the lossy link")


#: the seed of the 10 % random drops (decided by content, not timing: see LossyProxy); on top of
#: them the test drops the first parameter value, mission request and command for sure, so the
#: recovery paths are exercised whatever the parameter list's length does to the draws
LOSS_SEED = 39


def test_ten_percent_packet_loss(tmp_path, fc):
    g = Gcs()
    try:
        # every recovery path is exercised whatever the draws: the first parameter value, mission
        # request and arm command are lost for sure
        must = frozenset({("down", M.MAVLINK_MSG_ID_PARAM_VALUE), ("down", M.MAVLINK_MSG_ID_MISSION_REQUEST_INT),
                          ("up", M.MAVLINK_MSG_ID_COMMAND_LONG)})  # fmt: skip
        with LossyProxy(g.port, loss=0.10, seed=LOSS_SEED, drop_first=must) as proxy:
            fc(gcs_port=proxy.fc_side_port, gcs=g, speed=3.0)
            g.wait("HEARTBEAT", lambda m: m.get_srcSystem() == FC_SYSID, timeout=20)
            # the parameter list, re-requesting what was lost
            mark = g.mark()
            params = g.param_list(rerequest=True, timeout=60)
            n = next(iter(params.values())).param_count
            assert sorted(params) == list(range(n))
            # a mission upload: the FC re-requests lost items, we resend lost counts
            items = standard_mission()
            mark = g.mark()
            for attempt in range(5):  # noqa: B007 - the count is reported after the loop
                ack = upload_mission(g, items, resend_count_after_s=2.5, timeout=60)
                if ack.type == M.MAV_MISSION_ACCEPTED:
                    break
            assert ack.type == M.MAV_MISSION_ACCEPTED, ack
            requests = len(g.since(mark, "MISSION_REQUEST_INT"))
            got = download_mission(g, retry_s=1.0, timeout=60)
            assert [same_item(x, y, i) for i, (x, y) in enumerate(zip(got, items))] == [[]] * len(items)
            # arm and take off, resending until acknowledged
            ack, arm_tries = reliable_command(g, ARM, 1)
            assert ack.result == ACCEPTED
            ack, takeoff_tries = reliable_command(g, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, 3.0)
            assert ack.result == ACCEPTED
            g.wait_altitude(3.0, tol_m=0.2)
            stats = (f"proxy passed {proxy.passed}, dropped {proxy.dropped} (protocol {proxy.dropped_protocol});"
                     f" {g.param_rerequests} of {n} parameters re-requested; {requests} MISSION_REQUEST_INT for {len(items)} items"
                     f" ({attempt + 1} uploads); arm sent {arm_tries}x, takeoff {takeoff_tries}x")  # fmt: skip
            print(stats)
            assert g.param_rerequests > 0 and requests > len(items) and arm_tries + takeoff_tries > 2, (
                f"the drops missed a recovery path: {stats}"
            )
    finally:
        g.close()


# == 7. GCS-loss failsafe ================================================================================
@pytest.mark.parametrize("enable", [1, 2, 0], ids=["rtl", "land", "off"])
def test_gcs_loss_failsafe(fc, enable):
    g = fc().gcs
    g.heartbeat_period_s = 0.5
    assert g.param_set("FS_GCS_ENABLE", float(enable), M.MAV_PARAM_TYPE_INT32).param_value == enable
    assert g.param_set("FS_GCS_TIMEOUT", 2.0).param_value == 2.0
    g.take_off(3.0)
    if enable:  # away from home first
        g.mav.set_position_target_local_ned_send(0, FC_SYSID, FC_COMPID, M.MAV_FRAME_LOCAL_NED, POS_ONLY,
                                                 4, 0, -3, 0, 0, 0, 0, 0, 0, 0, 0)  # fmt: skip
        g.until(lambda: math.dist(g.ne(), (4.0, 0.0)) < 0.2, sim_timeout_s=15, what="4 m north")
    mark = g.mark()
    g.heartbeats = False
    t0 = time.monotonic()
    if not enable:
        g.run_wall(3.5)
        assert not [t for t in g.texts(mark) if "GCS" in t]
        assert g.mode() == GUIDED and g.armed() and abs(g.rel_alt() - 3.0) < 0.15
        return
    text = g.wait("STATUSTEXT", lambda m: "GCS" in m.text, since=mark, timeout=15, what="GCS-loss STATUSTEXT")
    assert time.monotonic() - t0 >= 1.5, f"failsafe after {time.monotonic() - t0:.2f} s, timeout is 2 s"
    g.wait_mode(RTL if enable == 1 else LAND)
    m2 = g.mark()
    g.wait_disarmed(sim_timeout_s=60)
    g.run_sim(1.0)
    assert abs(g.rel_alt()) < 0.15
    if enable == 1:  # RTL: up to RTL_ALT_M (5 m), home, land
        assert math.dist(g.ne(), (0.0, 0.0)) < 0.6, f"landed at {g.ne()}, not home: {text.text}"
        assert max(m.relative_alt for m in g.since(m2, "GLOBAL_POSITION_INT")) == pytest.approx(5000, abs=300)
    else:  # LAND where it is
        assert math.dist(g.ne(), (4.0, 0.0)) < 0.3, f"landed at {g.ne()}, not where the failsafe hit"


# == 8. Telemetry for standard tools ======================================================================
def test_default_telemetry_streams(fc):
    g = fc().gcs
    mark = g.mark()
    g.run_sim(5.5)
    got = {r.msg.get_type() for r in g.log[mark:]}
    for t in ("HEARTBEAT", "ATTITUDE", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "SYS_STATUS", "EXTENDED_SYS_STATE",
              "HOME_POSITION", "GPS_RAW_INT", "VFR_HUD", "SYSTEM_TIME", "MISSION_CURRENT", "NAMED_VALUE_FLOAT"):  # fmt: skip
        assert t in got, f"{t} not streamed by default"
    st = g.since(mark, "SYS_STATUS")[-1]
    for bit in (M.MAV_SYS_STATUS_PREARM_CHECK, M.MAV_SYS_STATUS_GEOFENCE, M.MAV_SYS_STATUS_SENSOR_GPS,
                M.MAV_SYS_STATUS_SENSOR_3D_GYRO, M.MAV_SYS_STATUS_SENSOR_3D_ACCEL, M.MAV_SYS_STATUS_SENSOR_3D_MAG):  # fmt: skip
        assert st.onboard_control_sensors_present & bit and st.onboard_control_sensors_enabled & bit
        assert st.onboard_control_sensors_health & bit, f"bit {bit:#x} not healthy"
    assert g.since(mark, "EXTENDED_SYS_STATE")[-1].landed_state == M.MAV_LANDED_STATE_ON_GROUND
    home = g.since(mark, "HOME_POSITION")[-1]
    assert (home.latitude, home.longitude, home.altitude) == (round(HOME_LAT * 1e7), round(HOME_LON * 1e7), HOME_ALT * 1000)
    gp = g.since(mark, "GLOBAL_POSITION_INT")[-1]
    assert abs(gp.lat - home.latitude) < 20 and abs(gp.lon - home.longitude) < 20 and abs(gp.relative_alt) < 100
    assert abs(gp.alt - HOME_ALT * 1000) < 100
    nv = {m.name for m in g.since(mark, "NAMED_VALUE_FLOAT")}
    assert {f"{k}_{c}" for k in ("CHI", "SIG") for c in ("PHI", "THETA", "PSI", "Z")} <= nv, nv
    assert all(math.isnan(m.value) for m in g.since(mark, "NAMED_VALUE_FLOAT")), "CHI_*/SIG_* should be NaN while disarmed"
    assert not g.since(mark, "POSITION_TARGET_LOCAL_NED"), "no set-point is flown while disarmed"
    gps = g.since(mark, "GPS_RAW_INT")[-1]
    assert gps.fix_type == M.GPS_FIX_TYPE_3D_FIX and gps.satellites_visible == 12
    assert "OVERRUN" in {m.name for m in g.since(mark, "NAMED_VALUE_INT")}
    # rates (per simulated second, from when each arrived)
    t0, t1 = g.log[mark].sim_ms + 500, g.sim_ms - 500
    for t, hz in (("HEARTBEAT", 1), ("SYS_STATUS", 1), ("EXTENDED_SYS_STATE", 1), ("GPS_RAW_INT", 2), ("VFR_HUD", 4),
                  ("GLOBAL_POSITION_INT", 10), ("LOCAL_POSITION_NED", 10)):  # fmt: skip
        n = sum(1 for r in g.log[mark:] if r.msg.get_type() == t and t0 <= r.sim_ms < t1)
        assert n == pytest.approx(hz * (t1 - t0) / 1000, abs=1.5), f"{t}: {n} in {(t1 - t0) / 1000:.1f} sim s"
    assert attitude_rate(g, 3.0) == pytest.approx(10.0, abs=1.0)


def test_fc_listening_with_udpin_answers_a_gcs_that_writes(tmp_path):
    opts = SitlOptions.of(lockstep=True, speed=5.0, gcs=f"udpin:{LOOPBACK}:0", tlog=tmp_path / "udpin.tlog",
                       param_file=tmp_path / "udpin.parm", log_dir=tmp_path)  # fmt: skip
    with Sitl(opts) as sitl:
        g = Gcs(f"udpout:{sitl.gcs_address}")
        try:
            g.heartbeat()  # our heartbeat made the FC learn our address
            g.wait("ATTITUDE")
            assert g.param_read("SMC_Z_KD").param_id == "SMC_Z_KD"
            g.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, LOITER)
            g.wait_mode(LOITER)
        finally:
            g.close()


def test_requested_messages(fc):
    g = fc().gcs
    g.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HOME_POSITION, -1)  # only on request from now
    g.run_sim(0.5)
    for cmd, params in ((M.MAV_CMD_REQUEST_MESSAGE, (M.MAVLINK_MSG_ID_HOME_POSITION,)), (M.MAV_CMD_GET_HOME_POSITION, ())):
        mark = g.mark()
        g.command(cmd, *params)
        home = g.wait("HOME_POSITION", since=mark, what=f"HOME_POSITION after command {cmd}")
        assert home.latitude == round(HOME_LAT * 1e7)
    mark = g.mark()
    g.run_sim(6.0)
    assert not g.since(mark, "HOME_POSITION"), "HOME_POSITION still streamed after interval -1"

    for cmd, params in ((M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, (1,)),
                        (M.MAV_CMD_REQUEST_MESSAGE, (M.MAVLINK_MSG_ID_AUTOPILOT_VERSION,))):  # fmt: skip
        mark = g.mark()
        g.command(cmd, *params)
        av = g.wait("AUTOPILOT_VERSION", since=mark, what=f"AUTOPILOT_VERSION after command {cmd}")
        for cap in (M.MAV_PROTOCOL_CAPABILITY_MAVLINK2, M.MAV_PROTOCOL_CAPABILITY_MISSION_INT,
                    M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT, M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT,
                    M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED,
                    M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT):  # fmt: skip
            assert av.capabilities & cap, f"capability {cap:#x} missing"
    g.command(M.MAV_CMD_REQUEST_MESSAGE, 65000, expect=None)  # unknown id: refused, not a crash
    g.heartbeat()


def test_message_intervals_and_data_streams(fc):
    g = fc().gcs
    g.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, 50_000)  # 20 Hz
    g.run_sim(0.3)
    assert attitude_rate(g, 3.0) == pytest.approx(20.0, abs=1.5)
    g.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, -1)  # off
    g.run_sim(0.3)
    mark = g.mark()
    g.run_sim(2.0)
    assert not g.since(mark, "ATTITUDE") and g.since(mark, "GLOBAL_POSITION_INT")
    g.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, 0)  # default
    g.run_sim(0.3)
    assert attitude_rate(g, 3.0) == pytest.approx(10.0, abs=1.0)

    g.mav.request_data_stream_send(FC_SYSID, FC_COMPID, M.MAV_DATA_STREAM_EXTRA1, 4, 1)  # ATTITUDE at 4 Hz
    g.run_sim(0.5)
    assert attitude_rate(g, 4.0) == pytest.approx(4.0, abs=0.6)
    g.mav.request_data_stream_send(FC_SYSID, FC_COMPID, M.MAV_DATA_STREAM_POSITION, 0, 0)  # stop
    g.run_sim(0.5)
    mark = g.mark()
    g.run_sim(2.0)
    assert not g.since(mark, "GLOBAL_POSITION_INT") and g.since(mark, "ATTITUDE")


def test_ftp_is_refused_with_file_not_found(fc):
    g = fc().gcs
    path = b"@PARAM/param.pck?withdefaults=1"
    payload = bytearray(251)
    payload[0:2] = (77).to_bytes(2, "little")  # seq
    payload[3] = 4  # OpenFileRO
    payload[4] = len(path)
    payload[12 : 12 + len(path)] = path
    mark = g.mark()
    g.mav.file_transfer_protocol_send(0, FC_SYSID, FC_COMPID, list(payload))
    reply = g.wait("FILE_TRANSFER_PROTOCOL", since=mark)
    data = bytes(reply.payload)
    assert (reply.target_system, reply.target_component) == (GCS_SYSID, GCS_COMPID)
    assert data[3] == 129, "not a NAK"
    assert data[5] == 4, "req_opcode should echo OpenFileRO"
    assert data[4] >= 1 and data[12] == 10, "error should be FileNotFound (10)"
    assert int.from_bytes(data[0:2], "little") == 78


# == 10. A real ground station ==========================================================================
@pytest.mark.interop
def test_mavsdk_connects_arms_and_takes_off(tmp_path):
    mavsdk = pytest.importorskip("mavsdk", reason="MAVSDK-Python not installed (pip install mavsdk)")
    from mavsdk.plugins.action import Action
    from mavsdk.plugins.telemetry import Telemetry

    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind((LOOPBACK, 0))
    port = probe.getsockname()[1]
    probe.close()
    with sitl_run(tmp_path, "mavsdk", speed=2.0, gcs_port=port):
        drone = mavsdk.Mavsdk(mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.GROUND_STATION))
        try:
            assert drone.add_any_connection(f"udpin://{LOOPBACK}:{port}") == mavsdk.ConnectionResult.SUCCESS
            system = drone.first_autopilot(20.0)
            assert system is not None, "MAVSDK found no autopilot"
            tel, act = Telemetry(system), Action(system)
            deadline = time.monotonic() + 20
            while not tel.health_all_ok():
                assert time.monotonic() < deadline, f"MAVSDK health never all ok: {tel.health()}"
                time.sleep(0.2)
            act.set_takeoff_altitude(3.0)
            act.arm()
            act.takeoff()
            deadline = time.monotonic() + 30
            while not (tel.in_air() and tel.position().relative_altitude_m > 2.7):
                assert time.monotonic() < deadline, f"no take-off seen by MAVSDK: {tel.position()}"
                time.sleep(0.2)
            act.land()
            deadline = time.monotonic() + 40
            while tel.armed():
                assert time.monotonic() < deadline, "MAVSDK never saw the vehicle disarm after landing"
                time.sleep(0.2)
        finally:
            drone.destroy()
