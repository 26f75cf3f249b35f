"""The lockstep kernel (:mod:`fc.lockstep_kernel`) against the ordinary path, state by state.

A recorded flight's state datagrams, with odd ones slipped in (a state sent twice, a NaN, an IMU
stamped with another time, an IMU without its accelerometer, a truth stamped with another time,
a datagram from another system), are fed over real UDP to two flight controllers in this
process, one flying plain ticks in the kernel and one flying every tick the ordinary way: their
answers and their logs must be the same bytes, and the kernel must have flown most ticks and
none of the odd ones. (``tests/test_compiled_pipeline.py`` flies whole SITL flights both ways.)
"""

from __future__ import annotations

import math
import os
import socket
from pathlib import Path

import numpy as np
import pytest
from bits_helpers import needs_jit
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sitl_helpers import fly_sitl

from fc.app import FlightControllerApp
from fc.cli import build_app
from smcpilot.tlog import read_tlog

_ORDER = {mavlink.MAVLINK_MSG_ID_ATTITUDE: 0, mavlink.MAVLINK_MSG_ID_HIGHRES_IMU: 1, mavlink.MAVLINK_MSG_ID_ODOMETRY: 2,
          mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 3}  # fmt: skip


def _state_messages(tlog: Path) -> list[list[mavlink.MAVLink_message]]:
    """The simulator's per-tick messages the FC logged, four a state, in the datagram's order."""
    out: list[list[mavlink.MAVLink_message]] = []
    cur: list[mavlink.MAVLink_message] = []
    for _, msg in read_tlog(tlog):
        if msg.get_msgId() in _ORDER and msg.get_srcComponent() != 1:
            cur.append(msg)
            if len(cur) == 4:
                out.append(sorted(cur, key=lambda m: _ORDER[m.get_msgId()]))
                cur = []
    return out


def _pack(msgs: list[mavlink.MAVLink_message], system: int | None = None) -> bytes:
    """The messages framed again (each with its own sequence number and source; ``system``: as
    another system's), as one datagram."""
    out = b""
    for m in msgs:
        mav = mavlink.MAVLink(None, srcSystem=system or m.get_srcSystem(), srcComponent=m.get_srcComponent())
        mav.seq = m.get_seq()
        out += bytes(m.pack(mav, force_mavlink1=False))
    return out


def _odd(states: list[list[mavlink.MAVLink_message]]) -> tuple[list[bytes], set[int]]:
    """The datagrams with odd ones slipped in, and the indices of the odd ones (and of a state
    that follows one and is not plain for that: its predecessor was not a tick)."""
    datagrams: list[bytes] = []
    odd: set[int] = set()
    for k, msgs in enumerate(states):
        att, imu, odo, lpn = msgs
        if k == 900:  # a NaN (a sensor's dropout): dead reckoning starts, and its status change is an event
            lpn.x = math.nan
            odd.add(len(datagrams))
        elif k == 1200:  # the IMU stamped with another time
            imu.time_usec += 3000
            odd.add(len(datagrams))
        elif k == 1300:  # the IMU without its accelerometer
            imu.fields_updated &= ~0x07
            odd.add(len(datagrams))
        elif k == 1400:  # the truth stamped with another time
            odo.time_usec += 5000
            odd.add(len(datagrams))
        good = _pack(msgs)
        if k == 1500:  # another system's state (dropped before either path), then this one
            datagrams.append(_pack(msgs, system=77))  # (packing sets the messages' source: after good)
            odd.add(len(datagrams) - 1)
        datagrams.append(good)
        if k == 1100:  # the same state again (a re-send: answered again, unlogged)
            datagrams.append(datagrams[-1])
            odd.add(len(datagrams) - 1)
    return datagrams, odd


def _replay(run_dir: Path, datagrams: list[bytes], kernel: bool, name: str) -> tuple[list[bytes], bytes, dict]:
    """Feed the datagrams one at a time to a lockstep FC in this process; its answers, its log and
    its pipeline summary."""
    scenario = next(run_dir.glob("*.scenario.toml"))
    app = build_app(["--sim", "udpin:127.0.0.1:0", "--gcs", "none", "--scenario", str(scenario), "--tlog", str(run_dir / f"{name}.tlog"),
                     "--param-file", str(run_dir / f"{name}.parm"), "--watchdog-s", "30", "--lockstep", "--jit", "wait"],
                    out=open(os.devnull, "w"))  # fmt: skip
    assert not isinstance(app, int)
    answers: list[bytes] = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sim:
        sim.bind(("127.0.0.1", 0))
        sim.settimeout(0.2)
        _start(app, kernel)
        dest = app.sim.local_address
        for data in datagrams:
            sim.sendto(data, dest)
            app.lockstep_take(1)
            try:
                answers.append(sim.recv(4096))
            except TimeoutError:
                answers.append(b"")
        # (what telemetry reads of the last tick: made from the kernel's outputs when read)
        pipeline = {"kernel": app._plain.flown if app._plain is not None else 0, "ticks": app.core.ticks, "last": repr(app.core.last),
                    "estimate": repr(app.core._est), "commander": repr((app.core.commander.state, app.core.commander.estimate))}
        app.close()
    return answers, (run_dir / f"{name}.tlog").read_bytes(), pipeline


@needs_jit
def test_odd_states_fly_the_ordinary_way_with_the_same_answers_and_log(tmp_path: Path) -> None:
    plan = ({"t_s": 0.0, "action": "takeoff", "alt_m": 2.0}, {"t_s": 2.5, "action": "goto", "north_m": 2.0, "east_m": 0.0, "alt_m": 2.0})
    fly_sitl(tmp_path, "src", 4.0, plan=plan, fc_args=("--jit", "off"))
    run_dir = tmp_path / "src"
    states = _state_messages(run_dir / "src.tlog")
    assert len(states) >= 1990
    datagrams, odd = _odd(states)
    on, log_on, p_on = _replay(run_dir, datagrams, True, "on")
    off, log_off, p_off = _replay(run_dir, datagrams, False, "off")
    assert p_off["kernel"] == 0 and p_on["ticks"] == p_off["ticks"] >= 1990
    assert p_on["last"] == p_off["last"] and "PipelineOutput" in p_on["last"]
    assert p_on["estimate"] == p_off["estimate"] and p_on["commander"] == p_off["commander"]
    # every tick in the kernel but the first (the take-off), the plan's goto and the five odd
    # ones that are ticks (the NaN, the one after it that ends the dead reckoning, the IMU's two,
    # the truth's): the re-sent state and the other system's are no ticks
    assert p_on["kernel"] == p_on["ticks"] - 7, p_on
    assert [len(a) for a in on] == [len(a) for a in off]
    first = next((k for k, (a, b) in enumerate(zip(on, off)) if a != b), None)
    assert first is None, f"answers differ first at datagram {first}"
    assert on[1100] == on[1101]  # (the re-sent state answered again, the same answer)
    assert len(log_on) > 200_000
    assert log_on == log_off


@needs_jit
def test_the_kernel_refuses_a_state_that_is_not_plain_and_changes_nothing(tmp_path: Path) -> None:
    """Directly: a NaN state, a state stamped one period too late and an IMU of another time give 0
    and leave the held pipeline state, the estimator's state and the ground count as they were."""
    plan = ({"t_s": 0.0, "action": "takeoff", "alt_m": 2.0},)
    fly_sitl(tmp_path, "src", 3.0, plan=plan, fc_args=("--jit", "off"))
    run_dir = tmp_path / "src"
    states = _state_messages(run_dir / "src.tlog")
    datagrams = [_pack(m) for m in states[:1000]]
    _replay(run_dir, datagrams, True, "warm")  # (compiles and caches the kernel)
    app = build_app(["--sim", "udpin:127.0.0.1:0", "--gcs", "none", "--scenario", str(next(run_dir.glob("*.scenario.toml"))),
                     "--param-file", str(run_dir / "x.parm"), "--lockstep", "--jit", "wait"], out=open(os.devnull, "w"))  # fmt: skip
    assert not isinstance(app, int)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sim:
        sim.bind(("127.0.0.1", 0))
        _start(app, True)
        for data in datagrams:
            sim.sendto(data, app.sim.local_address)
            app.lockstep_take(1)
            sim.recv(4096)
        plain = app._plain
        assert plain is not None and plain.flown > 500
        core = app.core
        held = core.flight._held
        watch = core.plain_watch()
        assert watch is not None and held is not None

        def attempt(msgs: list[mavlink.MAVLink_message]) -> int:
            kf = plain.kf
            kf[:] = (app._last_tick_ms, app.cfg.period_us, core.config.period_s, core.t0_us, math.inf, core.config.disarm_delay_s,
                     core.commander.ground_armed_s, *watch, core.flight.yaw_target_rad)  # fmt: skip
            held.io[12:20] = core.flight.pipeline_inputs()
            plain.ki[:6] = (0, 0, 128, core.flags(), core.mode, app.clock.now_us())
            ps0, es0, ground0 = held.state(), core._est, float(kf[6])
            flown, es = plain.call(_pack(msgs), app._sim_sysid, held, core._est, core._est_params, app._state_decoder.fo,
                                   app._answer_encoder)  # fmt: skip
            if not flown:
                assert es is es0 or es == es0
                assert held.state() == ps0 and core._est is es0 and float(kf[6]) == ground0
            return int(flown)

        nxt = states[1000]
        ok = [_copy(m) for m in nxt]
        nan = [_copy(m) for m in nxt]
        nan[3].z = math.nan
        late = [_copy(m) for m in states[1001]]
        imu_off = [_copy(m) for m in nxt]
        imu_off[1].time_usec += 2000
        assert attempt(nan) == 0
        assert attempt(late) == 0
        assert attempt(imu_off) == 0
        assert attempt(ok) == 1  # (the state the app expects next: plain)
        app.close()


def _start(app: FlightControllerApp, kernel: bool) -> None:
    """Start ``app`` for lockstep with the kernel (``SMCPILOT_LOCKSTEP_KERNEL``, read as the
    compiled parts load) or without."""
    os.environ["SMCPILOT_LOCKSTEP_KERNEL"] = "1" if kernel else "0"
    try:
        app.start(freeze_gc=False)
    finally:
        del os.environ["SMCPILOT_LOCKSTEP_KERNEL"]
    assert (app._plain is not None) == kernel
    app.lockstep_begin()


def _copy(m: mavlink.MAVLink_message) -> mavlink.MAVLink_message:
    """A message decoded again from its bytes (a copy to change)."""
    mav = mavlink.MAVLink(None)
    out = mav.parse_buffer(bytes(m.get_msgbuf()))
    assert out is not None and len(out) == 1
    return out[0]


@pytest.fixture(autouse=True)
def _no_kernel_switch_left() -> None:
    assert "SMCPILOT_LOCKSTEP_KERNEL" not in os.environ


@needs_jit
def test_a_ground_command_acts_from_the_next_tick_with_the_kernel_flying(tmp_path: Path) -> None:
    """Commands arrive between plain ticks: the kernel's inputs (which it keeps from one plain tick
    to the next) must be made again, so the tick after a command flies it (the FC's log: the
    command stamped with the last tick's time, the next tick's SMC record with its set-point)."""
    from sitl_helpers import load_flight

    from ground.client import Vehicle
    from ground.sitl import Sitl, SitlOptions

    tlog = tmp_path / "fc.tlog"
    vehicle = Vehicle("udpin:127.0.0.1:0").open()
    try:
        opts = SitlOptions.of(gcs=f"udp:127.0.0.1:{vehicle.local_address[1]}", lockstep=True, log_dir=tmp_path, tlog=tlog,
                              fc_args=("--jit", "wait"))  # fmt: skip
        with Sitl(opts) as sitl:
            vehicle.wait_heartbeat(20.0)
            vehicle.arm()
            vehicle.takeoff(2.0)
            vehicle.wait_altitude(2.0, tol_m=0.3, timeout_sim_s=20.0)
            vehicle.goto_ned(3.0, -2.0, -2.5)
            vehicle.wait_position_ned(3.0, -2.0, -2.5, tol_m=0.3, timeout_sim_s=20.0)
            vehicle.goto_ned(-1.0, 1.0, -1.5)
            vehicle.wait_position_ned(-1.0, 1.0, -1.5, tol_m=0.3, timeout_sim_s=20.0)
    finally:
        vehicle.close()
    assert sitl.fc_summary is not None
    assert sitl.fc_summary["pipeline"]["lockstep_kernel_ticks"] > 1000, sitl.fc_summary["pipeline"]
    commands = [(t, m) for t, m in read_tlog(tlog) if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    assert len(commands) >= 2
    flight = load_flight(tlog)
    for t_us, m in commands:
        k = int(np.searchsorted(flight.smc_t, t_us * 1e-6 + 1e-7))  # the first tick after it
        want = (m.x, -m.y, -m.z)  # NED -> the paper's x north, y west, z up
        got = tuple(float(flight.smc[f"target_{c}"][k]) for c in "xyz")
        assert got == pytest.approx(want, abs=1e-6), (t_us, k, got, want)
