"""The FC side of fault injection, from outside, over real UDP on 127.0.0.1: the real FC process
(``python -m fc``, lockstep), a raw-pymavlink ground station (tests/gcs_helpers.py) and the test
playing the simulator (tests/sitl_helpers.py's FakeSim, sysid 1 component 200): the SIM_*
parameters listed after the FC's, volatile, validated and forwarded to the simulator as
PARAM_SET; MAV_CMD_INJECT_FAILURE mapped onto them (DENIED unless SYS_FAILURE_EN, UNSUPPORTED
for what the simulator cannot do, DENIED for garbage); the simulator's STATUSTEXT relayed; an
unanswered forward warned about once; everything in the FC's tlog."""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from gcs_helpers import FC_COMPID, FC_SYSID, Gcs
from pymavlink.dialects.v20 import ardupilotmega as M
from sitl_helpers import FakeSim, FcProcess, parse_datagram

from fc.params import PARAMS, SIM_PARAM_OFFSET
from smcpilot.faults import SIM_PARAMS
from smcpilot.protocol import SIM_COMPONENT_ID
from smcpilot.tlog import read_tlog

ACCEPTED, DENIED, UNSUPPORTED = M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_DENIED, M.MAV_RESULT_UNSUPPORTED
INJECT = M.MAV_CMD_INJECT_FAILURE
NAN = math.nan


def f32(v: float) -> float:
    return struct.unpack("<f", struct.pack("<f", v))[0]


@dataclass
class Rig:
    fc: FcProcess
    sim: FakeSim
    gcs: Gcs
    tlog: Path
    param_file: Path
    t_ms: int = 0

    def tick(self) -> None:
        """One lockstep state from the simulator (and the FC's answer)."""
        self.t_ms += 2
        self.sim.send_state(self.t_ms)

    def sim_messages(self, wall_s: float = 1.0, *, until: int | None = None) -> list:
        """Everything the FC sent the simulator for ``wall_s`` (or until ``until`` PARAM_SETs came)."""
        out: list = []
        deadline = time.monotonic() + wall_s
        while time.monotonic() < deadline:
            self.sim.sock.settimeout(max(0.01, deadline - time.monotonic()))
            try:
                data, _ = self.sim.sock.recvfrom(65535)
            except TimeoutError:
                break
            out.extend(parse_datagram(data))
            if until is not None and len([m for m in out if m.get_type() == "PARAM_SET"]) >= until:
                break
        return out

    def sim_param_sets(self, n: int, wall_s: float = 5.0) -> list[tuple[str, float]]:
        """The next ``n`` PARAM_SETs to the simulator, checked for the address and type."""
        got = [m for m in self.sim_messages(wall_s, until=n) if m.get_type() == "PARAM_SET"]
        for m in got:
            assert (m.target_system, m.target_component) == (1, SIM_COMPONENT_ID), m
            assert m.param_type == M.MAV_PARAM_TYPE_REAL32, m
            assert (m.get_srcSystem(), m.get_srcComponent()) == (FC_SYSID, FC_COMPID), m
        assert len(got) == n, f"expected {n} PARAM_SET to the simulator, got {got}"
        return [(m.param_id, m.param_value) for m in got]

    def no_param_set(self, wall_s: float = 0.5) -> None:
        got = [m for m in self.sim_messages(wall_s) if m.get_type() == "PARAM_SET"]
        assert not got, f"nothing should have been forwarded: {got}"

    def answer(self, name: str, value: float) -> None:
        """The simulator's PARAM_VALUE for ``name``."""
        mav = self.sim.mav()
        index = [p.name for p in SIM_PARAMS].index(name)
        ptype = M.MAV_PARAM_TYPE_REAL32
        self.sim.send_raw(bytes(mav.param_value_encode(name.encode(), value, ptype, len(SIM_PARAMS), index).pack(mav)))

    def inject(self, unit: float, ftype: float, instance: float, expect: int):
        return self.gcs.command(INJECT, unit, ftype, instance, expect=expect)


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Rig]:
    param_file = tmp_path / "fc.parm"
    # A SIM_* value in the parameter file is never loaded: the simulator's parameters are volatile.
    param_file.write_text("SIM_ENGINE_MUL 0.25\nSMC_Z_KD 1.5\n", encoding="ascii")
    gcs = Gcs()
    tlog = tmp_path / "fc.tlog"
    fc = FcProcess(
        ["--sim", "udpin:127.0.0.1:0", "--gcs", f"udp:127.0.0.1:{gcs.port}", "--lockstep", "--tlog", str(tlog),
         "--param-file", str(param_file), "--watchdog-s", "120"], cwd=tmp_path,
    )  # fmt: skip
    sim = None
    try:
        host, port = fc.listening()["sim"].rsplit(":", 1)
        sim = FakeSim((host, int(port)))
        sim.exchange(0)  # the FC learns where the simulator is, and sends its first telemetry
        gcs.heartbeat()
        yield Rig(fc, sim, gcs, tlog, param_file)
    finally:
        if sim is not None:
            sim.close()
        gcs.close()
        fc.kill()
        print("--- FC output ---\n" + "\n".join(fc.all_lines[-40:]))  # shown by pytest when the test fails


def test_sim_params_are_listed_volatile_validated_and_forwarded(rig: Rig) -> None:
    g = rig.gcs
    got = g.param_list()
    n_fc, n = len(PARAMS), len(PARAMS) + len(SIM_PARAMS)
    assert sorted(got) == list(range(n)) and {m.param_count for m in got.values()} == {n}
    for j, sp in enumerate(SIM_PARAMS):  # after the FC's own, at their defaults
        m = got[n_fc + j]
        assert m.param_id == sp.name and m.param_value == f32(sp.default), m
        assert m.param_type == (M.MAV_PARAM_TYPE_INT32 if sp.is_int else M.MAV_PARAM_TYPE_REAL32), m
    assert got[PARAMS.index(next(p for p in PARAMS if p.name == "SYS_FAILURE_EN"))].param_value == 0.0
    assert g.param_read("SMC_Z_KD").param_value == 1.5  # the file was loaded ...
    assert g.param_read("SIM_ENGINE_MUL").param_value == 1.0  # ... but not its SIM_* line
    assert any("SIM_ENGINE_MUL is a live simulator parameter, not loaded" in ln for ln in rig.fc.all_lines)
    last = g.param_read(index=n - 1)
    assert last.param_id == SIM_PARAMS[-1].name and last.param_index == SIM_PARAM_OFFSET + len(SIM_PARAMS) - 1

    # A change: echoed to the ground at once, forwarded to the simulator's component.
    assert g.param_set("SIM_ENGINE_MUL", 0.7).param_value == f32(0.7)
    assert rig.sim_param_sets(1) == [("SIM_ENGINE_MUL", f32(0.7))]
    rig.answer("SIM_ENGINE_MUL", 0.7)
    assert g.param_read("SIM_ENGINE_MUL").param_value == f32(0.7)
    assert g.param_set("SIM_ENGINE_FAIL", 2.4).param_value == 2.0  # a whole-number parameter: rounded
    assert rig.sim_param_sets(1) == [("SIM_ENGINE_FAIL", 2.0)]
    rig.answer("SIM_ENGINE_FAIL", 2.0)

    # Refused: the value in force comes back with the reason; nothing reaches the simulator.
    for name, bad, why in (("SIM_ENGINE_MUL", 1.5, "out of range"), ("SIM_ENGINE_MUL", NAN, "finite"),
                           ("SIM_DIST_FN", 25.0, "out of range")):  # fmt: skip
        mark = g.mark()
        pv = g.param_set(name, bad)
        assert pv.param_value == g.param_read(name).param_value and pv.param_value != bad
        text = g.wait("STATUSTEXT", lambda m, name=name: name in m.text, since=mark, what=f"reason for {name}={bad}")
        assert why in text.text, text.text
    rig.no_param_set()
    # A sensor fault's mode and value must make a fault together: a noise std is >= 0.
    assert g.param_set("SIM_GYR_FAULT", 3.0).param_value == 3.0
    rig.answer(*rig.sim_param_sets(1)[0])
    mark = g.mark()
    assert g.param_set("SIM_GYR_FAULT_V", -0.5).param_value == 0.0
    assert g.wait("STATUSTEXT", lambda m: "SIM_GYR_FAULT_V" in m.text, since=mark).text == "SIM_GYR_FAULT_V -0.5: noise std must be >= 0"
    rig.no_param_set()

    # The simulator answers another value (it refused ours): the FC takes it and tells the ground.
    assert g.param_set("SIM_GUST_F", 0.5).param_value == f32(0.5)
    assert rig.sim_param_sets(1) == [("SIM_GUST_F", f32(0.5))]
    mark = g.mark()
    rig.answer("SIM_GUST_F", 0.0)
    assert g.wait("PARAM_VALUE", lambda m: m.param_id == "SIM_GUST_F", since=mark).param_value == 0.0
    assert g.param_read("SIM_GUST_F").param_value == 0.0

    # A forward the simulator never answers: one warning after 1 s, no stall.
    mark = g.mark()
    g.param_set("SIM_DIST_TX", 0.1)
    rig.sim_param_sets(1)
    g.wait("STATUSTEXT", lambda m: m.text == "SIM_DIST_TX: no answer from the simulator", since=mark, timeout=10.0)
    rig.tick()
    assert len(rig.sim.recv_actuators()) == 1  # the lockstep goes on

    # The simulator's fault announcements reach the ground stations.
    mav = rig.sim.mav()
    mark = g.mark()
    rig.sim.send_raw(bytes(mav.statustext_encode(M.MAV_SEVERITY_WARNING, b"SIM: motor 2 at 70%").pack(mav)))
    relayed = g.wait("STATUSTEXT", lambda m: m.text == "SIM: motor 2 at 70%", since=mark)
    assert relayed.severity == M.MAV_SEVERITY_WARNING and relayed.get_srcComponent() == FC_COMPID
    # A ground station's own STATUSTEXT (its "id" field is 0, HEARTBEAT's message id) is not
    # mistaken for a heartbeat: no handler error below.
    g.mav.statustext_send(M.MAV_SEVERITY_INFO, b"hello from the ground", 0, 0)

    # SIM_* never reach the parameter file; the FC's own parameters do.
    assert g.param_set("SYS_FAILURE_EN", 1.0, M.MAV_PARAM_TYPE_INT32).param_value == 1.0
    deadline = time.monotonic() + 5.0  # the FC writes the file on a thread of its own, moments after the echo
    while True:
        names = {ln.split()[0] for ln in rig.param_file.read_text().splitlines() if ln and not ln.startswith("#")}
        if "SYS_FAILURE_EN" in names or time.monotonic() > deadline:
            break
        time.sleep(0.01)
    assert "SYS_FAILURE_EN" in names and "FS_POS_TMO" in names and not {n for n in names if n.startswith("SIM_")}

    assert rig.fc.stop() == 0
    summary = rig.fc.summary()
    assert summary["sim_param_forwards"] == 5 and summary["sim_param_answers"] == 4
    assert summary["sim_param_unanswered"] == 1 and summary["sim_statustexts"] == 1
    assert summary["gcs_rejected"]["param_refused"] == 4
    assert "handler_error" not in summary["gcs_rejected"], summary["gcs_rejected"]
    # The tlog holds the forwards to the simulator and its messages.
    sent, heard = [], []
    for _, m in read_tlog(rig.tlog):
        if m.get_type() == "PARAM_SET" and m.target_component == SIM_COMPONENT_ID:
            sent.append(m.param_id)
        elif m.get_type() == "STATUSTEXT" and m.get_srcComponent() == SIM_COMPONENT_ID:
            heard.append(m.text)
    assert sent == ["SIM_ENGINE_MUL", "SIM_ENGINE_FAIL", "SIM_GYR_FAULT", "SIM_GUST_F", "SIM_DIST_TX"]
    assert heard == ["SIM: motor 2 at 70%"]


def test_inject_failure_round_trip(rig: Rig) -> None:
    g = rig.gcs
    MOTOR, GYRO, ACCEL, GPS, MAG = (M.FAILURE_UNIT_SYSTEM_MOTOR, M.FAILURE_UNIT_SENSOR_GYRO, M.FAILURE_UNIT_SENSOR_ACCEL,
                                    M.FAILURE_UNIT_SENSOR_GPS, M.FAILURE_UNIT_SENSOR_MAG)  # fmt: skip
    OK, OFF, STUCK, GARBAGE, WRONG, SLOW, DELAYED = (M.FAILURE_TYPE_OK, M.FAILURE_TYPE_OFF, M.FAILURE_TYPE_STUCK,
                                                     M.FAILURE_TYPE_GARBAGE, M.FAILURE_TYPE_WRONG, M.FAILURE_TYPE_SLOW,
                                                     M.FAILURE_TYPE_DELAYED)  # fmt: skip

    # Disabled by default (PX4's SYS_FAILURE_EN).
    mark = g.mark()
    rig.inject(MOTOR, OFF, 1, DENIED)
    assert "failure injection disabled (SYS_FAILURE_EN=0)" in g.texts(mark)
    rig.no_param_set()
    assert g.param_set("SYS_FAILURE_EN", 1.0, M.MAV_PARAM_TYPE_INT32).param_value == 1.0

    def injected(unit, ftype, instance, changes, text) -> None:
        mark = g.mark()
        rig.inject(unit, ftype, instance, ACCEPTED)
        assert rig.sim_param_sets(len(changes)) == [(n, f32(v)) for n, v in changes]
        for n, v in changes:
            rig.answer(n, v)
        g.wait("STATUSTEXT", lambda m: m.text == text, since=mark, what=text)
        for n, v in dict(changes).items():  # the ground heard the change, and reads it back
            assert g.since(mark, "PARAM_VALUE", lambda m, n=n: m.param_id == n)[-1].param_value == f32(v)
            assert g.param_read(n).param_value == f32(v)

    injected(MOTOR, OFF, 2, [("SIM_MOT_OFF", 2.0)], "Failure injected: motor 2 off")
    injected(MOTOR, OFF, 4, [("SIM_MOT_OFF", 10.0)], "Failure injected: motor 4 off")
    injected(MOTOR, OK, 2, [("SIM_MOT_OFF", 8.0)], "Failure cleared: motor 2")
    injected(MOTOR, OFF, 0, [("SIM_MOT_OFF", 15.0)], "Failure injected: all motors off")
    injected(MOTOR, OK, 0, [("SIM_MOT_OFF", 0.0)], "Failure cleared: all motors")
    injected(GYRO, OFF, 0, [("SIM_GYR_FAULT", 4.0)], "Failure injected: gyro dropout")
    injected(GYRO, WRONG, 1, [("SIM_GYR_FAULT", 2.0), ("SIM_GYR_FAULT_V", 0.1)], "Failure injected: gyro bias 0.1 rad/s")
    injected(GYRO, OK, 0, [("SIM_GYR_FAULT", 0.0), ("SIM_GYR_FAULT_V", 0.0)], "Failure cleared: gyro")
    injected(ACCEL, DELAYED, 0, [("SIM_ACC_FAULT", 5.0), ("SIM_ACC_FAULT_V", 0.1)], "Failure injected: accel delay 0.1 s")
    injected(ACCEL, STUCK, 0, [("SIM_ACC_FAULT", 1.0), ("SIM_ACC_FAULT_V", 0.0)], "Failure injected: accel stuck")
    injected(GPS, GARBAGE, 0, [("SIM_POS_FAULT", 3.0), ("SIM_POS_FAULT_V", 2.0), ("SIM_VEL_FAULT", 3.0), ("SIM_VEL_FAULT_V", 1.0)],
             "Failure injected: GPS noise 2 m, 1 m/s")  # fmt: skip
    injected(GPS, OK, 0, [("SIM_POS_FAULT", 0.0), ("SIM_POS_FAULT_V", 0.0), ("SIM_VEL_FAULT", 0.0), ("SIM_VEL_FAULT_V", 0.0)],
             "Failure cleared: GPS")  # fmt: skip

    # What the simulator cannot do: UNSUPPORTED, saying what; garbage: DENIED with a reason.
    refused = [
        (MAG, OFF, 0, UNSUPPORTED, "SENSOR_MAG not simulated"),
        (GYRO, SLOW, 0, UNSUPPORTED, "gyro SLOW not simulated"),
        (GYRO, M.FAILURE_TYPE_INTERMITTENT, 0, UNSUPPORTED, "gyro INTERMITTENT not simulated"),
        (ACCEL, OFF, 2, UNSUPPORTED, "accel 2 not simulated"),
        (MOTOR, STUCK, 1, UNSUPPORTED, "motor STUCK not simulated"),
        (M.FAILURE_UNIT_SYSTEM_BATTERY, OFF, 0, UNSUPPORTED, "SYSTEM_BATTERY not simulated"),
        (NAN, OFF, 0, DENIED, "not whole numbers: nan, 1, 0"),
        (GYRO, NAN, 0, DENIED, "not whole numbers: 0, nan, 0"),
        (GYRO, 1.5, 0, DENIED, "not whole numbers: 0, 1.5, 0"),
        (55, OFF, 0, DENIED, "unknown failure unit 55"),
        (GYRO, 9, 0, DENIED, "unknown failure type 9"),
        (MOTOR, OFF, 7, DENIED, "no motor 7"),
    ]
    before = {sp.name: g.param_read(sp.name).param_value for sp in SIM_PARAMS}
    for unit, ftype, instance, code, why in refused:
        mark = g.mark()
        rig.inject(unit, ftype, instance, code)
        g.wait("STATUSTEXT", lambda m, why=why: why in m.text, since=mark, what=f"reason '{why}'")
    rig.no_param_set()
    assert {sp.name: g.param_read(sp.name).param_value for sp in SIM_PARAMS} == before  # nothing changed

    # Disabled again: refused, the values stay.
    assert g.param_set("SYS_FAILURE_EN", 0.0, M.MAV_PARAM_TYPE_INT32).param_value == 0.0
    rig.inject(MOTOR, OFF, 1, DENIED)
    rig.no_param_set()
    assert rig.fc.stop() == 0
    summary = rig.fc.summary()
    assert summary["sim_param_forwards"] == summary["sim_param_answers"] == 22
    assert summary["gcs_rejected"]["inject_refused"] == len(refused)
    assert summary["sim_param_unanswered"] == 0
