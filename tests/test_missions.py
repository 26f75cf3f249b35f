"""ground.missions: the scripted-mission format, its conversion to mission items, and the runner.

- Parsing: good files give the right items/expectations/settings; every kind of malformed file
  raises MissionFileError whose message and attributes name the file, the item/expectation
  number and the key.
- Conversion: north/east items become latitude/longitude through smcpilot.geo, and come back
  (through the wire's 1e-7° resolution) to the same local point.
- Expectation logic on hand-made flight records (times, windows, verdicts).
- End to end, real processes: ``smcpilot mission run`` launches lockstep SITL (the FC and the
  simulator bridge), uploads through the mission protocol, flies, and judges from the FC's log;
  a passing mission exits 0 with JSON and plots, an impossible expectation exits 1 naming it, a
  broken file exits 2; ``--connect`` flies a running SITL and judges from telemetry; every
  example in examples/missions flies and passes.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.client import HomePosition, MissionItem, Vehicle
from ground.missions import (
    ChiHat,
    FlightRecord,
    ItemSpec,
    Landed,
    MaxErrorAfter,
    MaxTilt,
    Mission,
    MissionFileError,
    MissionRunError,
    Reach,
    TelemetryRecorder,
    items_to_toml,
    load_mission,
    parse_mission,
)
from ground.sitl import Sitl, SitlOptions
from smcpilot.errors import ConfigError
from smcpilot.geo import Home, global_to_ned, ned_to_global

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples" / "missions").glob("*.toml"))
HOME = Home(-35.363261, 149.165230, 584.0)
#: Wall-clock limit of one CLI run: only turns a hang into a failure.
RUN_TIMEOUT_S = 240.0


def write(tmp_path: Path, text: str, name: str = "m.toml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text), encoding="utf-8")
    return p


GOOD = """
name = "good"
description = "every item type"

[sitl]
controller = "pid_smc"
seed = 3
plant = "rigid-body"
noise = true
noise_scale = 0.5
wind_force_ned_n = [0.5, -0.25, 0]
gust_std_n = 0.2
home = [47.0, 8.0, 400.0]
max_duration_s = 90

[[item]]
type = "takeoff"
alt_m = 3

[[item]]
type = "speed"
speed_mps = 2.5

[[item]]
type = "waypoint"
north_m = 4.0
east_m = -3.0
alt_m = 3.5
hold_s = 2
yaw_deg = 90
radius_m = 0.5

[[item]]
type = "waypoint"
lat_deg = 47.00001
lon_deg = 8.00002
alt_m = 3

[[item]]
type = "loiter_time"
hold_s = 5

[[item]]
type = "loiter_time"
hold_s = 1.5
north_m = 1
east_m = 1
alt_m = 2

[[item]]
type = "land"
north_m = 0
east_m = 0

[[item]]
type = "rtl"

[[expect]]
kind = "reach"
item = 3
within_m = 0.3
by_s = 20

[[expect]]
kind = "max_tilt"
max_deg = 25

[[expect]]
kind = "chi_hat"
max = 2
min = 0.1
channels = ["z", "phi"]

[[expect]]
kind = "final_position"
north_m = 0
east_m = 0
within_m = 0.5
alt_m = 0

[[expect]]
kind = "landed"
by_s = 60

[[expect]]
kind = "max_error_after"
t_s = 10
max_m = 0.2
until_s = 15
"""


# ----------------------------------------------------------------------------------------- parsing
def test_good_file_parses_every_item_type_expectation_and_setting(tmp_path: Path) -> None:
    m = load_mission(write(tmp_path, GOOD))
    assert m.name == "good" and m.description == "every item type"
    assert [it.type for it in m.items] == ["takeoff", "speed", "waypoint", "waypoint", "loiter_time", "loiter_time", "land", "rtl"]
    assert [it.number for it in m.items] == list(range(1, 9))
    wp = m.items[2]
    assert (wp.north_m, wp.east_m, wp.alt_m, wp.hold_s, wp.yaw_deg, wp.radius_m) == (4.0, -3.0, 3.5, 2.0, 90.0, 0.5)
    assert m.items[3].lat_deg == 47.00001 and m.items[3].north_m is None
    assert not m.items[4].has_position and m.items[4].alt_m is None
    assert m.items[1].speed_mps == 2.5
    s = m.sitl
    assert (s.controller, s.seed, s.noise, s.noise_scale, s.gust_std_n, s.max_duration_s) == ("pid_smc", 3, True, 0.5, 0.2, 90.0)
    assert s.wind_force_ned_n == (0.5, -0.25, 0.0)
    assert s.home == Home(47.0, 8.0, 400.0)
    kinds = [type(e) for e in m.expectations]
    assert kinds == [Reach, MaxTilt, ChiHat, type(m.expectations[3]), Landed, MaxErrorAfter]
    assert m.expectations[0] == Reach(1, item=3, within_m=0.3, by_s=20.0)
    assert m.expectations[2].channels == ("phi", "z") and m.expectations[2].min == 0.1
    assert m.expectations[5].until_s == 15.0
    opts = s.options(gcs="udp:127.0.0.1:1", log_dir=tmp_path, tlog=tmp_path / "x.tlog", param_file=tmp_path / "p.parm")
    sc = opts.scenario
    assert opts.lockstep and sc.controller == "pid_smc" and sc.environment.wind_force_ned_n == (0.5, -0.25, 0.0)
    assert sc.home is not None and [float(v) for v in sc.home] == [47.0, 8.0, 400.0]


def test_minimal_file_defaults(tmp_path: Path) -> None:
    m = load_mission(write(tmp_path, '[[item]]\ntype = "takeoff"\nalt_m = 2\n', "tiny.toml"))
    assert m.name == "tiny" and m.expectations == ()
    assert m.sitl.controller == "adaptive_pid_smc" and m.sitl.max_duration_s == 600.0 and m.sitl.vehicle is None


def test_vehicle_path_is_relative_to_the_mission_file(tmp_path: Path) -> None:
    (tmp_path / "vehicles").mkdir()
    (tmp_path / "vehicles" / "v.toml").write_text("", encoding="utf-8")
    sub = tmp_path / "missions"
    sub.mkdir()
    p = write(sub, '[sitl]\nvehicle = "../vehicles/v.toml"\n[[item]]\ntype = "rtl"\n')
    assert load_mission(p).sitl.vehicle == sub / ".." / "vehicles" / "v.toml"


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_examples_parse(path: Path) -> None:
    m = load_mission(path)
    assert m.items and m.expectations and m.ends_on_ground
    assert m.sitl.controller == "adaptive_pid_smc"


def test_the_three_examples_exist() -> None:
    assert {p.name for p in EXAMPLES} >= {"box.toml", "figure8.toml", "gusty-hold.toml"}


ITEM = '[[item]]\ntype = "takeoff"\nalt_m = 3\n'

# (file text, section, number, key, words the message must contain)
MALFORMED = [
    pytest.param("[[item]]\ntype = 'takeoff'\nalt_m = 3\n[mision]\n", None, None, "mision", ["unknown key 'mision'"], id="unknown-top-level"),
    pytest.param("name = 'x'\n", None, None, "item", ["no [[item]]"], id="no-items"),
    pytest.param("item = []\n", None, None, "item", ["no [[item]]"], id="empty-items"),
    pytest.param("[item]\ntype = 'takeoff'\nalt_m = 3\n", None, None, "item", ["[[item]]"], id="item-not-array"),
    pytest.param("name = 3\n" + ITEM, None, None, "name", ["string"], id="name-not-string"),
    pytest.param(ITEM + "[[item]]\nalt_m = 3\n", "item", 2, "type", ["missing key 'type'"], id="item-missing-type"),
    pytest.param(ITEM + "[[item]]\ntype = 'waypiont'\n", "item", 2, "type", ["unknown item type", "did you mean 'waypoint'"], id="unknown-type"),
    pytest.param(ITEM * 2 + "[[item]]\ntype = 'waypoint'\nnort_m = 1\neast_m = 1\nalt_m = 3\n", "item", 3, "nort_m",
                 ["unknown key 'nort_m'", "did you mean 'north_m'"], id="unknown-item-key"),
    pytest.param("[[item]]\ntype = 'waypoint'\nnorth_m = 1\neast_m = 1\n", "item", 1, "alt_m", ["missing key 'alt_m'"], id="missing-alt"),
    pytest.param("[[item]]\ntype = 'waypoint'\nalt_m = 3\n", "item", 1, "north_m", ["needs north_m/east_m or lat_deg/lon_deg"], id="waypoint-no-position"),
    pytest.param("[[item]]\ntype = 'waypoint'\nnorth_m = 1\nalt_m = 3\n", "item", 1, "east_m", ["missing key 'east_m'"], id="half-position"),
    pytest.param("[[item]]\ntype = 'land'\nlat_deg = 1\n", "item", 1, "lon_deg", ["missing key 'lon_deg'"], id="half-latlon"),
    pytest.param("[[item]]\ntype = 'waypoint'\nnorth_m = 1\neast_m = 1\nlat_deg = 1\nlon_deg = 1\nalt_m = 3\n", "item", 1, "lat_deg",
                 ["not both"], id="both-positions"),
    pytest.param("[[item]]\ntype = 'takeoff'\nalt_m = nan\n", "item", 1, "alt_m", ["finite"], id="nan"),
    pytest.param("[[item]]\ntype = 'loiter_time'\nhold_s = inf\n", "item", 1, "hold_s", ["finite"], id="inf"),
    pytest.param("[[item]]\ntype = 'loiter_time'\nhold_s = -1\n", "item", 1, "hold_s", [">= 0"], id="negative-hold"),
    pytest.param("[[item]]\ntype = 'takeoff'\nalt_m = '3'\n", "item", 1, "alt_m", ["must be a number"], id="string-number"),
    pytest.param("[[item]]\ntype = 'takeoff'\nalt_m = true\n", "item", 1, "alt_m", ["must be a number"], id="bool-number"),
    pytest.param("[[item]]\ntype = 'takeoff'\nalt_m = 0.2\n", "item", 1, "alt_m", [">= 0.5"], id="takeoff-too-low"),
    pytest.param("[[item]]\ntype = 'land'\nlat_deg = 91\nlon_deg = 0\n", "item", 1, "lat_deg", ["<= 90"], id="latitude-range"),
    pytest.param("[[item]]\ntype = 'speed'\nspeed_mps = 0\n", "item", 1, "speed_mps", ["> 0"], id="speed-zero"),
    pytest.param("[[item]]\ntype = 'loiter_time'\nhold_s = 1\nnorth_m = 1\neast_m = 2\n", "item", 1, "alt_m", ["needs its altitude"],
                 id="loiter-position-without-alt"),
    pytest.param("[[item]]\ntype = 'rtl'\nalt_m = 3\n", "item", 1, "alt_m", ["unknown key 'alt_m'", "rtl item takes: none"], id="rtl-with-key"),
    pytest.param("item = [3]\n", "item", 1, None, ["must be a table"], id="item-not-table"),
    pytest.param(ITEM + "[[expect]]\nkind = 'max_speed'\n", "expect", 1, "kind", ["unknown expectation kind 'max_speed'"], id="unknown-kind"),
    pytest.param(ITEM + "[[expect]]\nmax_deg = 3\n", "expect", 1, "kind", ["missing key 'kind'"], id="missing-kind"),
    pytest.param(ITEM + "[[expect]]\nkind = 'landed'\n[[expect]]\nkind = 'reach'\nitem = 1\nby_s = 3\n", "expect", 2, "within_m",
                 ["missing key 'within_m'"], id="expect-missing-key"),
    pytest.param(ITEM + "[[expect]]\nkind = 'max_tilt'\nmax_dg = 3\n", "expect", 1, "max_dg", ["unknown key 'max_dg'", "did you mean 'max_deg'"],
                 id="expect-unknown-key"),
    pytest.param(ITEM + "[[expect]]\nkind = 'reach'\nitem = 2\nwithin_m = 1\nby_s = 3\n", "expect", 1, "item", ["does not exist"], id="reach-no-such-item"),
    pytest.param(ITEM + "[[expect]]\nkind = 'reach'\nitem = 1.0\nwithin_m = 1\nby_s = 3\n", "expect", 1, "item", ["integer"], id="reach-item-float"),
    pytest.param("[[item]]\ntype = 'rtl'\n[[expect]]\nkind = 'reach'\nitem = 1\nwithin_m = 1\nby_s = 3\n", "expect", 1, "item",
                 ["no position to reach"], id="reach-rtl"),
    pytest.param(ITEM + "[[expect]]\nkind = 'reach'\nitem = 1\nwithin_m = 1\nby_s = -3\n", "expect", 1, "by_s", [">= 0"], id="negative-time"),
    pytest.param(ITEM + "[[expect]]\nkind = 'reach'\nitem = 1\nwithin_m = 0\nby_s = 3\n", "expect", 1, "within_m", ["> 0"], id="zero-radius"),
    pytest.param(ITEM + "[[expect]]\nkind = 'max_error_after'\nt_s = -1\nmax_m = 1\n", "expect", 1, "t_s", [">= 0"], id="negative-t_s"),
    pytest.param(ITEM + "[[expect]]\nkind = 'max_error_after'\nt_s = 5\nmax_m = 1\nuntil_s = 5\n", "expect", 1, "until_s", ["> t_s"],
                 id="until-before-t"),
    pytest.param(ITEM + "[[expect]]\nkind = 'chi_hat'\nmax = 1\nmin = 2\n", "expect", 1, "min", ["<= max"], id="chi-min-above-max"),
    pytest.param(ITEM + "[[expect]]\nkind = 'chi_hat'\nmax = nan\n", "expect", 1, "max", ["finite"], id="chi-nan"),
    pytest.param(ITEM + "[[expect]]\nkind = 'chi_hat'\nmax = 1\nchannels = ['roll']\n", "expect", 1, "channels", ["unknown channel 'roll'"],
                 id="chi-bad-channel"),
    pytest.param(ITEM + "[[expect]]\nkind = 'max_tilt'\nmax_deg = 91\n", "expect", 1, "max_deg", ["<= 90"], id="tilt-range"),
    pytest.param(ITEM + "[[expect]]\nkind = 'landed'\nby_s = inf\n", "expect", 1, "by_s", ["finite"], id="landed-inf"),
    pytest.param(ITEM + "[expect]\nkind = 'landed'\n", None, None, "expect", ["[[expect]]"], id="expect-not-array"),
    pytest.param(ITEM + "[sitl]\nwind = [1, 2, 3]\n", "sitl", None, "wind", ["unknown key 'wind'"], id="sitl-unknown-key"),
    pytest.param(ITEM + "[sitl]\ncontroller = 'lqr'\n", "sitl", None, "controller", ["adaptive_pid_smc"], id="sitl-controller"),
    pytest.param(ITEM + "[sitl]\nvehicle = 'nope.toml'\n", "sitl", None, "vehicle", ["not found"], id="sitl-vehicle-missing"),
    pytest.param(ITEM + "[sitl]\nseed = -1\n", "sitl", None, "seed", ["integer"], id="sitl-seed"),
    pytest.param(ITEM + "[sitl]\nnoise = 1\n", "sitl", None, "noise", ["true or false"], id="sitl-noise"),
    pytest.param(ITEM + "[sitl]\nwind_force_ned_n = [1, 2]\n", "sitl", None, "wind_force_ned_n", ["three numbers"], id="sitl-wind-length"),
    pytest.param(ITEM + "[sitl]\nwind_force_ned_n = [1, nan, 2]\n", "sitl", None, "wind_force_ned_n", ["element 2", "finite"], id="sitl-wind-nan"),
    pytest.param(ITEM + "[sitl]\nmax_duration_s = 0\n", "sitl", None, "max_duration_s", ["> 0"], id="sitl-duration"),
    pytest.param(ITEM + "[sitl]\ngust_std_n = -0.1\n", "sitl", None, "gust_std_n", [">= 0"], id="sitl-gust"),
    pytest.param(ITEM + "[sitl]\nhome = [95, 0, 0]\n", "sitl", None, "home", ["lat_deg"], id="sitl-home"),
    pytest.param("sitl = 3\n" + ITEM, "sitl", None, None, ["must be a table"], id="sitl-not-table"),
    pytest.param(ITEM + "sitl = 3\n", "item", 1, "sitl", ["unknown key 'sitl'"], id="key-after-table-belongs-to-it"),
]


@pytest.mark.parametrize(("text", "section", "number", "key", "words"), MALFORMED)
def test_malformed_files_name_file_section_number_and_key(
    tmp_path: Path, text: str, section: str | None, number: int | None, key: str | None, words: list[str]
) -> None:
    path = write(tmp_path, text, "broken.toml")
    with pytest.raises(MissionFileError) as info:
        load_mission(path)
    err = info.value
    msg = str(err)
    assert isinstance(err, ConfigError)
    assert (err.path, err.section, err.number, err.key) == (str(path), section, number, key), msg
    assert msg.startswith(f"{path}: "), msg
    if section in ("item", "expect"):
        assert f"{section} {number}" in msg, msg
    elif section == "sitl":
        assert "[sitl]" in msg, msg
    if key is not None:
        assert repr(key) in msg, msg
    for w in words:
        assert w in msg, msg


def test_unreadable_and_invalid_toml(tmp_path: Path) -> None:
    with pytest.raises(MissionFileError, match="not found"):
        load_mission(tmp_path / "missing.toml")
    with pytest.raises(MissionFileError, match="not valid TOML"):
        load_mission(write(tmp_path, "[[item]\ntype = 'rtl'\n"))
    with pytest.raises(MissionFileError, match="is a directory"):
        load_mission(tmp_path)


# -------------------------------------------------------------------------------------- conversion
def test_to_items_converts_north_east_through_geo_and_maps_every_type(tmp_path: Path) -> None:
    m = load_mission(write(tmp_path, GOOD))
    items = m.to_items(HOME)
    assert [it.command for it in items] == [
        mavlink.MAV_CMD_NAV_TAKEOFF,
        mavlink.MAV_CMD_DO_CHANGE_SPEED,
        mavlink.MAV_CMD_NAV_WAYPOINT,
        mavlink.MAV_CMD_NAV_WAYPOINT,
        mavlink.MAV_CMD_NAV_LOITER_TIME,
        mavlink.MAV_CMD_NAV_LOITER_TIME,
        mavlink.MAV_CMD_NAV_LAND,
        mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH,
    ]
    takeoff, speed, wp, wp_global, loiter_here, loiter_at, land, _rtl = items
    assert takeoff.alt_m == 3.0 and takeoff.frame == mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
    assert speed.param2 == 2.5 and speed.frame == mavlink.MAV_FRAME_MISSION
    lat, lon, _ = ned_to_global(HOME, 4.0, -3.0, 0.0)
    assert (wp.lat_deg, wp.lon_deg, wp.alt_m) == (lat, lon, 3.5)
    assert (wp.param1, wp.param2, wp.param4) == (2.0, 0.5, 90.0)
    assert (wp_global.lat_deg, wp_global.lon_deg) == (47.00001, 8.00002) and math.isnan(wp_global.param4)
    assert (loiter_here.param1, loiter_here.lat_deg, loiter_here.lon_deg, loiter_here.alt_m) == (5.0, 0.0, 0.0, 0.0)
    n, e, _ = global_to_ned(HOME, loiter_at.lat_deg, loiter_at.lon_deg, HOME.alt_m)
    assert (round(n, 6), round(e, 6), loiter_at.alt_m, loiter_at.param1) == (1.0, 1.0, 2.0, 1.5)
    assert (land.lat_deg, land.lon_deg) == (HOME.lat_deg, HOME.lon_deg)


def test_to_items_accepts_the_vehicles_home_position(tmp_path: Path) -> None:
    m = load_mission(write(tmp_path, GOOD))
    hp = HomePosition(HOME.lat_deg, HOME.lon_deg, HOME.alt_m)
    assert m.to_items(hp) == m.to_items(HOME)


def test_to_items_needs_home_only_for_north_east(tmp_path: Path) -> None:
    local = load_mission(write(tmp_path, "[[item]]\ntype = 'takeoff'\nalt_m = 2\n[[item]]\ntype = 'land'\nnorth_m = 1\neast_m = 2\n"))
    with pytest.raises(MissionRunError, match="item 2 .*north_m/east_m need the vehicle's home"):
        local.to_items(None)
    global_only = load_mission(write(tmp_path, "[[item]]\ntype = 'land'\nlat_deg = 1\nlon_deg = 2\n", "g.toml"))
    assert global_only.to_items(None)[0].lat_deg == 1.0


@settings(max_examples=200, deadline=None)
@given(
    lat=st.floats(-80.0, 80.0),
    lon=st.floats(-179.9, 179.9),
    north=st.floats(-3000.0, 3000.0),
    east=st.floats(-3000.0, 3000.0),
)
def test_north_east_round_trip_through_the_wire(lat: float, lon: float, north: float, east: float) -> None:
    """north/east -> lat/lon (smcpilot.geo) -> MISSION_ITEM_INT (1e-7°) -> back: the same point
    to the wire's resolution (1e-7° ≈ 1.1 cm of latitude)."""
    home = Home(lat, lon, 100.0)
    spec = ItemSpec(1, "waypoint", north_m=north, east_m=east, alt_m=5.0)
    item = spec.to_item(home)
    n, e, _ = global_to_ned(home, item.lat_deg, item.lon_deg, home.alt_m)
    assert abs(n - north) < 1e-6 and abs(e - east) < 1e-6
    mav = mavlink.MAVLink(None)
    wire = MissionItem.from_message(mav.decode(bytearray(item.to_message(mav, 1, 1, 1).pack(mav))))
    n2, e2, _ = global_to_ned(home, wire.lat_deg, wire.lon_deg, home.alt_m)
    assert abs(n2 - north) < 0.012 and abs(e2 - east) < 0.012
    back = ItemSpec.from_mission_item(wire, 1, home)
    assert abs(back.north_m - north) < 0.012 and abs(back.east_m - east) < 0.012 and back.alt_m == 5.0


def test_items_to_toml_round_trip(tmp_path: Path) -> None:
    m = load_mission(write(tmp_path, GOOD))
    home47 = Home(47.0, 8.0, 400.0)  # near the file's lat/lon item
    items = m.to_items(home47)
    for home in (None, home47):
        text = items_to_toml(items, home, header="downloaded")
        again = parse_mission(tomllib.loads(text), source="downloaded")
        for a, b in zip(again.to_items(home47), items, strict=True):
            assert a.close_to(b), (a, b)
    unknown = MissionItem(mavlink.MAV_CMD_DO_SET_SERVO)
    assert "# item 1: MAV_CMD_DO_SET_SERVO" in items_to_toml([unknown])


# ---------------------------------------------------------------------------- expectation logic
def record(t: np.ndarray, north: np.ndarray, east: np.ndarray, alt: np.ndarray, armed: np.ndarray, **kw: object) -> FlightRecord:
    """A hand-made flight record (no FC involved): evaluation logic only."""
    z = np.zeros(0)
    args = dict(
        source="log", description="synthetic", t0_s=0.0, pos_t=t, north=north, east=east, alt=alt,
        tilt_t=t, tilt_deg=np.zeros_like(t), chi_t=z, chi=np.zeros((0, 4)), armed_t=t, armed=armed,
        sp_t=t, sp_north=np.zeros_like(t), sp_east=np.zeros_like(t), sp_source="synthetic",
    )  # fmt: skip
    args.update(kw)
    return FlightRecord(**args)  # type: ignore[arg-type]


def test_reach_counts_only_from_when_the_item_became_current() -> None:
    m = Mission((ItemSpec(1, "takeoff", alt_m=3.0), ItemSpec(2, "waypoint", north_m=0.0, east_m=0.0, alt_m=3.0)))
    t = np.arange(0.0, 20.0, 0.1)
    alt = np.minimum(t, 3.0)
    north = np.where(t < 5.0, 0.0, np.where(t < 10.0, 5.0, 0.0))  # passes home at 3 m at t = 3, away, back at 10
    rec = record(t, north, np.zeros_like(t), alt, np.ones_like(t, dtype=bool), item_start_s={1: 0.0, 2: 6.0})
    early = Reach(1, item=2, within_m=0.1, by_s=8.0).evaluate(rec, m, None)
    assert not early.passed and "within 0.1 m only at 10.00 s" in early.detail and early.measured == pytest.approx(5.0)
    never = Reach(4, item=2, within_m=0.1, by_s=8.0).evaluate(
        record(t, north + 1.0, np.zeros_like(t), alt, np.ones_like(t, dtype=bool), item_start_s={1: 0.0, 2: 6.0}), m, None
    )
    assert not never.passed and "never within" in never.detail
    late = Reach(2, item=2, within_m=0.1, by_s=12.0).evaluate(rec, m, None)
    assert late.passed and late.extra["first_within_s"] == pytest.approx(10.0)
    takeoff = Reach(3, item=1, within_m=0.05, by_s=4.0).evaluate(rec, m, None)
    assert takeoff.passed and takeoff.extra["first_within_s"] == pytest.approx(3.0, abs=0.06)


def test_landed_max_error_chi_and_tilt_verdicts() -> None:
    m = Mission((ItemSpec(1, "takeoff", alt_m=3.0),))
    t = np.arange(0.0, 10.0, 0.01)
    armed = t < 8.0
    alt = np.where(t < 8.0, 1.0, 0.0)
    east = np.where((t > 4.0) & (t < 4.5), 0.3, 0.05)
    chi = np.column_stack([np.full_like(t, 0.5), np.linspace(0.5, 0.9, t.size), np.full_like(t, np.nan), np.full_like(t, 0.5)])
    tilt = np.where(t > 9.0, 80.0, 5.0)  # a tip-over after disarming does not count
    rec = record(t, np.zeros_like(t), east, alt, armed, chi_t=t, chi=chi, tilt_deg=tilt)
    landed = Landed(1, by_s=8.5).evaluate(rec, m, None)
    assert landed.passed and landed.measured == pytest.approx(8.0)
    assert not Landed(2, by_s=7.0).evaluate(rec, m, None).passed
    hold = MaxErrorAfter(3, t_s=5.0, max_m=0.1).evaluate(rec, m, None)
    assert hold.passed and hold.measured == pytest.approx(0.05)
    assert not MaxErrorAfter(4, t_s=1.0, max_m=0.1, until_s=6.0).evaluate(rec, m, None).passed
    chi_ok = ChiHat(5, max=1.0, min=0.4).evaluate(rec, m, None)
    assert not chi_ok.passed and "no χ̂ for psi" in chi_ok.detail  # psi is all NaN
    chi_some = ChiHat(6, max=1.0, min=0.4, channels=("phi", "theta")).evaluate(rec, m, None)
    assert chi_some.passed and chi_some.measured == pytest.approx(0.5 + 0.4 * 799 / 999, abs=1e-3)
    assert not ChiHat(7, max=0.8).evaluate(rec, m, None).passed
    tilt_result = MaxTilt(8, max_deg=10.0).evaluate(rec, m, None)
    assert tilt_result.passed and tilt_result.measured == 5.0
    no_chi = record(t, np.zeros_like(t), east, alt, armed)
    assert not ChiHat(9, max=5.0).evaluate(no_chi, m, None).passed


def test_telemetry_record_uses_the_streamed_set_point_else_the_planned_one() -> None:
    """The --connect record: times from time_boot_ms, mission time from t0; set-points from
    POSITION_TARGET_LOCAL_NED when streamed, else the current item's planned point."""
    m = Mission((ItemSpec(1, "takeoff", alt_m=2.0), ItemSpec(2, "waypoint", north_m=5.0, east_m=0.0, alt_m=2.0),
                 ItemSpec(3, "loiter_time", hold_s=2.0), ItemSpec(4, "rtl")))  # fmt: skip
    rec_from = TelemetryRecorder(Vehicle("udpin:127.0.0.1:0"))  # never opened: filled by hand below
    t0 = 100.0
    for k in range(200):  # 20 s at 10 Hz
        t = t0 + 0.1 * k
        rec_from.pos.append((t, min(0.5 * 0.1 * k, 4.0), 0.0, 2.0))
        rec_from.att.append((t, 0.0, 0.0))
        rec_from.armed.append((t, True))
    rec_from.current += [(t0 + 2.0, "MISSION_ITEM_REACHED", 1), (t0 + 9.0, "MISSION_ITEM_REACHED", 2),
                         (t0 + 12.05, "MISSION_CURRENT", 4)]  # fmt: skip
    planned = rec_from.record(t0, m, HOME)
    assert planned.item_start_s == {1: 0.0, 2: 2.0, 3: 9.0, 4: pytest.approx(12.05)}
    assert "planned" in planned.sp_source
    sp = dict(zip(np.round(planned.sp_t, 3), zip(planned.sp_north, planned.sp_east)))
    assert sp[1.0] == (0.0, 0.0)  # takeoff: where it was when the item began
    assert sp[5.0] == (5.0, 0.0)  # the waypoint's point
    assert sp[10.0] == (pytest.approx(4.0), 0.0)  # loiter here: where it was at 9 s
    assert sp[15.0] == (0.0, 0.0)  # RTL: home
    for k in range(0, 80):
        rec_from.targets.append((t0 + 0.25 * k, 4.0, 0.5))
    streamed = rec_from.record(t0, m, HOME)
    assert "POSITION_TARGET_LOCAL_NED" in streamed.sp_source and streamed.sp_t.size == 80
    hold = MaxErrorAfter(1, t_s=10.0, max_m=0.6).evaluate(streamed, m, HOME)
    assert hold.passed and hold.measured == pytest.approx(0.5)


# ------------------------------------------------------------------------------------ end to end
def run_cli(*args: str | Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lab.cli", "mission", *map(str, args)],
        cwd=cwd, capture_output=True, text=True, timeout=RUN_TIMEOUT_S, check=False,
    )  # fmt: skip


SHORT = """
name = "short"

[[item]]
type = "takeoff"
alt_m = 2.0

[[item]]
type = "waypoint"
north_m = 3.0
east_m = 1.0
alt_m = 2.0
hold_s = 1.0

[[item]]
type = "land"

[[expect]]
kind = "reach"
item = 2
within_m = 0.3
by_s = 15.0

[[expect]]
kind = "landed"
by_s = 30.0

[[expect]]
kind = "final_position"
north_m = 3.0
east_m = 1.0
within_m = 0.5
"""


@pytest.mark.slow
def test_short_mission_passes_and_writes_json_and_plots(tmp_path: Path) -> None:
    mission = write(tmp_path, SHORT, "short.toml")
    out, report = tmp_path / "out", tmp_path / "report.json"
    r = run_cli("run", mission, "--json", report, "--out", out, cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "t=" in r.stdout and ("item 2/3" in r.stdout or "item 3/3" in r.stdout), r.stdout  # progress lines
    assert "Result: 3/3 expectations held -> PASS" in r.stdout, r.stdout
    data = json.loads(report.read_text(encoding="utf-8"))
    assert data["passed"] is True and data["source"] == "log" and data["finished"] is True
    assert [e["kind"] for e in data["expectations"]] == ["reach", "landed", "final_position"]
    assert all(e["passed"] for e in data["expectations"])
    assert data["expectations"][0]["measured"] <= 0.3
    # The flight's metrics from the FC's log (ground.logs.metrics), in the JSON and the text.
    m = data["metrics"]
    assert m["crashed"] is False and m["recovered"] is None and m["flight_time_s"] > 5.0
    assert m["iae_pos_m_s"] > 0.0 and m["effort_u2_s"] > 0.0 and m["max_tilt_deg"] < 30.0
    assert re.search(r"position error +IAE [0-9.]+ m s", r.stdout) and re.search(r"crashed +no\n", r.stdout), r.stdout
    assert Path(data["tlog"]).is_file() and Path(data["tlog"]).parent == out
    pngs = sorted((out / "plots").glob("*.png"))
    assert {p.name for p in pngs} >= {"position.png", "track.png"}
    assert all(p.read_bytes().startswith(b"\x89PNG") for p in pngs)
    assert [str(p) for p in pngs] == sorted(data["plots"])


@pytest.mark.slow
def test_impossible_expectation_exits_1_and_names_it(tmp_path: Path) -> None:
    text = SHORT + '\n[[expect]]\nkind = "max_tilt"\nmax_deg = 0.5\n'
    mission = write(tmp_path, text, "impossible.toml")
    report = tmp_path / "r.json"
    r = run_cli("run", mission, "--json", report, "--out", tmp_path / "out", "--no-plots", cwd=tmp_path)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "FAIL  expect 4 max_tilt" in r.stdout and "vs limit <= 0.5°" in r.stdout, r.stdout
    assert "Result: 3/4 expectations held -> FAIL" in r.stdout and "failed: expect 4 max_tilt" in r.stdout
    data = json.loads(report.read_text(encoding="utf-8"))
    assert data["passed"] is False
    assert [e["number"] for e in data["expectations"] if not e["passed"]] == [4]
    assert not (tmp_path / "out" / "plots").exists()


def test_broken_file_exits_2_naming_the_key(tmp_path: Path) -> None:
    mission = write(tmp_path, SHORT.replace("within_m = 0.3", "within_m = nan"), "broken.toml")
    r = run_cli("run", mission, cwd=tmp_path)
    assert r.returncode == 2
    assert "broken.toml: expect 1 (reach): key 'within_m': must be a finite number" in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()  # nothing launched


def test_usage_error_exits_2(tmp_path: Path) -> None:
    assert run_cli("run", cwd=tmp_path).returncode == 2
    assert run_cli("fly", "x.toml", cwd=tmp_path).returncode == 2


@pytest.mark.slow
def test_connect_flies_a_running_vehicle_and_judges_from_telemetry(tmp_path: Path) -> None:
    mission = write(tmp_path, SHORT + '\n[[expect]]\nkind = "max_error_after"\nt_s = 6.0\nuntil_s = 10.0\nmax_m = 0.3\n', "short.toml")
    opts = SitlOptions.of(gcs="udpin:127.0.0.1:0", log_dir=tmp_path, tlog=tmp_path / "sitl.tlog", param_file=tmp_path / "p.parm")
    report = tmp_path / "r.json"
    with Sitl(opts) as sitl:
        r = run_cli("run", mission, "--connect", f"udpout:{sitl.gcs_address}", "--json", report, "--out", tmp_path / "out", cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    data = json.loads(report.read_text(encoding="utf-8"))
    assert data["source"] == "telemetry" and data["passed"] is True
    assert all(e["source"] == "telemetry" for e in data["expectations"])
    assert "[from telemetry]" in r.stdout and "POSITION_TARGET_LOCAL_NED" in data["expectations"][3]["detail"]
    assert data["tlog"].endswith("short-telemetry.tlog") and (tmp_path / "out" / "plots" / "track.png").is_file()


@pytest.mark.slow
@pytest.mark.parametrize("path", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_example_flies_and_passes(tmp_path: Path, path: Path) -> None:
    """Each example is 35-55 simulated seconds: 5-10 s wall in lockstep."""
    report = tmp_path / "r.json"
    r = run_cli("run", path, "--json", report, "--out", tmp_path / "out", "--no-plots", cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    data = json.loads(report.read_text(encoding="utf-8"))
    assert data["passed"] and data["finished"], data


# == faults in a mission's [sitl] ===========================================================================
def test_sitl_faults_reach_the_scenario_and_bad_ones_name_the_item() -> None:
    doc = tomllib.loads(textwrap.dedent("""
        [sitl]
        [[sitl.fault]]
        kind = "motor"
        motor = 2
        efficiency = 0.6
        start_s = 12.5
        [[sitl.fault]]
        kind = "sensor"
        sensor = "position"
        mode = "dropout"
        start_s = 20.0
        stop_s = 20.5
        [[item]]
        type = "takeoff"
        alt_m = 3.0
    """))
    m = parse_mission(doc, source="m.toml")
    faults = m.sitl.scenario().faults
    assert [(f.kind, f.start_s, f.stop_s) for f in faults] == [("motor", 12.5, math.inf), ("sensor", 20.0, 20.5)]
    assert faults[0].motor == 2 and faults[0].efficiency == 0.6
    assert "motor 2 at 60%" in m.sitl.describe()
    doc["sitl"]["fault"][0]["motor"] = 5
    with pytest.raises(MissionFileError, match=r"m\.toml: \[sitl\]: key 'fault': \[\[sitl\.fault\]\] 1 \(motor\): .*motor"):
        parse_mission(doc, source="m.toml")
    doc["sitl"]["fault"] = {"kind": "motor"}
    with pytest.raises(MissionFileError, match="array of tables"):
        parse_mission(doc, source="m.toml")
