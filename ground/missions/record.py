"""Flight records: what the expectations are evaluated on (:class:`FlightRecord`), from the FC's
``.tlog`` (:func:`record_from_log`) or from the telemetry a ground link receives
(:class:`TelemetryRecorder`). Times are mission time (simulated seconds since the mission
started); positions north/east/altitude-up metres from home; tilt degrees.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.missions.errors import MissionRunError
from ground.vehicle.telemetry import TIMED_MESSAGES
from smcpilot.errors import TlogError
from smcpilot.geo import Home
from smcpilot.protocol import CHI_NAMES

if TYPE_CHECKING:
    from ground.logs.load import FlightLog
    from ground.missions.schema import Mission
    from ground.vehicle.subscription import Subscription
    from ground.vehicle.vehicle import Vehicle

__all__ = ["FlightRecord", "TelemetryRecorder", "record_from_log"]


def _hold(t_src: np.ndarray, values: np.ndarray, t_query: np.ndarray) -> np.ndarray:
    """Zero-order hold: the latest sample at or before each query time (NaN before the first)."""
    idx = np.searchsorted(t_src, t_query, side="right") - 1
    out = np.full(t_query.shape, np.nan)
    ok = idx >= 0
    if t_src.size:
        out[ok] = values[idx[ok]]
    return out


@dataclass
class FlightRecord:
    """What the expectations are evaluated on. Times are mission time (s since the mission
    started, see :mod:`ground.missions`); positions north/east/altitude-up metres from home."""

    #: "log" (the FC's .tlog) or "telemetry" (what the ground link received).
    source: str
    #: a sentence for the report.
    description: str
    #: mission start in the source's own time base (sim seconds since the log's first record).
    t0_s: float
    pos_t: np.ndarray
    north: np.ndarray
    east: np.ndarray
    alt: np.ndarray
    tilt_t: np.ndarray
    tilt_deg: np.ndarray
    #: χ̂ per channel (phi, theta, psi, z), shape (n, 4).
    chi_t: np.ndarray
    chi: np.ndarray
    armed_t: np.ndarray
    armed: np.ndarray
    #: horizontal position set-point.
    sp_t: np.ndarray
    sp_north: np.ndarray
    sp_east: np.ndarray
    sp_source: str
    events: list[tuple[float, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    #: item number -> mission time at which it became the current item (the previous item's
    #: MISSION_ITEM_REACHED, else the first MISSION_CURRENT naming it; item 1 at 0).
    item_start_s: dict[int, float] = field(default_factory=dict)

    def armed_at(self, t: np.ndarray) -> np.ndarray:
        """Armed flag held onto times ``t`` (False before the first armed sample)."""
        if not self.armed_t.size:
            return np.zeros(t.shape, dtype=bool)
        v = _hold(self.armed_t, self.armed.astype(float), t)
        return np.nan_to_num(v, nan=0.0) > 0.5

    @property
    def end_s(self) -> float:
        """Mission time of the last position sample."""
        return float(self.pos_t[-1]) if self.pos_t.size else 0.0


def _mission_start_in_log(log: FlightLog) -> tuple[float, str]:
    """(log time of the mission start, how it was found)."""
    armed_t = log.act_t_s[log.armed] if log.act_t_s.size else np.zeros(0)
    first_armed = float(armed_t[0]) if armed_t.size else None
    for ev in log.events:
        if ev.text.strip() == "Mode AUTO" and (first_armed is None or ev.t_s >= first_armed - 1.0):
            return ev.t_s, "the FC's 'Mode AUTO' event"
    if first_armed is not None:
        return first_armed, "arming (no 'Mode AUTO' event in the log)"
    return 0.0, "the start of the log (never armed, no 'Mode AUTO' event)"


def _item_starts(changes: Iterable[tuple[float, str, int]], t0_s: float) -> dict[int, float]:
    """Item number -> mission time it became current, from ``(time, message type, seq)`` of
    MISSION_ITEM_REACHED (item seq done: seq + 1 starts) and MISSION_CURRENT (seq is current),
    times in the same base as ``t0_s``; only those after the mission start count."""
    starts: dict[int, float] = {1: 0.0}
    for t, mtype, seq in sorted(changes):
        if t < t0_s - 0.05:
            continue
        item = seq + 1 if mtype == "MISSION_ITEM_REACHED" else seq
        if item >= 1 and item not in starts:
            starts[item] = max(0.0, t - t0_s)
    return starts


def _mission_messages_in_tlog(path: Path, t0_us: int) -> list[tuple[float, str, int]]:
    """``(log time, type, seq)`` of every MISSION_ITEM_REACHED / MISSION_CURRENT the FC sent."""
    from smcpilot.tlog import read_tlog

    out: list[tuple[float, str, int]] = []
    try:
        for time_us, msg in read_tlog(path):
            mtype = msg.get_type()
            if mtype in ("MISSION_ITEM_REACHED", "MISSION_CURRENT"):
                out.append(((time_us - t0_us) * 1e-6, mtype, int(msg.seq)))
    except TlogError:
        pass  # a cut-short log: keep what was read (load_log reported it)
    return out


def record_from_log(log: FlightLog) -> FlightRecord:
    """A :class:`FlightRecord` from a :class:`ground.logs.FlightLog` of the FC's ``.tlog``
    (the file is read once more for the mission messages the FC sent)."""
    t0, how = _mission_start_in_log(log)
    changes = _mission_messages_in_tlog(log.path, log.t0_us) if log.t0_us is not None else []
    sp_t = log.smc_t_s - t0 if log.has_smc else np.zeros(0)
    return FlightRecord(
        source="log",
        description=f"FC log {log.path} (state from the {log.state_source or 'n/a'}, χ̂ and set-points from"
        f" {log.ctrl_source or 'n/a'}); mission time 0 = {how}, at {t0:.3f} s of the log",
        t0_s=t0,
        pos_t=log.pos_t_s - t0,
        north=log.north_m,
        east=log.east_m,
        alt=log.alt_m,
        tilt_t=log.att_t_s - t0,
        tilt_deg=log.tilt_deg,
        chi_t=log.ctrl_t_s - t0,
        chi=log.chi_hat,
        armed_t=log.act_t_s - t0,
        armed=log.armed,
        sp_t=sp_t,
        sp_north=log.target_north_m if log.has_smc else np.zeros(0),
        sp_east=log.target_east_m if log.has_smc else np.zeros(0),
        sp_source="the FC's position target (per tick)",
        events=[(e.t_s - t0, e.text) for e in log.events],
        notes=list(log.warnings),
        item_start_s=_item_starts(changes, t0),
    )


class TelemetryRecorder:
    """Records the telemetry of a :class:`~ground.vehicle.Vehicle` (on its receiver thread) for
    expectations and plots when there is no FC log. Times are the vehicle's simulated seconds
    (``time_boot_ms``; for messages without it, the latest one). Optionally writes every message
    to a ``.tlog`` stamped with simulated time, for :func:`ground.logs.plot_log`."""

    def __init__(self, vehicle: Vehicle, tlog_path: Path | None = None) -> None:
        self.vehicle = vehicle
        self.pos: list[tuple[float, float, float, float]] = []
        self.att: list[tuple[float, float, float]] = []
        self.chi: dict[float, list[float]] = {}
        self.armed: list[tuple[float, bool]] = []
        self.current: list[tuple[float, str, int]] = []
        self.targets: list[tuple[float, float, float]] = []
        self.events: list[tuple[float, str]] = []
        self._last_t = 0.0
        self._writer = None
        self._sub: Subscription | None = None
        self._lock = threading.Lock()
        if tlog_path is not None:
            from smcpilot.tlog import TlogWriter

            self._writer = TlogWriter(tlog_path)

    def start(self) -> TelemetryRecorder:
        self._sub = self.vehicle.subscribe(None, self._on_message)
        return self

    def stop(self) -> None:
        if self._sub is not None:
            self._sub.close()
            self._sub = None
        with self._lock:
            if self._writer is not None:
                self._writer.close()

    def _on_message(self, msg: mavlink.MAVLink_message) -> None:
        mtype = msg.get_type()
        if mtype in TIMED_MESSAGES:
            t = float(msg.time_boot_ms) * 1e-3
            self._last_t = max(self._last_t, t)
        else:
            t = self._last_t
        with self._lock:
            if self._writer is not None and not self._writer.closed:
                try:
                    self._writer.write(round(t * 1e6), msg.get_msgbuf())
                except TlogError:
                    pass
        if mtype == "LOCAL_POSITION_NED":
            self.pos.append((t, msg.x, msg.y, -msg.z))
        elif mtype == "ATTITUDE":
            self.att.append((t, msg.roll, msg.pitch))
        elif mtype == "POSITION_TARGET_LOCAL_NED":
            self.targets.append((t, msg.x, msg.y))
        elif mtype == "NAMED_VALUE_FLOAT":
            name = msg.name if isinstance(msg.name, str) else msg.name.decode("ascii", "replace")
            name = name.split("\0", 1)[0]
            if name in CHI_NAMES:
                self.chi.setdefault(t, [math.nan] * 4)[CHI_NAMES.index(name)] = float(msg.value)
        elif mtype == "HEARTBEAT":
            if msg.type != mavlink.MAV_TYPE_GCS and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID:
                self.armed.append((t, bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)))
        elif mtype in ("MISSION_ITEM_REACHED", "MISSION_CURRENT"):
            self.current.append((t, mtype, int(msg.seq)))
        elif mtype == "STATUSTEXT":
            text = msg.text if isinstance(msg.text, str) else msg.text.decode("utf-8", "replace")
            self.events.append((t, text.split("\0", 1)[0]))

    def record(self, t0_s: float, mission: Mission, home: Home | None) -> FlightRecord:
        """The recorded telemetry as a :class:`FlightRecord` with mission time 0 at ``t0_s``."""
        p = np.asarray(sorted(self.pos), dtype=float).reshape(-1, 4)
        a = np.asarray(sorted(self.att), dtype=float).reshape(-1, 3)
        tilt = np.degrees(np.arccos(np.clip(np.cos(a[:, 1]) * np.cos(a[:, 2]), -1.0, 1.0)))
        chi_t = np.asarray(sorted(self.chi), dtype=float)
        chi = np.asarray([self.chi[t] for t in sorted(self.chi)], dtype=float).reshape(-1, 4)
        arm = sorted(self.armed, key=lambda r: r[0])
        rec = FlightRecord(
            source="telemetry",
            description="telemetry received over the ground link (10 Hz position/attitude/χ̂, armed from the 1 Hz"
            f" HEARTBEAT); mission time 0 = the vehicle's start of AUTO at {t0_s:.2f} s simulated",
            t0_s=t0_s,
            pos_t=p[:, 0] - t0_s,
            north=p[:, 1],
            east=p[:, 2],
            alt=p[:, 3],
            tilt_t=a[:, 0] - t0_s,
            tilt_deg=tilt,
            chi_t=chi_t - t0_s,
            chi=chi,
            armed_t=np.asarray([r[0] for r in arm], dtype=float) - t0_s,
            armed=np.asarray([r[1] for r in arm], dtype=bool),
            sp_t=np.zeros(0),
            sp_north=np.zeros(0),
            sp_east=np.zeros(0),
            sp_source="planned: the current item's point (telemetry has no set-point)",
            events=[(t - t0_s, text) for t, text in self.events],
            item_start_s=_item_starts(self.current, t0_s),
        )
        targets = np.asarray(sorted(self.targets), dtype=float).reshape(-1, 3)
        if np.count_nonzero(targets[:, 0] >= t0_s) >= 2:
            rec.sp_t, rec.sp_north, rec.sp_east = targets[:, 0] - t0_s, targets[:, 1], targets[:, 2]
            rec.sp_source = "the FC's set-point from POSITION_TARGET_LOCAL_NED (4 Hz telemetry)"
        else:
            self._planned_setpoints(rec, mission, home)
        return rec

    def _planned_setpoints(self, rec: FlightRecord, mission: Mission, home: Home | None) -> None:
        """Set ``rec.sp_*`` at the position samples after the mission start: the current item's
        point (see :mod:`ground.missions`)."""
        changes = sorted((t, item) for item, t in rec.item_start_s.items())
        t = rec.pos_t
        sel = np.flatnonzero(t >= 0.0)
        if not sel.size:
            return
        sp_n = np.full(sel.size, np.nan)
        sp_e = np.full(sel.size, np.nan)
        seq = 1
        started = 0.0
        anchor: tuple[float, float] | None = None
        ci = 0
        for j, k in enumerate(sel):
            tk = t[k]
            while ci < len(changes) and changes[ci][0] <= tk:
                if changes[ci][1] != seq:
                    seq, started, anchor = changes[ci][1], changes[ci][0], None
                ci += 1
            if not 1 <= seq <= len(mission.items):
                seq_item = mission.items[-1]
            else:
                seq_item = mission.items[seq - 1]
            point = None
            if seq_item.type == "rtl":
                point = (0.0, 0.0)
            elif seq_item.has_position:
                try:
                    point = seq_item.local_ne(home)
                except MissionRunError:
                    point = None
            if point is None:
                if anchor is None:
                    i0 = min(int(np.searchsorted(t, started)), t.size - 1)
                    anchor = (float(rec.north[i0]), float(rec.east[i0]))
                point = anchor
            sp_n[j], sp_e[j] = point
        rec.sp_t = t[sel]
        rec.sp_north = sp_n
        rec.sp_east = sp_e
