"""Many vehicles: the [swarm] table, the ground router, and K vehicles flying in one simulator.

Oracles: a vehicle of a lockstep swarm flies exactly as it flies alone (its tlog byte for byte);
the router's target_system offsets agree with pymavlink's own encoding for every message that has
one; real UDP sockets and real processes throughout.
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.router import TARGET_OFFSETS, GroundRouter, split_packets
from ground.sitl import Sitl, SitlError, SitlOptions
from ground.vehicle import Swarm
from smcpilot.errors import ScenarioError
from smcpilot.scenario import Scenario
from smcpilot.swarm import MAX_VEHICLES, SwarmError, SwarmSpec, check_count, fc_ground_port, fc_groups, grid_offset
from smcpilot.tlog import read_tlog

ROOT = Path(__file__).resolve().parents[1]

SWARM = """
name = "trio"
duration_s = {duration}
[[step]]
t_s = 0.0
action = "takeoff"
alt_m = 2.0
[swarm]
count = {count}
{swarm_keys}
"""


def swarm_scenario(tmp_path: Path, count: int = 3, duration: float = 2.0, extra: str = "", swarm_keys: str = "") -> Scenario:
    path = tmp_path / "swarm.toml"
    path.write_text(SWARM.format(count=count, duration=duration, swarm_keys=swarm_keys) + extra, encoding="utf-8")
    return Scenario.from_toml(path)


#: vehicle 2 (spawned 3 m east of vehicle 1 with spacing_m = 3) flies 3 m west in its own frame: onto vehicle 1.
CONTACT_VEHICLES = """
[[swarm.vehicle]]
[[swarm.vehicle]]
[[swarm.vehicle.step]]
t_s = 0.0
action = "takeoff"
alt_m = 2.0
[[swarm.vehicle.step]]
t_s = 3.0
action = "goto"
north_m = 0.0
east_m = -3.0
alt_m = 2.0
"""


def _free_port() -> int:
    """A UDP port free on loopback now (for a ground station's address)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def fly(scenario: Scenario, tmp_path: Path, name: str, **kw) -> Sitl:
    opts = SitlOptions(scenario=scenario, timed=True, lockstep=True, gcs=kw.pop("gcs", None), tlog=tmp_path / f"{name}.tlog",
                       log_dir=tmp_path, watchdog_s=10.0, **kw)  # fmt: skip
    with Sitl(opts) as sitl:
        sitl.wait(timeout_s=120.0)
    return sitl


# -- the [swarm] table --------------------------------------------------------------------------------
def test_fleet_gives_each_vehicle_its_flight(tmp_path: Path) -> None:
    sc = swarm_scenario(tmp_path, count=4, extra="""
[[swarm.vehicle]]
seed = 7
params = { SMC_CHI_DZ = 0.2 }
[[swarm.vehicle.fault]]
kind = "motor"
start_s = 1.0
motor = 2
efficiency = 0.7
[[swarm.vehicle]]
sysid = 9
offset_m = [0.0, 10.0]
controller = "cascade_pid"
""")
    fleet = sc.fleet()
    assert [v.sysid for v in fleet] == [1, 9, 3, 4]
    assert [v.offset_ne_m for v in fleet] == [(0.0, 0.0), (0.0, 10.0), grid_offset(2, 4, 4.0), grid_offset(3, 4, 4.0)]
    assert grid_offset(2, 4, 4.0) == (4.0, 0.0) and grid_offset(3, 4, 4.0) == (4.0, 4.0)
    v1, v2, v3, _ = (v.scenario for v in fleet)
    assert v1.seed == 7 and v2.seed == 1000 and v3.seed == 2000
    assert dict(v1.params) == {"SMC_CHI_DZ": 0.2} and len(v1.faults) == 1 and not v2.faults
    assert v2.controller == "cascade_pid" and v1.controller == "adaptive_pid_smc"
    assert v1.home is None  # the first vehicle spawns at the swarm's home: its flight is the scenario's
    assert all(v.scenario.swarm is None and len(v.scenario.plan) == 1 for v in fleet)
    # its home lies where its offset says (10 m east of the swarm's)
    from smcpilot.geo import Home, global_to_ned

    n, e, d = global_to_ned(Home(), *v2.home)  # type: ignore[misc]
    assert abs(n) < 1e-6 and abs(e - 10.0) < 1e-6 and abs(d) < 1e-9
    # the document round trip keeps the swarm
    assert Scenario.from_mapping(sc.to_mapping()) == sc


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        ("[[swarm.vehicle]]\nsede = 3\n", "swarm.vehicle[1].sede"),
        ("[[swarm.vehicle]]\n[[swarm.vehicle]]\nsysid = 1\n", "both have system id 1"),
        ("[[swarm.vehicle]]\nsysid = 0\n", "1..255"),
        ("[[swarm.vehicle]]\n[[swarm.vehicle]]\n[[swarm.vehicle]]\n[[swarm.vehicle]]\n", "4 [[swarm.vehicle]] tables for a swarm of 3"),
        ("[[swarm.vehicle]]\noffset_m = [1.0]\n", "offset_m"),
        ("[[swarm.vehicle]]\ncontroller = \"no_such_law\"\n", "no_such_law"),
    ],
)
def test_bad_vehicle_tables_name_the_key(tmp_path: Path, extra: str, needle: str) -> None:
    with pytest.raises(ScenarioError, match=None) as info:
        swarm_scenario(tmp_path, extra=extra)
    assert needle in str(info.value), str(info.value)


def test_sitl_says_when_a_swarm_would_fly_faster_in_fewer_processes() -> None:
    from ground.sitl_cmd import layout_hint

    assert layout_hint(1, None, 2, True) is None  # one vehicle
    assert layout_hint(3, 1, 2, True) is None  # grouped already
    assert layout_hint(3, None, 8, False) is None  # they fit the cores
    line = layout_hint(16, None, 2, False)
    assert line is not None and "--fc-processes 1 flies them in one loop" in line and "real time" in line
    line = layout_hint(16, None, 4, True)
    assert line is not None and "--fc-processes 3 flies them in 3 loops" in line and "lockstep" in line
    assert "\n" not in line


def test_count_limits() -> None:
    check_count(MAX_VEHICLES)
    for bad in (0, -1, MAX_VEHICLES + 1):
        with pytest.raises(SwarmError):
            check_count(bad)
    with pytest.raises(SwarmError, match="beyond 65535"):
        check_count(8, base_port=65500)
    with pytest.raises(SwarmError, match="unknown key swarm.cuont"):
        SwarmSpec.from_mapping({"cuont": 3})
    with pytest.raises(SwarmError, match="swarm.lost must be one of stop, hold, remove"):
        SwarmSpec.from_mapping({"count": 2, "lost": "explode"})
    assert fc_ground_port(0) == 14561 and fc_ground_port(3) == 14591


def smcpilot(*args: str | Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "lab.cli", *map(str, args)], cwd=cwd, capture_output=True, text=True,
                          timeout=120, check=False)  # fmt: skip


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("--count", str(MAX_VEHICLES + 1)), f"at most {MAX_VEHICLES} vehicles"),
        (("--count", "0"), "whole number >= 1"),
        (("--count", "2", "--sysid", "255"), "1..255"),
        (("--count", "2", "--sysid", "300"), "1..255"),
        (("--count", "2", "--sim", "px4"), "leave out --sim or --count"),
        (("--count", "2", "--fc-processes", "0"), "--fc-processes must be a whole number in 1.."),
        (("--fc-processes", "2"), "give --count K > 1"),
    ],
)
def test_sitl_count_errors_are_one_line_exit_2(tmp_path: Path, args: tuple[str, ...], needle: str) -> None:
    r = smcpilot("sitl", "--lockstep", "--duration", "1", "--gcs", "none", *args, cwd=tmp_path)
    lines = r.stderr.splitlines()
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert len(lines) == 1 and lines[0].startswith("smcpilot sitl: error: ") and needle in lines[0], r.stderr
    assert not (tmp_path / "logs").exists() or not list((tmp_path / "logs").iterdir())  # nothing started


def test_sitl_unknown_vehicle_key_is_one_line_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(SWARM.format(count=2, duration=1.0, swarm_keys="") + "[[swarm.vehicle]]\nplann = \"x.toml\"\n", encoding="utf-8")
    r = smcpilot("sitl", "--lockstep", "--gcs", "none", "--scenario", bad, cwd=tmp_path)
    lines = r.stderr.splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "swarm.vehicle[1].plann" in lines[0], r.stderr


# -- the router ---------------------------------------------------------------------------------------
def _default_args(cls: type) -> list:
    args: list = []
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes):
        n = cls.array_lengths[cls.ordered_fieldnames.index(name)]  # (in wire order)
        if ftype == "char":
            args.append(b"")
        elif n:
            args.append([0] * n)
        else:
            args.append(0)
    return args


MESSAGES_WITH_TARGET = sorted(TARGET_OFFSETS)


def test_target_offsets_cover_every_message_with_a_target() -> None:
    have = [mid for mid, cls in mavlink.mavlink_map.items() if "target_system" in cls.fieldnames]
    assert sorted(have) == MESSAGES_WITH_TARGET
    assert len(MESSAGES_WITH_TARGET) > 50


@pytest.mark.parametrize("target", [0, 1, 77, 255])
def test_split_packets_reads_target_system_as_pymavlink_encodes_it(target: int) -> None:
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    checked = 0
    for mid in MESSAGES_WITH_TARGET:
        cls = mavlink.mavlink_map[mid]
        args = _default_args(cls)
        args[cls.fieldnames.index("target_system")] = target
        try:
            msg = cls(*args)
            packet = msg.pack(mav)
        except Exception:  # a message pymavlink cannot build from zeros (none in practice): not our question
            continue
        (got,), bad = split_packets(packet + b"")
        assert bad == 0 and got[0] == packet and got[1] == 255
        assert got[2] == target, (cls.msgname, got[2], target)
        # and pymavlink reads the same target back from the same bytes
        assert mavlink.MAVLink(None).decode(bytearray(packet)).target_system == target
        checked += 1
    assert checked == len(MESSAGES_WITH_TARGET)


def test_split_packets_keeps_signed_packets_whole_and_counts_garbage() -> None:
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    mav.signing.secret_key = bytes(range(32))
    mav.signing.link_id = 1
    mav.signing.sign_outgoing = True
    mav.signing.timestamp = 1
    signed = mav.command_long_encode(2, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav)
    plain = mavlink.MAVLink(None, srcSystem=255).heartbeat_encode(6, 8, 0, 0, 0).pack(mavlink.MAVLink(None, srcSystem=255))
    packets, bad = split_packets(b"\x00garbage" + signed + b"\xfd\x09" + plain)
    assert [p for p, _, _ in packets] == [signed, plain]
    assert packets[0][2] == 2 and packets[1][2] is None  # HEARTBEAT has no target: everyone
    assert bad == 2


class _RouterThread:
    def __init__(self, ground_port: int, vehicles: dict[int, tuple[str, int]] | None = None) -> None:
        self.router = GroundRouter(f"udp:127.0.0.1:{ground_port}", vehicles, sysids=(1, 2))
        self.thread = threading.Thread(target=self.router.serve, kwargs={"poll_s": 0.05}, daemon=True)

    def __enter__(self) -> GroundRouter:
        self.thread.start()
        return self.router

    def __exit__(self, *exc: object) -> None:
        self.router.request_stop()
        self.thread.join(timeout=5)
        self.router.close()


def _sock() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(2.0)
    return s


def _drain(s: socket.socket, wait_s: float = 0.3) -> list[bytes]:
    out = []
    s.settimeout(wait_s)
    try:
        while True:
            out.append(s.recvfrom(65535)[0])
    except TimeoutError:
        return out


def test_router_sends_each_ground_packet_to_the_vehicle_it_names() -> None:
    ground, fc1, fc2, hostile = _sock(), _sock(), _sock(), _sock()
    try:
        with _RouterThread(ground.getsockname()[1]) as router:
            vaddr = router.vehicle_address
            for sid, s in ((1, fc1), (2, fc2)):  # each FC's first telemetry: the router learns it
                hb = mavlink.MAVLink(None, srcSystem=sid, srcComponent=1)
                s.sendto(hb.heartbeat_encode(2, 3, 0, 0, 4).pack(hb), vaddr)
            got = [split_packets(d)[0][0][1] for d in (ground.recvfrom(65535)[0], ground.recvfrom(65535)[0])]
            assert sorted(got) == [1, 2]
            gaddr = router.ground_address
            mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
            to2 = mav.command_long_encode(2, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav)
            ground.sendto(to2, gaddr)
            assert _drain(fc2) == [to2] and _drain(fc1) == []
            to_all = mav.param_request_list_encode(0, 0).pack(mav)
            hostile.sendto(to_all, gaddr)
            assert _drain(fc1) == [to_all] and _drain(fc2) == [to_all]
            to9 = mav.command_long_encode(9, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav)
            to1 = mav.command_long_encode(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav)
            hostile.sendto(to9 + to1 + b"\xfe\x01junk", gaddr)  # one datagram: a wrong id, a right one, garbage
            assert _drain(fc1) == [to1] and _drain(fc2) == []
            # a stranger on the vehicle side is not a vehicle
            hostile.sendto(to1, vaddr)
            time.sleep(0.1)
            c = router.counters
            assert c.no_such_vehicle == 1 and c.rx_bad == 1 and c.foreign == 1 and c.broadcast_packets == 1
            # the hostile station heard every vehicle's telemetry since it wrote (a ground peer)
            fc1.sendto(mavlink.MAVLink(None, srcSystem=1).heartbeat_encode(2, 3, 0, 0, 4).pack(mavlink.MAVLink(None, srcSystem=1)), vaddr)
            assert len(_drain(hostile)) == 1 and len(_drain(ground)) == 1
    finally:
        for s in (ground, fc1, fc2, hostile):
            s.close()


# -- K vehicles in one simulator -------------------------------------------------------------------------
def test_each_vehicle_of_a_lockstep_swarm_flies_as_it_flies_alone(tmp_path: Path) -> None:
    sc = swarm_scenario(tmp_path, count=3, duration=2.0)
    swarm = fly(sc, tmp_path, "swarm")
    assert len(swarm.tlogs) == 3 and all(p.exists() for p in swarm.tlogs)
    sim = swarm.sim_summary
    assert sim is not None and sim["sim_time_s"] == pytest.approx(2.0) and len(sim["vehicles"]) == 3
    assert [v["system_id"] for v in sim["vehicles"]] == [1, 2, 3]
    assert sim["proximity"]["min_separation_m"] == pytest.approx(4.0, abs=0.05) and not sim["proximity"]["contacts"]
    for s in swarm.fc_summaries:
        assert s is not None and s["ticks"] == 1001
    # vehicle 2 alone: its own scenario, its system id: the same log, byte for byte
    v2 = sc.fleet()[1]
    solo = fly(v2.scenario, tmp_path, "solo", fc_args=("--sysid", "2"), sim_args=("--sysid", "2"))
    assert solo.tlog is not None
    assert swarm.tlogs[1].read_bytes() == solo.tlog.read_bytes()
    # and each vehicle's messages come from its own system id
    assert {m.get_srcSystem() for _, m in read_tlog(swarm.tlogs[2]) if m.get_type() == "ATTITUDE"} == {3}


def test_flight_controllers_flown_in_groups_write_the_same_logs(tmp_path: Path) -> None:
    """python -m fc.group: several FCs in one process and one loop are the same FCs: each log is
    byte for byte the one its own process writes (noise and gusts on, a fault, 3 vehicles in 2 groups)."""
    extra = '[environment]\nnoise = true\ngust_std_n = 0.5\n[[fault]]\nkind = "motor"\nstart_s = 1.0\nmotor = 1\nefficiency = 0.7\n'
    sc = swarm_scenario(tmp_path, count=3, duration=2.0, extra=extra)
    own = fly(sc, tmp_path / "own", "run")
    grouped = fly(sc, tmp_path / "grouped", "run", fc_processes=2)
    assert [c.name for c in grouped.fcs] == ["fc1", "fc2", "fc3"]
    assert len({c.proc.pid for c in grouped.fcs}) == 2 and grouped.fcs[0].proc is grouped.fcs[1].proc
    assert [p.read_bytes() for p in grouped.tlogs] == [p.read_bytes() for p in own.tlogs]
    for s in grouped.fc_summaries:  # each FC's own summary, routed from the group's output
        assert s is not None and s["ticks"] == 1001 and s["sim_time_s"] == pytest.approx(2.0)
    assert {s["tlog"] for s in grouped.fc_summaries if s} == {str(p) for p in grouped.tlogs}


def test_states_sent_ahead_of_the_slowest_vehicle_give_the_same_logs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A busy-polling simulator sends each vehicle its next state as soon as its FC has answered
    (SimBridgeApp._run_lockstep_swarm): each log is byte for byte the one the barrier loop gives
    (noise and gusts on, a fault, a resend-free flight of 3 vehicles in one spinning group)."""
    from ground.sitl import Sitl

    extra = '[environment]\nnoise = true\ngust_std_n = 0.5\n[[fault]]\nkind = "motor"\nstart_s = 1.0\nmotor = 1\nefficiency = 0.7\n'
    sc = swarm_scenario(tmp_path, count=3, duration=2.0, extra=extra)
    barrier = fly(sc, tmp_path / "barrier", "run")
    monkeypatch.setattr(Sitl, "_spinning", lambda self: True)  # (whatever this machine's cores)
    ahead = fly(sc, tmp_path / "ahead", "run", fc_processes=1)
    assert "--spin-s" not in ahead.sim.proc.args  # the simulator busy-polls: it sends states ahead
    assert [p.read_bytes() for p in ahead.tlogs] == [p.read_bytes() for p in barrier.tlogs]
    sim = ahead.sim_summary
    assert sim is not None and sim["sim_time_s"] == pytest.approx(2.0) and sim["actuator_msgs"] == 3 * 1000
    assert sim["ahead"]["states"] > 0 and "ahead" not in (barrier.sim_summary or {})


@pytest.mark.slow
def test_a_group_of_flight_controllers_on_an_impaired_link_writes_the_same_logs(tmp_path: Path) -> None:
    """A lossy, delayed simulator link: the group's loop releases what the link holds back on time,
    and every state lost is re-sent until answered, so each log is still its own process's."""
    sc = swarm_scenario(tmp_path, count=2, duration=1.0, extra="[link.sim]\nloss = 0.1\ndelay_ms = 2.0\n")
    assert sc.sim_link.loss == 0.1
    own = fly(sc, tmp_path / "own", "run")
    grouped = fly(sc, tmp_path / "grouped", "run", fc_processes=1)
    assert [p.read_bytes() for p in grouped.tlogs] == [p.read_bytes() for p in own.tlogs]
    for s in grouped.fc_summaries:
        assert s is not None and s["ticks"] == 501, s
        assert sum(d["lost"] for d in s["impairment"]["sim"].values()) > 0, s["impairment"]  # (either direction)


def test_flight_controllers_in_a_group_fly_a_real_time_swarm(tmp_path: Path) -> None:
    """In real time a group's FCs each keep their own wall clock, in one loop, every one to the end."""
    sc = swarm_scenario(tmp_path, count=3, duration=2.0)
    opts = SitlOptions(scenario=sc, timed=True, lockstep=False, gcs=None, tlog=tmp_path / "rt.tlog", log_dir=tmp_path,
                       watchdog_s=10.0, fc_processes=1)  # fmt: skip
    with Sitl(opts) as sitl:
        assert len({c.proc.pid for c in sitl.fcs}) == 1
        sitl.wait(timeout_s=60.0)
    for s in sitl.fc_summaries:
        assert s is not None and s["pipeline"]["why_not"] != "--jit off", s  # (a group may load the compiled pipeline)
        assert s["ticks"] >= 0.8 * 2.0 * 500 and s["sim_time_s"] >= 1.9, s  # each FC ticked on its own clock to the end
        assert s["rx_rejected"]["total"] == 0
    for tlog, sysid in zip(sitl.tlogs, (1, 2, 3)):  # each log its own vehicle's
        assert {m.get_srcSystem() for _, m in read_tlog(tlog) if m.get_type() == "ATTITUDE"} == {sysid}
    # the launcher spread the FCs' ticks over the period: the i-th of 3 a third of a period after the one before
    (group_file,) = tmp_path.glob("*fc-group1.json")
    phases = [float(args[args.index("--tick-phase") + 1]) for args in json.loads(group_file.read_text())]
    assert phases == pytest.approx([0.0, 1 / 3, 2 / 3], abs=1e-12)


@pytest.mark.parametrize("phase", ["1", "-0.1", "nan", "2.5"])
def test_fc_refuses_a_tick_phase_outside_the_period_in_one_line(tmp_path: Path, phase: str) -> None:
    r = subprocess.run([sys.executable, "-m", "fc", "--sim", "udpin:127.0.0.1:0", "--gcs", "none", "--log-dir", str(tmp_path),
                        "--tick-phase", phase], capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 2, r
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "--tick-phase must be a fraction of the period in [0, 1)" in lines[0], r.stderr


def test_fc_groups_split_the_vehicles_evenly() -> None:
    assert fc_groups(16, 2) == [list(range(8)), list(range(8, 16))]
    assert fc_groups(5, 2) == [[0, 1, 2], [3, 4]]
    assert fc_groups(2, 4) == [[0], [1]]
    for k in range(1, 20):
        for n in range(1, 6):
            groups = fc_groups(k, n)
            assert sum(groups, []) == list(range(k)) and max(map(len, groups)) - min(map(len, groups)) <= 1
    with pytest.raises(SwarmError, match="whole number >= 1"):
        fc_groups(3, 0)


def test_a_real_time_group_spreads_its_deadlines_over_the_period() -> None:
    """Of K FCs in one real-time loop the i-th ticks i/K of a period after the first, whenever
    it starts: the next deadline after now at its place on the beat (never now, never later than a period)."""
    from fc.group import beat_deadline

    period = 0.002
    beat = 100.0
    for k in (1, 3, 16):
        for start in (99.0, 100.0, 100.0007, 100.0013 + 1e-12, 123.4567):
            deadlines = [beat_deadline(start, beat, i / k, period) for i in range(k)]
            for i, d in enumerate(deadlines):
                assert start < d <= start + period + 1e-12
                n = (d - beat - i / k * period) / period  # on its own beat: a whole number of periods
                assert abs(n - round(n)) < 1e-6, (k, start, i, n)
            # one of each place on the beat, a period between a place and the same place again
            offsets = sorted(((d - beat) / period) % 1.0 for d in deadlines)
            assert all(abs(o - round(o * k) / k) < 1e-6 for o in offsets) and len({round(o * k) % k for o in offsets}) == k
    assert beat_deadline(beat, beat, 0.0, period) == pytest.approx(beat + period)  # the first FC: a period from its first state


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        ("not json", "Expecting value"),
        ("[]", "non-empty JSON list"),
        ('[["--lockstep"], ["--sim", "udpin:127.0.0.1:0"]]', "some flight controllers are lockstep and some real time"),
    ],
)
def test_fc_group_refuses_a_bad_file_in_one_line(tmp_path: Path, content: str, needle: str) -> None:
    f = tmp_path / "group.json"
    f.write_text(content)
    r = subprocess.run([sys.executable, "-m", "fc.group", str(f)], capture_output=True, text=True, timeout=60, check=False)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("fc.group: error: ") and needle in lines[0], r.stderr


@pytest.mark.slow
def test_a_lockstep_swarm_is_deterministic(tmp_path: Path) -> None:
    sc = swarm_scenario(tmp_path, count=3, duration=2.0, extra="[environment]\nnoise = true\ngust_std_n = 0.5\n")
    a = fly(sc, tmp_path / "a", "run")
    b = fly(sc, tmp_path / "b", "run")
    assert [p.read_bytes() for p in a.tlogs] == [p.read_bytes() for p in b.tlogs]
    assert len({p.read_bytes() for p in a.tlogs}) == 3  # and the vehicles' noise streams differ


@pytest.mark.slow
def test_two_vehicles_that_touch_both_crash(tmp_path: Path) -> None:
    # vehicle 2 spawns 3 m east of vehicle 1 and flies 3 m west in its own frame: onto vehicle 1
    sc = swarm_scenario(tmp_path, count=2, duration=8.0, extra=CONTACT_VEHICLES, swarm_keys="spacing_m = 3.0")
    sitl = fly(sc, tmp_path, "contact")
    sim = sitl.sim_summary
    assert sim is not None
    prox = sim["proximity"]
    assert [c["vehicles"] for c in prox["contacts"]] == [[1, 2]]
    assert prox["events"] and prox["events"][0]["t_s"] <= prox["contacts"][0]["t_s"]
    assert [v["crashed"] for v in sim["vehicles"]] == [True, True]
    for tlog, other in zip(sitl.tlogs, (2, 1)):
        texts = [m.text for _, m in read_tlog(tlog) if m.get_type() == "STATUSTEXT"]
        assert any(f"SIM: contact with vehicle {other}" in t for t in texts), texts
        assert any("within" in t for t in texts), texts


@pytest.mark.slow
def test_a_dead_vehicle_ends_a_lockstep_swarm_naming_it(tmp_path: Path) -> None:
    sc = swarm_scenario(tmp_path, count=3, duration=600.0)
    opts = SitlOptions(scenario=sc, timed=True, lockstep=True, gcs=None, speed=2.0, tlog=tmp_path / "dead.tlog",
                       log_dir=tmp_path, watchdog_s=10.0)  # fmt: skip
    lines: list[str] = []
    with Sitl(opts, echo=lines.append) as sitl:
        os.kill(sitl.fcs[1].proc.pid, signal.SIGKILL)
        with pytest.raises(SitlError, match="fc2 was killed by SIGKILL"):
            sitl.wait(timeout_s=60.0)
    assert sitl.sim is not None and sitl.sim.proc.returncode == 3
    assert any("the flight controller of vehicle 2" in ln for ln in lines), lines[-10:]
    for tlog in (sitl.tlogs[0], sitl.tlogs[2]):  # the others' logs are whole
        assert any(m.get_type() == "SYS_STATUS" for _, m in read_tlog(tlog))


@pytest.mark.slow
def test_a_dead_group_ends_a_lockstep_swarm_naming_a_vehicle_of_it(tmp_path: Path) -> None:
    """Vehicles 1-2 in one FC process, 3 in another: killing the first loses both of its vehicles;
    the run ends naming one of them, and vehicle 3's log is whole."""
    sc = swarm_scenario(tmp_path, count=3, duration=600.0)
    opts = SitlOptions(scenario=sc, timed=True, lockstep=True, gcs=None, speed=2.0, tlog=tmp_path / "dead.tlog",
                       log_dir=tmp_path, watchdog_s=10.0, fc_processes=2)  # fmt: skip
    lines: list[str] = []
    with Sitl(opts, echo=lines.append) as sitl:
        assert sitl.fcs[0].proc is sitl.fcs[1].proc is not sitl.fcs[2].proc
        os.kill(sitl.fcs[1].proc.pid, signal.SIGKILL)
        with pytest.raises(SitlError, match="fc[12] was killed by SIGKILL"):
            sitl.wait(timeout_s=60.0)
    assert sitl.sim is not None and sitl.sim.proc.returncode == 3
    assert any(re.search(r"the flight controller of vehicle [12]\b", ln) for ln in lines), lines[-10:]
    assert any(m.get_type() == "SYS_STATUS" for _, m in read_tlog(sitl.tlogs[2]))  # the other process's log is whole
    assert sitl.fc_summaries[2] is not None


@pytest.mark.slow
@pytest.mark.parametrize("lost", ["stop", "hold", "remove"])
def test_a_dead_vehicle_in_real_time_leaves_the_others_flying(tmp_path: Path, lost: str) -> None:
    sc = swarm_scenario(tmp_path, count=2, duration=4.0, swarm_keys=f"lost = {lost!r}".replace("'", '"'))
    opts = SitlOptions(scenario=sc, timed=True, lockstep=False, gcs=None, tlog=tmp_path / "rt.tlog", log_dir=tmp_path,
                       watchdog_s=1.0)  # fmt: skip
    lines: list[str] = []
    with Sitl(opts, echo=lines.append) as sitl:
        time.sleep(0.5)
        os.kill(sitl.fcs[1].proc.pid, signal.SIGKILL)
        with pytest.raises(SitlError, match="fc2 was killed"):
            sitl.wait(timeout_s=60.0)
    fate = {"stop": "its motors stop", "hold": "holds its last motor commands", "remove": "leaves the world"}[lost]
    assert any("vehicle 2" in ln and fate in ln and "fly on" in ln for ln in lines), lines[-10:]
    fc1 = sitl.fc_summaries[0]
    assert fc1 is not None and fc1["sim_time_s"] >= 3.5  # vehicle 1 flew to the end
    assert sitl.sim is not None and sitl.sim.proc.returncode == 0


@pytest.mark.slow
@pytest.mark.parametrize("fc_processes", [None, 1], ids=["own-processes", "one-group"])
def test_a_station_on_one_ground_address_flies_one_vehicle_of_the_swarm(tmp_path: Path, fc_processes: int | None) -> None:
    sc = swarm_scenario(tmp_path, count=2, duration=600.0).with_changes(plan=())
    ground_port = _free_port()
    opts = SitlOptions(scenario=sc, timed=False, lockstep=True, speed=3.0, gcs=f"udp:127.0.0.1:{ground_port}",
                       tlog=tmp_path / "gs.tlog", log_dir=tmp_path, watchdog_s=10.0, fc_processes=fc_processes)  # fmt: skip
    with Sitl(opts) as sitl:
        assert sitl.router is not None and sitl.gcs_address is not None
        with Swarm(f"udpout:{sitl.gcs_address}", [1, 2], connect_timeout_s=20) as swarm:
            # a hostile station: arm requests to a system no vehicle has, and a disarm to everyone
            mav = mavlink.MAVLink(None, srcSystem=250, srcComponent=190)
            host, port = sitl.gcs_address.rsplit(":", 1)
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as hostile:
                for target in (9, 200):
                    hostile.sendto(mav.command_long_encode(target, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav),
                                   (host, int(port)))  # fmt: skip
            swarm[2].arm()
            swarm[2].takeoff(2.0)
            swarm[2].wait_altitude(2.0, tol_m=0.3, timeout_sim_s=20)
            swarm[1].sleep_sim(1.0)
            assert not swarm[1].armed and swarm[2].armed
            alt1 = swarm[1].altitude_m
            assert alt1 is not None and abs(alt1) < 0.1
        # `smcpilot gcs status` on the one address lists every vehicle
        r = smcpilot("gcs", "--connect", f"udpout:{sitl.gcs_address}", "--timeout", "20", "status", cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        assert "2 vehicles: system ids 1, 2" in r.stdout and "vehicle 2: " in r.stdout and "ARMED" in r.stdout, r.stdout
        sitl.terminate()
    r = sitl.router_summary
    assert r is not None and r["no_such_vehicle"] >= 2 and set(r["vehicles"]) == {"1", "2"}


@pytest.mark.slow
@pytest.mark.interop
def test_mavsdk_sees_three_systems_on_one_connection_and_flies_one(tmp_path: Path) -> None:
    mavsdk = pytest.importorskip("mavsdk", reason="MAVSDK-Python not installed (pip install mavsdk)")
    from mavsdk.plugins.action import Action
    from mavsdk.plugins.telemetry import Telemetry

    port = _free_port()
    sc = swarm_scenario(tmp_path, count=3, duration=600.0).with_changes(plan=())
    opts = SitlOptions(scenario=sc, timed=False, lockstep=True, speed=2.0, gcs=f"udp:127.0.0.1:{port}", tlog=tmp_path / "mavsdk.tlog",
                       log_dir=tmp_path, watchdog_s=10.0)  # fmt: skip
    with Sitl(opts) as sitl:
        drone = mavsdk.Mavsdk(mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.GROUND_STATION))
        try:
            assert drone.add_any_connection(f"udpin://127.0.0.1:{port}") == mavsdk.ConnectionResult.SUCCESS
            deadline = time.monotonic() + 20
            while len([s for s in drone.get_systems() if s.has_autopilot()]) < 3:
                assert time.monotonic() < deadline, f"MAVSDK saw {drone.system_count()} systems"
                time.sleep(0.2)
            systems = {s.get_system_id(): s for s in drone.get_systems() if s.has_autopilot()}
            assert sorted(systems) == [1, 2, 3]
            tels = {sid: Telemetry(s) for sid, s in systems.items()}
            deadline = time.monotonic() + 20
            while not tels[2].health_all_ok():
                assert time.monotonic() < deadline, f"MAVSDK health of system 2 never all ok: {tels[2].health()}"
                time.sleep(0.2)
            act = Action(systems[2])
            act.set_takeoff_altitude(2.0)
            act.arm()
            act.takeoff()
            deadline = time.monotonic() + 30
            while not (tels[2].in_air() and tels[2].position().relative_altitude_m > 1.7):
                assert time.monotonic() < deadline, f"no take-off of system 2 seen by MAVSDK: {tels[2].position()}"
                time.sleep(0.2)
            assert not tels[1].armed() and not tels[3].armed()
            assert tels[1].position().relative_altitude_m < 0.2 and tels[3].position().relative_altitude_m < 0.2
        finally:
            drone.destroy()
        sitl.terminate()
    r = sitl.router_summary
    assert r is not None and set(r["vehicles"]) == {"1", "2", "3"}


# -- in-process ----------------------------------------------------------------------------------------


def _motors(tlog: Path) -> list[tuple[float, ...]]:
    return [tuple(m.controls[:4]) for _, m in read_tlog(tlog) if m.get_type() == "HIL_ACTUATOR_CONTROLS"]


def test_smcpilot_run_flies_a_swarm_in_process(tmp_path: Path) -> None:
    sc = swarm_scenario(tmp_path, count=3, duration=7.0, extra=CONTACT_VEHICLES, swarm_keys="spacing_m = 3.0")
    path = tmp_path / "contact.toml"
    sc.with_changes(name="contact").save(path)
    r = smcpilot("run", path, "--out", tmp_path / "out", "--no-plots", "--json", tmp_path / "r.json", "--quiet", cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "3 vehicles, 3501 ticks each" in r.stdout and "CONTACT: 1-2 at" in r.stdout, r.stdout
    import json

    doc = json.loads((tmp_path / "r.json").read_text())
    assert [v["sysid"] for v in doc["vehicles"]] == [1, 2, 3] and doc["proximity"]["contacts"][0]["vehicles"] == [1, 2]
    crashed = [v["metrics"]["crashed"] for v in doc["vehicles"]]
    assert crashed[:2] == [True, True] and not crashed[2]
    for sid in (1, 2, 3):
        assert len(_motors(tmp_path / "out" / f"contact-v{sid}.tlog")) == 3501


@pytest.mark.parametrize("fc_processes", [
    pytest.param(None, marks=pytest.mark.slow, id="a-process-each"),
    pytest.param(1, id="one-spinning-group-states-sent-ahead"),
])
def test_in_process_swarm_gives_sitls_motor_commands_tick_for_tick_contact_included(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fc_processes: int | None,
) -> None:  # fmt: skip
    """The same contact, the same motor commands tick for tick, in process and in SITL: with a
    process per FC (the simulator waits for every answer), and with one spinning group (the
    simulator sends each vehicle its next state ahead of the slowest and checks the separation
    when all have reached a state, before any flies on)."""
    from ground.sitl import Sitl
    from lab.swarm_run import fly_swarm

    if fc_processes is not None:
        monkeypatch.setattr(Sitl, "_spinning", lambda self: True)  # (whatever this machine's cores)
    sc = swarm_scenario(tmp_path, count=3, duration=7.0, extra=CONTACT_VEHICLES + "[environment]\nnoise = true\ngust_std_n = 0.3\n",
                        swarm_keys="spacing_m = 3.0")  # fmt: skip
    ip = fly_swarm(sc, tmp_path / "ip")
    st = fly_swarm(sc, tmp_path / "st", sitl=True, fc_processes=fc_processes)
    assert ip.status == st.status == "ok"
    assert ip.proximity["contacts"] and ip.proximity["contacts"] == st.proximity["contacts"]
    for a, b in zip(ip.vehicles, st.vehicles):
        ma, mb = _motors(a.tlog), _motors(b.tlog)
        assert len(ma) == len(mb) == 3501
        assert ma == mb


# -- swarm missions -----------------------------------------------------------------------------------
PAIR_MISSION = """
name = "pair"
[sitl]
count = 2
spacing_m = 5.0
max_duration_s = 60.0

[[item]]
type = "takeoff"
alt_m = 2.0
[[item]]
type = "waypoint"
north_m = 3.0
east_m = 0.0
alt_m = 2.0
[[item]]
type = "land"

[[expect]]
kind = "landed"
[[expect]]
kind = "separation"
min_m = {min_m}

[[vehicle]]
[[vehicle]]
[[vehicle.item]]
type = "takeoff"
alt_m = 3.0
[[vehicle.item]]
type = "land"
[[vehicle.expect]]
kind = "reach"
item = 1
within_m = 0.3
by_s = 20.0
"""


def test_swarm_mission_files_parse_per_vehicle_items_and_expectations() -> None:
    import tomllib

    from ground.missions import parse_mission
    from ground.missions.errors import MissionFileError

    m = parse_mission(tomllib.loads(PAIR_MISSION.format(min_m=3.0)), source="pair.toml")
    assert m.count == 2 and m.separation_min_m == (3.0,)
    v1, v2 = m.for_vehicle(0), m.for_vehicle(1)
    assert len(v1.items) == 3 and [e.kind for e in v1.expectations] == ["landed"]
    assert len(v2.items) == 2 and [(e.kind, e.number) for e in v2.expectations] == [("landed", 1), ("reach", 2)]
    assert m.sitl.scenario("pair").count == 2
    for doc, needle in (
        (PAIR_MISSION.format(min_m=3.0).replace("count = 2", "count = 1"), "needs a swarm"),
        (PAIR_MISSION.format(min_m=3.0) + "[[vehicle]]\n", "3 [[vehicle]] tables for [sitl] count = 2"),
        (PAIR_MISSION.format(min_m=3.0).replace("[[vehicle.expect]]", "[[vehicle.expectt]]"), "expectt"),
        (PAIR_MISSION.format(min_m=3.0).replace("kind = \"landed\"", "kind = \"reach\"\nitem = 3\nwithin_m = 1.0\nby_s = 9.0"),
         "item 3"),
        (PAIR_MISSION.format(min_m=0.0), "min_m"),
        (PAIR_MISSION.format(min_m=3.0).replace("count = 2", "count = 99"), "1..64"),
    ):
        with pytest.raises(MissionFileError) as info:
            parse_mission(tomllib.loads(doc), source="pair.toml")
        assert needle in str(info.value), str(info.value)


@pytest.mark.slow
@pytest.mark.parametrize(("min_m", "code"), [(3.0, 0), (6.0, 1)])
def test_a_swarm_mission_flies_each_vehicle_its_mission_and_judges_the_separation(tmp_path: Path, min_m: float, code: int) -> None:
    import json

    (tmp_path / "pair.toml").write_text(PAIR_MISSION.format(min_m=min_m), encoding="utf-8")
    r = smcpilot("mission", "run", "pair.toml", "--no-plots", "--json", "r.json", cwd=tmp_path)
    assert r.returncode == code, r.stdout[-3000:] + r.stderr
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["count"] == 2 and set(doc["vehicles"]) == {"1", "2"}
    assert all(v["passed"] for v in doc["vehicles"].values())  # each vehicle's own expectations held
    sep = doc["separation"][0]
    assert sep["measured_m"] == pytest.approx(5.0, abs=0.2) and sep["passed"] is (code == 0)
    assert ("separation >= 6 m: closest" in r.stdout) is (code == 1)


@pytest.mark.slow
def test_signing_holds_end_to_end_through_the_router(tmp_path: Path) -> None:
    key_file = tmp_path / "swarm.key"
    key_file.write_text("correct horse battery staple\n", encoding="utf-8")
    sc = swarm_scenario(tmp_path, count=2, duration=600.0).with_changes(plan=())
    opts = SitlOptions(scenario=sc, timed=False, lockstep=True, speed=3.0, gcs="udpin:127.0.0.1:0", tlog=tmp_path / "signed.tlog",
                       log_dir=tmp_path, watchdog_s=10.0, signing_key=key_file)  # fmt: skip
    with Sitl(opts) as sitl:
        assert sitl.gcs_address is not None
        host, port = sitl.gcs_address.rsplit(":", 1)
        with Swarm(f"udpout:{sitl.gcs_address}", [1, 2], connect_timeout_s=20, signing_key=key_file) as swarm:
            # an unsigned station's arm request reaches the vehicle (routed) and is dropped there; sent once
            # the swarm is connected: the router has heard both vehicles (before, it had no route to drop it by)
            mav = mavlink.MAVLink(None, srcSystem=250, srcComponent=190)
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
                stranger.sendto(mav.command_long_encode(2, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav),
                                (host, int(port)))  # fmt: skip
            swarm[2].sleep_sim(0.5)
            assert not swarm[2].armed  # the stranger did not arm it
            swarm[2].arm()  # a signed command through the router: accepted (signature intact)
            assert swarm[2].armed and not swarm[1].armed
        sitl.terminate()
    fc2 = sitl.fc_summaries[1]
    assert fc2 is not None and fc2["links"]["gcs"]["rx_unsigned"] >= 1 and fc2["links"]["gcs"]["rx_bad_signature"] == 0


@pytest.mark.slow
def test_an_in_process_swarm_of_a_law_that_measures_acceleration_matches_sitl(tmp_path: Path) -> None:
    from lab.swarm_run import fly_swarm

    sc = swarm_scenario(tmp_path, count=2, duration=3.0, extra="[environment]\nnoise = true\n").with_changes(controller="indi")
    ip = fly_swarm(sc, tmp_path / "ip")
    st = fly_swarm(sc, tmp_path / "st", sitl=True)
    for a, b in zip(ip.vehicles, st.vehicles):
        assert _motors(a.tlog) == _motors(b.tlog) and len(_motors(a.tlog)) == 1501


def _mavproxy() -> list[str] | None:
    """How to run MAVProxy: $SMCPILOT_MAVPROXY (a mavproxy.py, e.g. in a virtual environment of its
    own: it pulls in vtk and opencv), else mavproxy.py on the PATH; None when there is none."""
    import shutil

    exe = os.environ.get("SMCPILOT_MAVPROXY") or shutil.which("mavproxy.py")
    if not exe:
        return None
    python = Path(exe).with_name("python")
    return [str(python), exe] if python.exists() else [exe]


@pytest.mark.slow
@pytest.mark.interop
def test_mavproxy_flies_one_vehicle_of_three_with_vehicle_n(tmp_path: Path) -> None:
    cmd = _mavproxy()
    if cmd is None:
        pytest.skip("MAVProxy not found (set SMCPILOT_MAVPROXY to a mavproxy.py, or put it on the PATH)")
    port = _free_port()
    sc = swarm_scenario(tmp_path, count=3, duration=600.0).with_changes(plan=())
    opts = SitlOptions(scenario=sc, timed=False, lockstep=True, speed=1.0, gcs=f"udp:127.0.0.1:{port}", tlog=tmp_path / "mp.tlog",
                       log_dir=tmp_path, watchdog_s=10.0)  # fmt: skip
    with Sitl(opts) as sitl:
        mp = subprocess.Popen([*cmd, f"--master=udpin:127.0.0.1:{port}", "--nowait", f"--state-basedir={tmp_path / 'mavproxy'}"],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)  # fmt: skip
        out: list[str] = []
        reader = threading.Thread(target=lambda: out.extend(line.rstrip() for line in mp.stdout), daemon=True)  # type: ignore[union-attr]
        reader.start()

        def wait_for(text: str, timeout_s: float = 30.0) -> None:
            deadline = time.monotonic() + timeout_s
            while not any(text in ln for ln in out):
                assert mp.poll() is None and time.monotonic() < deadline, f"MAVProxy never printed {text!r}:\n" + "\n".join(out[-30:])
                time.sleep(0.1)

        def say(line: str) -> None:
            assert mp.stdin is not None
            mp.stdin.write(line + "\n")
            mp.stdin.flush()

        try:
            for sid in (1, 2, 3):
                wait_for(f"Detected vehicle {sid}:1")
            say("vehicle 2")
            wait_for("Set vehicle 2")
            say("mode guided")
            say("arm throttle")
            wait_for("COMPONENT_ARM_DISARM: ACCEPTED")
            say("takeoff 2")
            wait_for("NAV_TAKEOFF: ACCEPTED")
            # watch the climb in simulated time from a second station on the router's own port
            from ground.vehicle import Vehicle

            assert sitl.gcs_address is not None
            with Vehicle(f"udpout:{sitl.gcs_address}", system_id=2, connect_timeout_s=20) as v2:
                v2.wait_altitude(2.0, tol_m=0.3, timeout_sim_s=20)
        finally:
            mp.kill()
            mp.wait(timeout=10)
        sitl.terminate()
    from ground.logs import load_log

    logs = {sid: load_log(t) for sid, t in zip(sitl.sysids, sitl.tlogs)}
    assert float(logs[2].alt_m.max()) > 1.5  # vehicle 2 climbed
    assert float(logs[1].alt_m.max()) < 0.1 and float(logs[3].alt_m.max()) < 0.1  # the others never left the ground


def test_bench_swarm_flies_both_layouts(tmp_path: Path) -> None:
    r = smcpilot("bench", "swarm", "--counts", "2", "--duration", "0.5", "--fc-processes", "0,1", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    rows = [ln.split() for ln in r.stdout.splitlines() if ln.split()[:1] == ["2"]]
    assert [row[1] for row in rows] == ["2", "1"], r.stdout  # FC processes: one each, then one group
    assert all(row[-1] == "0.000" for row in rows)  # zero skew in lockstep
    from lab.swarm_bench import default_layouts

    assert default_layouts(2) == "0,1,2" and default_layouts(1) == "0,1" and default_layouts(8) == "0,7,8"
    bad = smcpilot("bench", "swarm", "--fc-processes", "x", cwd=tmp_path)
    assert bad.returncode == 2 and "--fc-processes must be whole numbers" in bad.stderr
