"""Fuzzing every socket the FC and the simulator listen on, during a real lockstep SITL flight.

A seeded fuzzer sends, while the vehicle takes off and holds: random bytes, truncated MAVLink 1
and 2 frames, frames with a bad CRC, valid-CRC frames with NaN / ±inf / huge fields (position
targets, COMMAND_LONG/INT parameters, PARAM_SET values and 16-character names, MISSION_COUNT /
MISSION_ITEM out of range or sequence, REQUEST_DATA_STREAM and SET_MESSAGE_INTERVAL rates),
frames for other target systems, and a heartbeat flood (10 Hz from each of 50 source systems,
each on its own socket). The same flight is flown clean first. Then:

- the flight under fuzz is bit-identical to the clean one (every simulator state, motor command
  and per-tick controller record, by payload and time stamp);
- no NaN reached a motor command or the plant;
- every rejected packet is counted: the FC's exit summary by reason, ``SYS_STATUS``
  (errors_comm and errors_count1..4, as a ground station reads them) and the tlog (what
  ``smcpilot log summary`` shows);
- a ground station that sent a command keeps its telemetry through the flood.

The test prints packets sent by class, rejected by reason, and the loop figures (wall time per
tick, lockstep) fuzzed vs clean.
"""

from __future__ import annotations

import contextlib
import math
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from gcs_helpers import FC_SYSID, LOOPBACK, Gcs
from pymavlink.dialects.v20 import ardupilotmega as M
from sitl_helpers import write_plan

from ground.logs import load_log, summarize
from ground.sitl import Sitl, SitlOptions
from lab.flood import FloodSpec, Fuzzer, heartbeat_flood, send_flood, udp_ports
from smcpilot.protocol import SIM_COMPONENT_ID, Mode
from smcpilot.tlog import read_tlog

SEED = 20261202
DURATION_S = 8.0
SPEED = 1.0  # lockstep at real time: the fuzz is spread over the whole flight
PLAN = ({"t_s": 0.0, "action": "takeoff", "alt_m": 2.0}, {"t_s": 4.0, "action": "goto", "north_m": 1.0, "east_m": 0.5, "alt_m": 2.5})
FLOOD_SYSTEMS = 50
FLOOD_RATE_HZ = 10.0


# -- running a flight --------------------------------------------------------------------------------
@dataclass
class Run:
    tlog: Path
    fc_summary: dict
    sim_summary: dict
    wall_s: float
    gcs_sys_status: object | None
    friend_heartbeats: int
    friend_wall_s: float
    listener_heartbeats: int
    #: FC heartbeats heard by a station that only sends heartbeats (never a command).
    watcher_heartbeats: int
    #: the highest SYS_STATUS drop_rate_comm (c%) the configured destination saw.
    max_drop_rate: int


def flight_records(tlog: Path) -> list[tuple[int, int, bytes]]:
    """(time, message id, payload) of everything that makes the flight: the simulator's states,
    the FC's motor commands and per-tick controller records (sequence numbers left out)."""
    out = []
    for t_us, msg in read_tlog(tlog):
        mid = msg.get_msgId()
        if mid in (M.MAVLINK_MSG_ID_ATTITUDE, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED) and msg.get_srcComponent() != SIM_COMPONENT_ID:
            continue  # the FC's own telemetry to ground stations (its rate may be fuzzed)
        if mid in (M.MAVLINK_MSG_ID_ATTITUDE, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, M.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS,
                   M.MAVLINK_MSG_ID_DEBUG_FLOAT_ARRAY):  # fmt: skip
            out.append((t_us, mid, bytes(msg.get_msgbuf()[10:-2])))
    # a state the simulator sent again (its answer was late: a loaded machine) and the FC's
    # repeated answer are the same records at the same time: counted once
    return list(dict.fromkeys(out))


Fuzz = Callable[[Sitl, threading.Event, Callable[[], float]], None]


def fly(tmp_path: Path, name: str, fuzz: Fuzz | None, *, lockstep: bool = True) -> Run:
    run_dir = tmp_path / name
    run_dir.mkdir()
    plan = write_plan(run_dir / "plan.toml", PLAN)
    listener = Gcs()  # the FC's configured ground destination
    opts = SitlOptions.of(lockstep=lockstep, speed=SPEED if lockstep else None, duration_s=DURATION_S, plan=plan, gcs=f"udp:{LOOPBACK}:{listener.port}",
                          tlog=run_dir / "fc.tlog", param_file=run_dir / "fc.parm", log_dir=run_dir, watchdog_s=10.0)  # fmt: skip
    stop = threading.Event()
    friend: Gcs | None = None
    watcher: Gcs | None = None
    try:
        t0 = time.monotonic()
        with Sitl(opts, echo=lambda line: None) as sitl:
            host, port = sitl.gcs_address.rsplit(":", 1)  # type: ignore[union-attr]
            # a second station that found the FC itself and sent a command: it keeps its place
            friend = Gcs(f"udpout:{host}:{port}", sysid=254)
            friend.send_heartbeat()
            friend.send_command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
            # and one that only sends its 1 Hz heartbeat (it keeps its place by writing)
            watcher = Gcs(f"udpout:{host}:{port}", sysid=253)
            watcher.send_heartbeat()
            sim_s = lambda: listener.sim_ms / 1000.0  # noqa: E731 - the vehicle's clock, as the listener hears it
            worker = threading.Thread(target=fuzz, args=(sitl, stop, sim_s), daemon=True) if fuzz is not None else None
            if worker is not None:
                worker.start()
            f0 = time.monotonic()
            while sitl.poll() == (None, None):
                friend.pump(0.05)
                watcher.pump(0.0)
                listener.pump(0.0)
            friend_wall = time.monotonic() - f0
            stop.set()
            if worker is not None:
                worker.join(10)
            assert sitl.wait(timeout_s=30) == 0
            wall = time.monotonic() - t0
            for _ in range(5):
                listener.pump(0.02)
        fc_hb = [r for r in friend.log if r.msg.get_type() == "HEARTBEAT" and r.msg.get_srcSystem() == FC_SYSID]
        lis_hb = [r for r in listener.log if r.msg.get_type() == "HEARTBEAT" and r.msg.get_srcSystem() == FC_SYSID]
        wat_hb = [r for r in watcher.log if r.msg.get_type() == "HEARTBEAT" and r.msg.get_srcSystem() == FC_SYSID]
        drop = max((r.msg.drop_rate_comm for r in listener.log if r.msg.get_type() == "SYS_STATUS"), default=0)
        return Run(opts.tlog, sitl.fc_summary or {}, sitl.sim_summary or {}, wall, listener.last.get("SYS_STATUS"),
                   len(fc_hb), friend_wall, len(lis_hb), len(wat_hb), drop)  # type: ignore[arg-type]  # fmt: skip
    finally:
        stop.set()
        listener.close()
        for g in (friend, watcher):
            if g is not None:
                g.close()


def fuzz_all(fuzzer: Fuzzer, rate_hz: float = 400.0) -> Fuzz:
    """The fuzzing thread: hostile datagrams to the FC's ground and sim ports and the simulator's
    port at ``rate_hz`` in all, plus the heartbeat flood; it ends 1.5 simulated seconds before the
    flight does, so that everything sent arrives while every socket is open and the FC's last
    SYS_STATUS has counted it."""

    def run(sitl: Sitl, stop: threading.Event, sim_s: Callable[[], float]) -> None:
        assert sitl.gcs_address is not None and sitl.sim is not None
        gcs_host, gcs_port = sitl.gcs_address.rsplit(":", 1)
        targets = {"gcs": (gcs_host, int(gcs_port)), "fc_sim": (LOOPBACK, sitl.sim_port)}
        sim_ports = udp_ports(sitl.sim.proc.pid)
        assert len(sim_ports) == 1, sim_ports
        targets["sim"] = (LOOPBACK, sim_ports[0])
        flood = heartbeat_flood(FLOOD_SYSTEMS)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as out:
            out.bind((LOOPBACK, 0))
            period = 1.0 / rate_hz
            next_flood = time.monotonic()
            order = ("gcs", "gcs", "gcs", "fc_sim", "sim")
            n = 0
            end = time.monotonic() + (DURATION_S - 1.5) / SPEED  # (real time: the clock is the wall's)
            while not stop.is_set() and time.monotonic() < end and sim_s() < DURATION_S - 1.5:
                target = order[n % len(order)]
                n += 1
                with contextlib.suppress(OSError):
                    out.sendto(fuzzer.datagram(target), targets[target])
                now = time.monotonic()
                if now >= next_flood:
                    next_flood = now + 1.0 / FLOOD_RATE_HZ
                    for s, hb in flood:
                        with contextlib.suppress(OSError):
                            s.sendto(hb, targets["gcs"])
                        fuzzer.sent[("gcs", "heartbeat_flood")] += 1
                time.sleep(period)
        for s, _ in flood:
            s.close()

    return run


@pytest.fixture(scope="module")
def realtime_flights(tmp_path_factory: pytest.TempPathFactory) -> tuple[Run, Run, Fuzzer]:
    """The same flight in real time (500 Hz on the wall clock), clean and fuzzed: the loop figures."""
    tmp = tmp_path_factory.mktemp("fuzz-rt")
    fuzzer = Fuzzer(SEED + 1)
    clean = fly(tmp, "clean", None, lockstep=False)
    fuzzed = fly(tmp, "fuzzed", fuzz_all(fuzzer), lockstep=False)
    for label, r in (("clean", clean), ("fuzzed", fuzzed)):
        f = r.fc_summary
        late = [f.get(k) for k in ("lateness_p50_s", "lateness_p99_s", "lateness_max_s")]
        print(f"\nfuzz: real-time loop {label:6s}: {f.get('ticks')} ticks, {f.get('overruns')} overruns (missed deadlines),"
              f" lateness p50/p99/max {' / '.join('-' if v is None else f'{v * 1e3:.3f}' for v in late)} ms,"
              f" failsafe events {f.get('failsafe_events')}, rejected {f.get('rx_rejected', {}).get('total')}")  # fmt: skip
    return clean, fuzzed, fuzzer


@pytest.fixture(scope="module")
def flights(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Run, Run, Fuzzer]]:
    tmp = tmp_path_factory.mktemp("fuzz")
    fuzzer = Fuzzer(SEED)
    clean = fly(tmp, "clean", None)
    fuzzed = fly(tmp, "fuzzed", fuzz_all(fuzzer))
    print_report(clean, fuzzed, fuzzer)
    yield clean, fuzzed, fuzzer


def print_report(clean: Run, fuzzed: Run, fuzzer: Fuzzer) -> None:
    print("\nfuzz: packets sent by class (target, class):")
    for (target, cls), n in sorted(fuzzer.sent.items()):
        print(f"  {target:7s} {cls:22s} {n:6d}")
    print(f"  total {sum(fuzzer.sent.values())}")
    print("fuzz: rejected by reason (the FC's exit summary):")
    for reason, n in sorted(fuzzed.fc_summary.get("rx_rejected", {}).items()):
        print(f"  {reason:32s} {n:6d}")
    sim_link = fuzzed.sim_summary.get("link", {})
    print(f"fuzz: the simulator rejected rx_bad {sim_link.get('rx_bad')} rx_unknown {sim_link.get('rx_unknown')}"
          f" rx_foreign_system {sim_link.get('rx_foreign_system')}")  # fmt: skip
    for label, r in (("clean", clean), ("fuzzed", fuzzed)):
        ticks = r.fc_summary.get("ticks", 0)
        print(f"fuzz: loop {label:6s}: {ticks} ticks in {r.wall_s:.2f} wall s (lockstep x{SPEED:g} cap),"
              f" {1e6 * r.wall_s / max(ticks, 1):.0f} wall us per tick incl. start-up, overruns {r.fc_summary.get('overruns')},"
              f" FC heartbeats heard by a commanding station {r.friend_heartbeats} in {r.friend_wall_s:.1f} s,"
              f" by a heartbeat-only station {r.watcher_heartbeats}, by the configured destination {r.listener_heartbeats};"
              f" highest SYS_STATUS drop_rate_comm {r.max_drop_rate / 100:.2f} %")  # fmt: skip


# -- the checks -----------------------------------------------------------------------------------------
@pytest.mark.slow
def test_flight_under_fuzz_is_bit_identical_to_the_clean_one(flights) -> None:
    clean, fuzzed, _ = flights
    a, b = flight_records(clean.tlog), flight_records(fuzzed.tlog)
    assert len(a) > 3 * DURATION_S * 100
    assert len(a) == len(b)
    first_diff = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), None)
    assert first_diff is None, f"record {first_diff} differs: {a[first_diff]} vs {b[first_diff]}"


@pytest.mark.slow
def test_no_nan_reached_a_motor_or_the_plant(flights) -> None:
    _, fuzzed, _ = flights
    n = 0
    for _t, msg in read_tlog(fuzzed.tlog):
        if msg.get_type() == "HIL_ACTUATOR_CONTROLS":
            assert all(math.isfinite(c) and 0.0 <= c <= 1.0 for c in msg.controls[:4]), msg
            n += 1
        elif msg.get_type() in ("ATTITUDE", "LOCAL_POSITION_NED") and msg.get_srcComponent() == SIM_COMPONENT_ID:
            assert all(math.isfinite(v) for v in msg.to_dict().values() if isinstance(v, float)), msg
    assert n > DURATION_S * 400


@pytest.mark.slow
def test_every_rejected_packet_is_counted(flights) -> None:
    clean, fuzzed, fuzzer = flights
    sent = fuzzer.sent
    rej = fuzzed.fc_summary["rx_rejected"]
    gcs = fuzzed.fc_summary["links"]["gcs"]
    sim = fuzzed.fc_summary["links"]["sim"]
    framing = ("garbage", "truncated_v1", "truncated_v2", "bad_crc")
    # bad frames: each datagram is at least one bad run (a garbage datagram may hold several)
    assert gcs["rx_bad"] + gcs["rx_unknown"] >= sum(sent[("gcs", k)] for k in framing)
    assert sim["rx_bad"] + sim["rx_unknown"] >= sum(sent[("fc_sim", k)] for k in framing)
    assert sim["rx_foreign_system"] >= 2 * sent[("fc_sim", "other_system")]  # ATTITUDE + LOCAL_POSITION_NED each
    sim_link = fuzzed.sim_summary["link"]
    assert sim_link["rx_bad"] + sim_link["rx_unknown"] >= sum(sent[("sim", k)] for k in framing)
    assert sim_link["rx_foreign_system"] >= sent[("sim", "other_system")]
    # valid-CRC hostile and foreign-target messages: each refused or dropped by the protocol
    accepted = ("heartbeat_flood", "request_data_stream_bounded")  # valid (a bounded request), not rejected
    hostile = sum(n for (t, cls), n in sent.items() if t == "gcs" and cls not in framing + accepted)
    protocol = sum(n for k, n in rej.items() if k.startswith("gcs.") and not k.startswith("gcs.rx_"))
    assert protocol >= hostile, (protocol, hostile)
    assert rej.get("gcs.other_system", 0) >= sent[("gcs", "other_system")]
    # the same totals reach a ground station (SYS_STATUS) and the log
    status = fuzzed.gcs_sys_status
    assert status is not None
    assert status.errors_count1 == gcs["rx_bad"] + gcs["rx_unknown"] + gcs["rx_foreign_system"]
    assert status.errors_count3 == protocol >= hostile
    assert status.errors_count4 == sim["rx_bad"] + sim["rx_unknown"] + sim["rx_foreign_system"]
    assert status.errors_count2 == 0  # no signing on this flight
    assert status.errors_comm == min(65535, status.errors_count1 + status.errors_count2 + status.errors_count3)
    logged = summarize(load_log(fuzzed.tlog))["comm_errors"]
    assert logged is not None and logged["errors_comm"] >= rej["total"] - rej.get("sim.rx_bad", 0) - rej.get(
        "sim.rx_unknown", 0) - rej.get("sim.rx_foreign_system", 0) - 1  # fmt: skip
    assert logged["errors_count4"] == min(65535, sim["rx_bad"] + sim["rx_unknown"] + sim["rx_foreign_system"])
    # the clean flight counts nothing
    assert clean.fc_summary["rx_rejected"] == {"total": 0}
    assert summarize(load_log(clean.tlog))["comm_errors"] == dict.fromkeys(("errors_comm", "drop_rate_comm", "errors_count1", "errors_count2", "errors_count3", "errors_count4"), 0)


@pytest.mark.slow
def test_a_station_that_commanded_keeps_its_telemetry_through_the_heartbeat_flood(flights) -> None:
    clean, fuzzed, fuzzer = flights
    assert fuzzer.sent[("gcs", "heartbeat_flood")] >= FLOOD_SYSTEMS * FLOOD_RATE_HZ * DURATION_S * 0.5
    # the FC's heartbeat is 1 Hz of simulated time: the station hears (nearly) all of them, as in
    # the clean flight (a station that only sends heartbeats keeps its place while the FC keeps up
    # with the flood; under overload its heartbeats can be lost in the socket buffer: printed only)
    assert fuzzed.friend_heartbeats >= DURATION_S - 2.0, (fuzzed.friend_heartbeats, fuzzed.friend_wall_s)
    assert fuzzed.friend_heartbeats >= clean.friend_heartbeats - 2
    assert fuzzed.fc_summary["links"]["gcs"]["peers_rejected"] > 0  # the flood was refused places


@pytest.mark.slow
def test_drop_rate_is_reported_while_the_fuzz_lasts(flights) -> None:
    clean, fuzzed, _ = flights
    assert clean.max_drop_rate == 0
    assert 0 < fuzzed.max_drop_rate <= 10000


# -- what other branches deliver -----------------------------------------------------------------------
@pytest.mark.slow
def test_huge_finite_targets_and_other_components_are_not_flown(tmp_path: Path) -> None:
    enc = M.MAVLink(None, srcSystem=250, srcComponent=190)
    packets = [
        enc.set_position_target_local_ned_encode(0, FC_SYSID, 1, M.MAV_FRAME_LOCAL_NED, 0xDF8, 1e30, 0, -2, 0, 0, 0, 0, 0, 0, 0, 0),
        enc.set_position_target_global_int_encode(0, FC_SYSID, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0xDF8, 2**31 - 1, 0, 2, 0, 0, 0, 0, 0, 0, 0, 0),  # fmt: skip
        enc.set_position_target_local_ned_encode(0, FC_SYSID, 99, M.MAV_FRAME_LOCAL_NED, 0xDF8, 3, 3, -3, 0, 0, 0, 0, 0, 0, 0, 0),
        enc.command_long_encode(FC_SYSID, 1, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 1e30),
        enc.command_long_encode(FC_SYSID, 1, M.MAV_CMD_DO_REPOSITION, 0, -1, 0, 0, 0, 89.0, 179.0, 1e30),
    ]

    def send(sitl: Sitl, stop: threading.Event, sim_s: Callable[[], float]) -> None:
        assert sitl.gcs_address is not None
        host, port = sitl.gcs_address.rsplit(":", 1)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            while not stop.is_set():
                for p in packets:
                    s.sendto(p.pack(enc), (host, int(port)))
                time.sleep(0.05)

    clean = fly(tmp_path, "clean", None)
    fuzzed = fly(tmp_path, "huge", send)
    assert flight_records(fuzzed.tlog) == flight_records(clean.tlog)


@pytest.mark.slow
def test_valid_states_forged_from_another_address_are_not_flown(tmp_path: Path) -> None:
    forged = M.MAVLink(None, srcSystem=FC_SYSID, srcComponent=SIM_COMPONENT_ID)

    def send(sitl: Sitl, stop: threading.Event, sim_s: Callable[[], float]) -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            t_ms = 0
            while not stop.is_set():
                t_ms += 2
                data = forged.attitude_encode(t_ms, 0.6, 0.6, 0, 0, 0, 0).pack(forged)
                data += forged.local_position_ned_encode(t_ms, 5, 5, -5, 0, 0, 0).pack(forged)
                s.sendto(data, (LOOPBACK, sitl.sim_port))
                time.sleep(0.01)

    clean = fly(tmp_path, "clean", None)
    fuzzed = fly(tmp_path, "forged", send)
    assert flight_records(fuzzed.tlog) == flight_records(clean.tlog)


@pytest.mark.slow
def test_real_time_loop_under_fuzz_keeps_flying_and_counts_everything(realtime_flights) -> None:
    """Real time: the figures are printed (speed is measured, not asserted); the checks are that
    the fuzzed flight kept its motors finite, ended cleanly and counted what it rejected."""
    clean, fuzzed, fuzzer = realtime_flights
    for r in (clean, fuzzed):
        f = r.fc_summary
        assert f.get("ticks", 0) + f.get("overruns", 0) >= 0.9 * DURATION_S * 500  # every period ticked or counted late
        for _t, msg in read_tlog(r.tlog):
            if msg.get_type() == "HIL_ACTUATOR_CONTROLS":
                assert all(math.isfinite(c) and 0.0 <= c <= 1.0 for c in msg.controls[:4]), msg
    framing = ("garbage", "truncated_v1", "truncated_v2", "bad_crc")
    gcs = fuzzed.fc_summary["links"]["gcs"]
    b = fuzzed.fc_summary["gcs_budget"]
    # each bad datagram was parsed and counted bad, or dropped unparsed by the budget and counted there
    assert gcs["rx_bad"] + gcs["rx_unknown"] + b["dropped"] >= sum(fuzzer.sent[("gcs", k)] for k in framing)
    assert clean.fc_summary["rx_rejected"] == {"total": 0}
    # every datagram the loop took off the ground socket (and every one from a stranger on the sim
    # socket) went through the intake: handled, dropped, or still waiting at the end
    assert b["queued"] >= gcs["rx_datagrams"] > 0
    assert b["queued"] == b["handled"] + b["dropped"] + b["left"]
    assert clean.fc_summary["gcs_budget"]["dropped"] == 0
    assert fuzzed.fc_summary["gcs_budget"]["telemetry_peers_skipped"] > 0  # the heartbeat flood's strangers
    assert clean.fc_summary["gcs_budget"]["telemetry_peers_skipped"] == 0


# -- the loop first: a request flood the FC cannot keep up with ---------------------------------------
#: PARAM_REQUEST_LIST a second from one address (each costs the FC ~176 PARAM_VALUE): far more than
#: its ground-link budget affords, so the intake overflows and drops.
REQUEST_FLOOD_HZ = 1000.0
PARAM_LIST = M.MAVLink(None, srcSystem=250, srcComponent=190).param_request_list_encode(FC_SYSID, 1).pack(
    M.MAVLink(None, srcSystem=250, srcComponent=190))


#: PARAM_REQUEST_LIST packets per flood datagram: a list request is cheap since the FC streams
#: the table a chunk a tick, so each datagram carries many, to cost more than the budget affords.
REQUEST_FLOOD_PACKETS = 16


def request_flood(seconds: float, rate_hz: float = REQUEST_FLOOD_HZ) -> Fuzz:
    """Datagrams of :data:`REQUEST_FLOOD_PACKETS` PARAM_REQUEST_LISTs at ``rate_hz`` to the FC's
    ground port, plus the heartbeat flood."""

    def run(sitl: Sitl, stop: threading.Event, sim_s: Callable[[], float]) -> None:
        assert sitl.gcs_address is not None
        host, port = sitl.gcs_address.rsplit(":", 1)
        n = int(rate_hz * seconds)
        spec = FloodSpec(hostile=n, seconds=seconds, systems=FLOOD_SYSTEMS, heartbeat_hz=FLOOD_RATE_HZ)
        send_flood({"gcs": (host, int(port))}, [("gcs", PARAM_LIST * REQUEST_FLOOD_PACKETS)] * n, spec, stop)

    return run


@pytest.mark.slow
def test_mode_changes_and_a_disarm_sent_during_a_request_flood_are_answered_and_acted_on(tmp_path: Path) -> None:
    """Real time: a station changes mode twice (COMMAND_LONG and SET_MODE), arms and disarms while
    the FC is flooded with more requests than its ground-link budget affords. Every command is
    answered and acted on while the flood lasts, ahead of a request the station sent before them;
    the flood's requests are dropped (counted), nothing more important is."""
    station = Gcs()
    opts = SitlOptions.of(lockstep=False, duration_s=16.0, gcs=f"udp:{LOOPBACK}:{station.port}", tlog=tmp_path / "fc.tlog",
                          param_file=tmp_path / "fc.parm", log_dir=tmp_path, watchdog_s=10.0)  # fmt: skip
    stop = threading.Event()
    try:
        with Sitl(opts, echo=lambda line: None) as sitl:
            station.wait("HEARTBEAT", lambda m: m.get_srcSystem() == FC_SYSID, what="the FC's first heartbeat")
            flooder = threading.Thread(target=request_flood(10.0), args=(sitl, stop, lambda: 0.0), daemon=True)
            flooder.start()
            station.run_sim(1.0)  # the intake is full of requests by now
            mark = station.mark()
            station.mav.param_request_read_send(FC_SYSID, 1, b"RTL_ALT_M", -1)  # a request, before the commands
            station.set_mode(Mode.ALT_HOLD)
            station.wait_mode(Mode.ALT_HOLD, sim_timeout_s=10.0)
            station.mav.set_mode_send(FC_SYSID, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, Mode.GUIDED)
            station.check_ack(station.ack(M.MAVLINK_MSG_ID_SET_MODE, mark), M.MAV_RESULT_ACCEPTED)
            station.wait_mode(Mode.GUIDED, sim_timeout_s=10.0)
            station.arm()
            station.wait("HEARTBEAT", lambda m: m.get_srcSystem() == FC_SYSID and m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED,
                         sim_timeout_s=10.0, what="armed HEARTBEAT")  # fmt: skip
            station.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0)
            station.wait_disarmed(sim_timeout_s=10.0)
            assert flooder.is_alive(), "the flood ended before the commands were answered: it proves nothing"
            flooder.join(30)
            assert sitl.wait(timeout_s=60) == 0
            summary = sitl.fc_summary or {}
    finally:
        stop.set()
        station.close()
    types = [r.msg.get_type() for r in station.log[mark:]]
    first_ack = types.index("COMMAND_ACK")
    read = [i for i, r in enumerate(station.log[mark:]) if r.msg.get_type() == "PARAM_VALUE" and r.msg.param_id == "RTL_ALT_M"]
    assert not read or read[0] > first_ack, "the request sent first was handled before the command"
    b = summary["gcs_budget"]
    by = b["by_class"]
    print(f"\nrequest flood: FC {summary['ticks']} ticks, {summary['overruns']} overruns, lateness p99"
          f" {summary['lateness_p99_s'] * 1e3:.3f} ms; ground link {b}")  # fmt: skip
    assert by["critical"]["handled"] >= 4 and by["critical"]["dropped"] == 0
    assert by["request"]["dropped"] > 0  # the flood overflowed the intake: its requests were dropped...
    assert all(v["dropped"] == 0 for name, v in by.items() if name in ("critical", "command", "heartbeat"))  # ...nothing better
    assert b["deferred"] > 0 and b["periods_out_of_budget"] > 0
    assert b["queued"] == b["handled"] + b["dropped"] + b["left"]


@pytest.mark.slow
def test_lockstep_flight_under_a_request_flood_is_bit_identical_to_the_clean_one(tmp_path: Path) -> None:
    clean = fly(tmp_path, "clean", None)
    flooded = fly(tmp_path, "flooded", request_flood(DURATION_S - 1.5, rate_hz=200.0))
    a, b = flight_records(clean.tlog), flight_records(flooded.tlog)
    assert len(a) > 3 * DURATION_S * 100
    assert a == b
    budget = flooded.fc_summary["gcs_budget"]
    assert budget["by_class"]["request"]["handled"] > 0 and budget["dropped"] == 0  # lockstep: every one handled


# -- the defences one by one, in process (the ground protocol handler with a fake link) ------------
def _handler_with_clock():
    from test_modes import _core, _handler

    core = _core()
    h, link, events, _ = _handler(core)
    now = [100.0]
    h.wall_s = lambda: now[0]
    return core, h, link, events, now


def _cmd(h, command: int, *params: float, src: tuple[int, int] = (255, 190), addr=("127.0.0.1", 14550)) -> None:
    p = list(params) + [0.0] * (7 - len(params))
    msg = M.MAVLink_command_long_message(1, 1, command, 0, *p)
    msg._header = M.MAVLink_header(msg.id, srcSystem=src[0], srcComponent=src[1])
    h.handle(msg, addr)


def test_message_intervals_are_bounded() -> None:
    from fc.streams import MAX_INTERVAL_US, MAX_STREAM_RATE_HZ, MIN_INTERVAL_US

    _core, h, link, events, _now = _handler_with_clock()
    hb = M.MAVLINK_MSG_ID_HEARTBEAT
    for interval in (1e30, 5e6, -1.0):  # the heartbeat: never slower than 1 Hz, never off
        _cmd(h, M.MAV_CMD_SET_MESSAGE_INTERVAL, hb, interval)
        assert link.to[-1][0].result == M.MAV_RESULT_DENIED
    assert h.streams.interval_us[hb] == 1_000_000
    _cmd(h, M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, MAX_INTERVAL_US * 2)
    assert link.to[-1][0].result == M.MAV_RESULT_DENIED
    _cmd(h, M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, 1)  # faster than we stream: the fastest
    assert link.to[-1][0].result == M.MAV_RESULT_ACCEPTED and h.streams.interval_us[M.MAVLINK_MSG_ID_ATTITUDE] == MIN_INTERVAL_US
    rds = M.MAVLink_request_data_stream_message(1, 1, M.MAV_DATA_STREAM_ALL, 65535, 1)
    rds._header = M.MAVLink_header(rds.id, srcSystem=255, srcComponent=190)
    h.handle(rds, ("127.0.0.1", 14550))
    assert min(v for v in h.streams.interval_us.values() if v > 0) == int(1e6 / MAX_STREAM_RATE_HZ)  # a group: ArduPilot's 50 Hz
    assert h.rejected["bad_interval"] == 3 + 1


def test_refusal_texts_are_rate_limited_per_reason_whoever_asks() -> None:
    from fc.gcs import REFUSAL_TEXT_BURST, REFUSAL_TEXT_RATE_HZ

    _core, h, link, events, now = _handler_with_clock()
    n0 = len(events)
    for i in range(400):  # 400 bad requests in a second, from 400 stations
        _cmd(h, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0, addr=("127.0.0.1", 20000 + i))
        _cmd(h, M.MAV_CMD_DO_SET_MODE, 1, 12345 + i, addr=("127.0.0.1", 20000 + i))  # distinct reasons
    texts = events[n0:]
    assert len(texts) <= REFUSAL_TEXT_BURST, texts  # in all, whoever asked
    assert sum("Takeoff" in t for _, t in texts) == 1
    assert len([m for m, _ in link.to if m.get_type() == "COMMAND_ACK"]) == 800  # every request still answered
    assert h.rejected["command_refused"] == 800 and h.texts_suppressed == 800 - len(texts)
    now[0] += 1.0
    _cmd(h, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0)
    assert events[-1][1] == "Takeoff: arm first"  # a second later: said again
    n1 = len(events)
    for i in range(400):  # the next second of the flood: the bucket's refill only
        now[0] += 1.0 / 400
        _cmd(h, M.MAV_CMD_DO_SET_MODE, 1, 50000 + i)
    assert len(events) - n1 <= 2 * REFUSAL_TEXT_RATE_HZ  # (the refill of the second before, and of this one)


def test_an_abandoned_mission_upload_does_not_block_another_station() -> None:
    from fc.mission import ABANDONED_UPLOAD_S

    _core, h, _link, _events, now = _handler_with_clock()
    link = _link
    h.mission._send_to = lambda msg, addr: link.to.append((msg, addr))
    a, b = ("127.0.0.1", 1111), ("127.0.0.1", 2222)

    def count(addr, n: int) -> None:
        msg = M.MAVLink_mission_count_message(1, 1, n, 0)
        msg._header = M.MAVLink_header(msg.id, srcSystem=255, srcComponent=190)
        h.handle(msg, addr)

    count(a, 3)  # station a starts an upload and goes away
    count(b, 2)
    assert link.to[-1][0].get_type() == "MISSION_ACK" and link.to[-1][0].type == M.MAV_MISSION_DENIED  # a is busy
    now[0] += ABANDONED_UPLOAD_S + 0.1
    count(b, 2)
    acks = [(m, addr) for m, addr in link.to if m.get_type() == "MISSION_ACK"]
    assert acks[-1][1] == a and acks[-1][0].type == M.MAV_MISSION_OPERATION_CANCELLED
    req, to = link.to[-1]
    assert req.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST") and req.seq == 0 and to == b
    assert h.mission.refused == 2  # the denial and the cancellation


def test_setup_signing_is_refused_while_armed_and_from_untrusted_unsigned_senders() -> None:
    from smcpilot.signing import Signing

    core, h, _link, events, _now = _handler_with_clock()
    h.signing = Signing(None)
    key = list(range(1, 33))

    def setup(k: list[int], signed: bool = False) -> None:
        msg = M.MAVLink_setup_signing_message(1, 1, k, 0)
        msg._header = M.MAVLink_header(msg.id, srcSystem=255, srcComponent=190)
        msg._signed = signed
        h.handle(msg, ("127.0.0.1", 14550))

    _cmd(h, M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, 21196)
    assert core.flight.armed
    setup(key)
    assert not h.signing.enabled and h.rejected["signing_armed"] == 1
    _cmd(h, M.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, 21196)
    setup(key)
    assert h.signing.enabled and events[-1][1] == "Signing enabled"
    setup([9] * 32)  # unsigned, with a key set, on an untrusted link: refused
    assert h.rejected["signing_untrusted"] == 1
    h.trusted = True  # a link declared trusted (--gcs-trusted): unsigned is accepted
    setup([9] * 32)
    assert h.signing.enabled and h.rejected["signing_untrusted"] == 1
    h.trusted = False
    setup([0] * 32, signed=True)  # signed with the current key: the zero key turns signing off
    assert not h.signing.enabled and events[-1][1] == "Signing disabled"
    assert not any(str(bytes(key)) in t or "1, 2, 3" in t for _, t in events)
