"""Read, summarise and plot the flight controller's ``.tlog`` files.

:func:`load_log` turns a log into a :class:`FlightLog` of numpy arrays in user-facing units and the
MAVLink NED convention; :func:`summarize` reduces it to a JSON-ready dict of headline numbers
(:func:`print_summary` prints them); :func:`plot_log` writes PNG figures. The CLI pieces
(:func:`add_plot_arguments` / :func:`plot_main` for ``smcpilot plot LOG`` and
:func:`add_log_arguments` / :func:`log_main` for ``smcpilot log summary LOG``) are wired into
:mod:`lab.cli`.

What the flight controller logs (see :mod:`fc.app` and :mod:`fc.telemetry`):

- from the simulator (source component 200), every control tick: ``ATTITUDE`` (roll, pitch, yaw
  and body rates, FRD body in NED) and ``LOCAL_POSITION_NED``, ``time_boot_ms`` = simulated time;
- to the simulator, every tick: ``HIL_ACTUATOR_CONTROLS`` (controls[0..3] = motor commands in
  [0, 1]; mode bit 128 = armed; flags bit 0 = lockstep);
- log-only, every tick: ``DEBUG_FLOAT_ARRAY`` "SMC" (array_id 1) whose entries
  :data:`smcpilot.protocol.SMC_FIELDS` names, in the paper's frames (NWU world, FLU body);
- to ground stations, if one was attached: ``HEARTBEAT``, ``SYS_STATUS``, ``NAMED_VALUE_INT``
  "OVERRUN", 10 Hz copies of ``ATTITUDE`` / ``LOCAL_POSITION_NED`` (component 1) and
  ``NAMED_VALUE_FLOAT`` ``CHI_*`` / ``SIG_*``; ``STATUSTEXT`` events.

Conventions of :class:`FlightLog`
---------------------------------
- **time**: seconds since the first record of the file. Every series has its own time array
  (``att_t_s``, ``pos_t_s``, ``act_t_s``, ``smc_t_s``, ``ctrl_t_s``). In a lockstep log the record
  stamps are simulated time; the simulator's state records are stamped when they arrive, which is
  one tick before the tick that uses them, so for state messages of a lockstep log the message's
  own ``time_boot_ms`` (the simulated time of the state) is used instead, on the same time base.
- **position**: north, east (m) and altitude **up** (m) = ``-z_NED``; velocities are NED (north,
  east, **down**, m/s).
- **angles in degrees**: roll, pitch, yaw of the FRD body in NED (yaw = heading, clockwise from
  north, wrapped to [-180, 180)); body rates in deg/s.
- The controller's paper-frame quantities are converted with :mod:`smcpilot.frames`: references
  (``ref_roll_deg`` ... ``ref_alt_m``), targets (``target_north_m``, ``target_east_m``,
  ``target_alt_m``, ``target_yaw_deg`` heading). The raw channel-ordered arrays (``chi_hat``,
  ``sigma``, ``s``, ``u``: columns phi, theta, psi, z) stay in the paper's frame.
- Quantities a controller does not have (``cascade_pid`` has no sigma, chi_hat) are NaN.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, TextIO

import numpy as np

from smcpilot.protocol import (
    CHANNEL_TAGS,
    CHI_NAMES,
    FLAG_ARMED,
    FLAG_FAILSAFE,
    FLAG_LANDING,
    SIG_NAMES,
    SMC_ARRAY_ID,
    SMC_FIELDS,
)
from smcpilot.errors import SmcpilotError, TlogError, TlogFormatError
from smcpilot.frames import euler_flu_to_frd, nwu_to_ned
from smcpilot.protocol import SIM_COMPONENT_ID
from smcpilot.tlog import read_tlog

__all__ = [
    "LogError",
    "LogEvent",
    "TimeSeries",
    "FlightLog",
    "CHANNELS",
    "DEFAULT_SETTLE_S",
    "DEFAULT_SIGMA_WINDOW_S",
    "load_log",
    "summarize",
    "print_summary",
    "plot_log",
    "add_plot_arguments",
    "plot_main",
    "add_log_arguments",
    "log_main",
]

#: Channel order of the controller arrays (chi_hat, sigma, s, u): the paper's (phi, theta, psi, z).
CHANNELS: tuple[str, ...] = ("phi", "theta", "psi", "z")
#: Seconds a set-point change is given before the tracking error counts (see :func:`summarize`).
DEFAULT_SETTLE_S = 8.0
#: Length of the window over which sigma's RMS is taken: the last seconds of flight before landing.
DEFAULT_SIGMA_WINDOW_S = 5.0

SIM_COMPONENT = SIM_COMPONENT_ID
_ARMED_BIT = 128  # MAV_MODE_FLAG_SAFETY_ARMED in HIL_ACTUATOR_CONTROLS.mode
_LOCKSTEP_FLAG = 1  # HIL_ACTUATOR_CONTROLS.flags bit 0
_SMC_USED = len(SMC_FIELDS)  # 29 of the 58 floats carry data
_SMC_INDEX = {name: i for i, name in enumerate(SMC_FIELDS)}
# Target changes smaller than this (m or rad) are float noise, not a new set-point.
_SETPOINT_TOLERANCE = 1e-4
# STATUSTEXT prefixes after which the FC descends on purpose (tracking is not assessed).
_LANDING_EVENT_PREFIXES = ("Landing", "FAILSAFE", "State back", "Mode LAND", "Mode RTL", "Failsafe")

_SEVERITY_NAMES = {
    0: "EMERGENCY",
    1: "ALERT",
    2: "CRITICAL",
    3: "ERROR",
    4: "WARNING",
    5: "NOTICE",
    6: "INFO",
    7: "DEBUG",
}


class LogError(SmcpilotError):
    """A flight log is missing, unreadable or not a ``.tlog``, or an output could not be written."""


@dataclass(frozen=True)
class LogEvent:
    """One ``STATUSTEXT``: time [s since the first record], severity name, text."""

    t_s: float
    severity: str
    text: str


@dataclass(frozen=True)
class TimeSeries:
    """Samples of one named value: times [s since the first record] and values."""

    t_s: np.ndarray
    value: np.ndarray


def _empty(columns: int | None = None) -> np.ndarray:
    return np.zeros((0,) if columns is None else (0, columns), dtype=float)


@dataclass
class FlightLog:
    """A flight log as numpy arrays (see the module docstring for units and frames).

    Every group of arrays shares its time array and is empty when the log has no such messages.
    """

    #: the log file.
    path: Path
    #: records read.
    records: int = 0
    #: record stamp of the first record [µs] (None for an empty log).
    t0_us: int | None = None
    #: last minus first record stamp [s].
    log_span_s: float = 0.0
    #: True/False from HIL_ACTUATOR_CONTROLS flags bit 0; None without actuator messages.
    lockstep: bool | None = None
    #: True when reading stopped before the end of the file (cut-short or corrupt record).
    truncated: bool = False
    #: why reading stopped early, if it did.
    read_error: str | None = None
    #: notes for the reader (truncation, fallbacks).
    warnings: list[str] = field(default_factory=list)
    #: records per message type (all sources).
    message_counts: dict[str, int] = field(default_factory=dict)
    #: where ATTITUDE / LOCAL_POSITION_NED came from, e.g. "simulator (component 200)".
    state_source: str | None = None

    # ATTITUDE: FRD body in NED, degrees.
    att_t_s: np.ndarray = field(default_factory=_empty)
    roll_deg: np.ndarray = field(default_factory=_empty)
    pitch_deg: np.ndarray = field(default_factory=_empty)
    yaw_deg: np.ndarray = field(default_factory=_empty)
    roll_rate_dps: np.ndarray = field(default_factory=_empty)
    pitch_rate_dps: np.ndarray = field(default_factory=_empty)
    yaw_rate_dps: np.ndarray = field(default_factory=_empty)

    # LOCAL_POSITION_NED: north, east, altitude up; NED velocities.
    pos_t_s: np.ndarray = field(default_factory=_empty)
    north_m: np.ndarray = field(default_factory=_empty)
    east_m: np.ndarray = field(default_factory=_empty)
    alt_m: np.ndarray = field(default_factory=_empty)
    v_north_mps: np.ndarray = field(default_factory=_empty)
    v_east_mps: np.ndarray = field(default_factory=_empty)
    v_down_mps: np.ndarray = field(default_factory=_empty)

    # HIL_ACTUATOR_CONTROLS.
    act_t_s: np.ndarray = field(default_factory=_empty)
    #: motor commands in [0, 1], shape (n, 4).
    motors: np.ndarray = field(default_factory=lambda: _empty(4))
    #: armed flag per actuator message (bool).
    armed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    # DEBUG_FLOAT_ARRAY "SMC": the law's internals every tick.
    smc_t_s: np.ndarray = field(default_factory=_empty)
    #: raw SMC columns by :data:`smcpilot.protocol.SMC_FIELDS` name, paper frame, as logged.
    smc: dict[str, np.ndarray] = field(default_factory=dict)
    #: sliding variable S and law output u per channel (phi, theta, psi, z), shape (n, 4).
    s: np.ndarray = field(default_factory=lambda: _empty(4))
    u: np.ndarray = field(default_factory=lambda: _empty(4))
    #: attitude/altitude references of the law, converted to NED angles [deg] and altitude [m].
    ref_roll_deg: np.ndarray = field(default_factory=_empty)
    ref_pitch_deg: np.ndarray = field(default_factory=_empty)
    ref_yaw_deg: np.ndarray = field(default_factory=_empty)
    ref_alt_m: np.ndarray = field(default_factory=_empty)
    #: position/heading set-point (north, east, altitude up [m]; heading [deg], [-180, 180)).
    target_north_m: np.ndarray = field(default_factory=_empty)
    target_east_m: np.ndarray = field(default_factory=_empty)
    target_alt_m: np.ndarray = field(default_factory=_empty)
    target_yaw_deg: np.ndarray = field(default_factory=_empty)
    #: mixer saturation bits: 1 phi, 2 theta, 4 psi, 8 z (int).
    limited_mask: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    # chi_hat and sigma per channel: from the SMC arrays if present, else NAMED_VALUE_FLOAT.
    ctrl_t_s: np.ndarray = field(default_factory=_empty)
    chi_hat: np.ndarray = field(default_factory=lambda: _empty(4))
    sigma: np.ndarray = field(default_factory=lambda: _empty(4))
    #: "DEBUG_FLOAT_ARRAY SMC", "NAMED_VALUE_FLOAT" or None.
    ctrl_source: str | None = None

    #: every NAMED_VALUE_FLOAT / NAMED_VALUE_INT by name.
    named_floats: dict[str, TimeSeries] = field(default_factory=dict)
    named_ints: dict[str, TimeSeries] = field(default_factory=dict)
    #: FC parameters logged in the flight (PARAM_VALUE: the start-up configuration, later changes), last value wins.
    params: dict[str, float] = field(default_factory=dict)
    #: STATUSTEXT events in file order.
    events: list[LogEvent] = field(default_factory=list)
    #: last NAMED_VALUE_INT "OVERRUN" (cumulative missed deadlines), None if never sent.
    overruns: int | None = None

    @property
    def name(self) -> str:
        """The log's file name."""
        return self.path.name

    @property
    def has_smc(self) -> bool:
        """True when the log holds the per-tick ``DEBUG_FLOAT_ARRAY`` "SMC" records."""
        return self.smc_t_s.size > 0

    @property
    def duration_s(self) -> float:
        """Simulated duration: span of the state times if there is state, else of the records."""
        for t in (self.att_t_s, self.pos_t_s):
            if t.size:
                return float(t[-1] - t[0])
        return self.log_span_s

    @property
    def tilt_deg(self) -> np.ndarray:
        """Angle between body z and the vertical, acos(cos(roll) cos(pitch)) [deg], at ``att_t_s``."""
        c = np.cos(np.radians(self.roll_deg)) * np.cos(np.radians(self.pitch_deg))
        return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


# -- loading -----------------------------------------------------------------------------------------
def _wrap_deg(angle_deg: np.ndarray) -> np.ndarray:
    """Wrap angles [deg] to [-180, 180) (NaN stays NaN), like :func:`smcpilot.frames.wrap_pi`."""
    a = np.mod(np.asarray(angle_deg, dtype=float) + 180.0, 360.0) - 180.0
    return np.where(a >= 180.0, a - 360.0, a)


def _pick_source(by_source: dict[tuple[int, int], list[tuple]]) -> tuple[tuple[int, int] | None, list[tuple]]:
    """The simulator's copy (component 200) if present, else the source with the most records."""
    if not by_source:
        return None, []
    sims = [k for k in by_source if k[1] == SIM_COMPONENT]
    key = max(sims or by_source, key=lambda k: len(by_source[k]))
    return key, by_source[key]


def _describe_source(key: tuple[int, int]) -> str:
    system, component = key
    who = "simulator" if component == SIM_COMPONENT else "GCS telemetry"
    return f"{who} (system {system}, component {component})"


def _state_times(rows: np.ndarray, t0_us: int, use_boot_time: bool) -> np.ndarray:
    """Times [s] of state rows (column 0 = record stamp µs, column 1 = time_boot_ms)."""
    if use_boot_time:
        return rows[:, 1] * 1e-3 - t0_us * 1e-6
    return (rows[:, 0] - t0_us) * 1e-6


def load_log(path: str | os.PathLike[str]) -> FlightLog:
    """Read the ``.tlog`` at ``path`` into a :class:`FlightLog`.

    An empty file gives an empty log. A log whose last record is cut short (or that holds a
    corrupt record) keeps every record before it, with ``truncated`` set and the reason in
    ``read_error`` and ``warnings``. Logs without the "SMC" arrays take chi_hat and sigma from
    ``NAMED_VALUE_FLOAT`` ``CHI_*`` / ``SIG_*`` (10 Hz) if present.

    Raises :class:`LogError` when the file is missing or unreadable, or is not a ``.tlog``.
    """
    p = Path(path)
    if not p.exists():
        raise LogError(f"no such log file: {p}")
    if p.is_dir():
        raise LogError(f"{p} is a directory, not a .tlog file")
    log = FlightLog(path=p)

    counts: dict[str, int] = {}
    att: dict[tuple[int, int], list[tuple]] = {}
    pos: dict[tuple[int, int], list[tuple]] = {}
    act: list[tuple] = []
    lockstep_flags: list[bool] = []
    smc_t: list[int] = []
    smc_rows: list[list[float]] = []
    named_f: dict[str, list[tuple[int, float]]] = {}
    named_i: dict[str, list[tuple[int, int]]] = {}
    events: list[tuple[int, int, str]] = []
    first_us: int | None = None
    last_us = 0

    records = 0
    try:
        for time_us, msg in read_tlog(p):
            records += 1
            if first_us is None:
                first_us = time_us
            last_us = time_us
            mtype = msg.get_type()
            counts[mtype] = counts.get(mtype, 0) + 1
            if mtype == "ATTITUDE":
                key = (msg.get_srcSystem(), msg.get_srcComponent())
                att.setdefault(key, []).append(
                    (time_us, msg.time_boot_ms, msg.roll, msg.pitch, msg.yaw, msg.rollspeed, msg.pitchspeed, msg.yawspeed)
                )
            elif mtype == "LOCAL_POSITION_NED":
                key = (msg.get_srcSystem(), msg.get_srcComponent())
                pos.setdefault(key, []).append((time_us, msg.time_boot_ms, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz))
            elif mtype == "PARAM_VALUE":
                pid = msg.param_id
                name = (pid.decode("ascii", "replace") if isinstance(pid, bytes) else str(pid)).split("\x00", 1)[0]
                log.params[name] = float(msg.param_value)
            elif mtype == "HIL_ACTUATOR_CONTROLS":
                c = msg.controls
                act.append((time_us, c[0], c[1], c[2], c[3], msg.mode & _ARMED_BIT))
                lockstep_flags.append(bool(msg.flags & _LOCKSTEP_FLAG))
            elif mtype == "DEBUG_FLOAT_ARRAY":
                if msg.name == "SMC" and msg.array_id == SMC_ARRAY_ID:
                    smc_t.append(time_us)
                    smc_rows.append(list(msg.data[:_SMC_USED]))
            elif mtype == "NAMED_VALUE_FLOAT":
                named_f.setdefault(msg.name, []).append((time_us, msg.value))
            elif mtype == "NAMED_VALUE_INT":
                named_i.setdefault(msg.name, []).append((time_us, msg.value))
            elif mtype == "STATUSTEXT":
                events.append((time_us, msg.severity, msg.text))
    except TlogFormatError as exc:
        reason = str(exc)
        prefix = f"{p}: "
        if reason.startswith(prefix):
            reason = reason[len(prefix) :]
        if records == 0:
            raise LogError(f"{p} is not a MAVLink telemetry log (.tlog): {reason}") from exc
        log.truncated = True
        log.read_error = reason
        log.warnings.append(f"reading stopped after {records} records: {reason}")
    except TlogError as exc:
        raise LogError(str(exc)) from exc

    log.records = records
    log.message_counts = dict(sorted(counts.items()))
    if first_us is None:
        log.warnings.append("the log is empty")
        return log
    t0 = first_us
    log.t0_us = t0
    log.log_span_s = (last_us - t0) * 1e-6

    # Actuators first: they tell whether the record stamps are simulated time (lockstep).
    if act:
        a = np.asarray(act, dtype=float)
        log.act_t_s = (a[:, 0] - t0) * 1e-6
        log.motors = a[:, 1:5]
        log.armed = a[:, 5] > 0
        log.lockstep = any(lockstep_flags)
    use_boot = bool(log.lockstep)

    # State: the simulator's copy at full rate, else whatever exists.
    att_key, att_rows = _pick_source(att)
    if att_rows:
        r = np.asarray(att_rows, dtype=float)
        log.att_t_s = _state_times(r, t0, use_boot)
        roll, pitch, yaw = (np.degrees(r[:, k]) for k in (2, 3, 4))
        log.roll_deg, log.pitch_deg, log.yaw_deg = roll, pitch, _wrap_deg(yaw)
        log.roll_rate_dps, log.pitch_rate_dps, log.yaw_rate_dps = (np.degrees(r[:, k]) for k in (5, 6, 7))
    pos_key, pos_rows = _pick_source(pos)
    if pos_rows:
        r = np.asarray(pos_rows, dtype=float)
        log.pos_t_s = _state_times(r, t0, use_boot)
        log.north_m, log.east_m, log.alt_m = r[:, 2], r[:, 3], -r[:, 4]
        log.v_north_mps, log.v_east_mps, log.v_down_mps = r[:, 5], r[:, 6], r[:, 7]
    if att_key is not None or pos_key is not None:
        log.state_source = _describe_source(att_key if att_key is not None else pos_key)  # type: ignore[arg-type]
        if att_key is not None and att_key[1] != SIM_COMPONENT:
            log.warnings.append(f"no simulator state in the log: using ATTITUDE from {_describe_source(att_key)}")

    # Controller internals.
    if smc_rows:
        m = np.asarray(smc_rows, dtype=float)
        log.smc_t_s = (np.asarray(smc_t, dtype=float) - t0) * 1e-6
        log.smc = {name: m[:, i] for i, name in enumerate(SMC_FIELDS)}
        col = log.smc
        log.s = m[:, _SMC_INDEX["s_phi"] : _SMC_INDEX["s_phi"] + 4]
        log.u = m[:, _SMC_INDEX["u_phi"] : _SMC_INDEX["u_phi"] + 4]
        roll_r, pitch_r, yaw_r = euler_flu_to_frd(col["ref_phi"], col["ref_theta"], col["ref_psi"])
        log.ref_roll_deg = np.degrees(roll_r)
        log.ref_pitch_deg = np.degrees(pitch_r)
        log.ref_yaw_deg = _wrap_deg(np.degrees(yaw_r))
        log.ref_alt_m = col["ref_z"].copy()  # paper z is already up
        north, east, down = nwu_to_ned((col["target_x"], col["target_y"], col["target_z"]))
        log.target_north_m, log.target_east_m, log.target_alt_m = north, east, -down
        log.target_yaw_deg = _wrap_deg(np.degrees(euler_flu_to_frd(0.0, 0.0, col["target_yaw"])[2]))
        mask = col["limited_mask"]
        log.limited_mask = np.where(np.isfinite(mask), mask, 0).astype(int)
        log.ctrl_t_s = log.smc_t_s
        log.chi_hat = m[:, _SMC_INDEX["chi_phi"] : _SMC_INDEX["chi_phi"] + 4]
        log.sigma = m[:, _SMC_INDEX["sigma_phi"] : _SMC_INDEX["sigma_phi"] + 4]
        log.ctrl_source = "DEBUG_FLOAT_ARRAY SMC"
    elif any(n in named_f for n in CHI_NAMES + SIG_NAMES):
        log.ctrl_t_s, columns = _align_named(named_f, CHI_NAMES + SIG_NAMES, t0)
        log.chi_hat, log.sigma = columns[:, :4], columns[:, 4:]
        log.ctrl_source = "NAMED_VALUE_FLOAT"
        log.warnings.append("no DEBUG_FLOAT_ARRAY SMC records: chi_hat and sigma from NAMED_VALUE_FLOAT telemetry")

    log.named_floats = {
        k: TimeSeries((np.asarray([t for t, _ in v], dtype=float) - t0) * 1e-6, np.asarray([x for _, x in v], dtype=float))
        for k, v in sorted(named_f.items())
    }
    log.named_ints = {
        k: TimeSeries((np.asarray([t for t, _ in v], dtype=float) - t0) * 1e-6, np.asarray([x for _, x in v], dtype=np.int64))
        for k, v in sorted(named_i.items())
    }
    if "OVERRUN" in named_i:
        log.overruns = int(named_i["OVERRUN"][-1][1])
    log.events = [LogEvent((t - t0) * 1e-6, _SEVERITY_NAMES.get(sev, str(sev)), text) for t, sev, text in events]
    return log


def _align_named(named: dict[str, list[tuple[int, float]]], names: tuple[str, ...], t0_us: int) -> tuple[np.ndarray, np.ndarray]:
    """Put several NAMED_VALUE_FLOAT series on their union of record times (missing: NaN)."""
    stamps = np.unique(np.concatenate([np.asarray([t for t, _ in named.get(n, [])], dtype=np.int64) for n in names]))
    out = np.full((stamps.size, len(names)), np.nan)
    for j, n in enumerate(names):
        rows = named.get(n)
        if rows:
            idx = np.searchsorted(stamps, np.asarray([t for t, _ in rows], dtype=np.int64))
            out[idx, j] = [v for _, v in rows]
    return (stamps - t0_us) * 1e-6, out


# -- summary -----------------------------------------------------------------------------------------
def _hold(t_src: np.ndarray, values: np.ndarray, t_query: np.ndarray) -> np.ndarray:
    """Zero-order hold: the latest sample of ``values`` at or before each ``t_query`` (NaN before the first)."""
    idx = np.searchsorted(t_src, t_query, side="right") - 1
    out = np.full(t_query.shape + values.shape[1:], np.nan)
    ok = idx >= 0
    if t_src.size:
        out[ok] = values[idx[ok]]
    return out


def _setpoint_changes(log: FlightLog) -> np.ndarray:
    """Mask over ``smc_t_s``: the first tick and every tick whose north/east/altitude/heading
    set-point differs from the previous tick's."""
    n = log.smc_t_s.size
    changed = np.zeros(n, dtype=bool)
    if n:
        target = np.column_stack([log.target_north_m, log.target_east_m, log.target_alt_m])
        changed[0] = True
        changed[1:] |= np.any(np.abs(np.diff(target, axis=0)) > _SETPOINT_TOLERANCE, axis=1)
        changed[1:] |= np.abs(_wrap_deg(np.diff(log.target_yaw_deg))) > math.degrees(_SETPOINT_TOLERANCE)
    return changed


def _tracking_masks(log: FlightLog, settle_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(holding, settled) masks over ``smc_t_s``; see :func:`summarize`."""
    t = log.smc_t_s
    n = t.size
    if log.act_t_s.size:
        armed = _hold(log.act_t_s, log.armed.astype(float), t) > 0.5
    else:
        armed = np.isfinite(log.ref_alt_m)
    changed = _setpoint_changes(log)
    if n:
        changed[1:] |= armed[1:] & ~armed[:-1]
    change_idx = np.flatnonzero(changed)
    last_change_t = t[change_idx[np.searchsorted(change_idx, np.arange(n), side="right") - 1]] if n else t
    flags = log.smc.get("flags") if log.smc else None
    # (All zeros means a log written before the FC logged its flags: a real FC run sets at least
    # POSITION_HOLD.)
    if flags is not None and flags.size == n and n and np.all(np.isfinite(flags)) and np.any(flags != 0):
        # The FC logs its state every tick: landing/failsafe bits are exact.
        bits = flags.astype(np.int64)
        armed = (bits & FLAG_ARMED) != 0
        landing = (bits & (FLAG_LANDING | FLAG_FAILSAFE)) != 0
        holding = armed & ~landing
        settled = holding & (t - last_change_t >= settle_s)
        return holding, settled
    # Older logs: landing (or failsafe descent) from its event until the next set-point change.
    landing = np.zeros(n, dtype=bool)
    for ev in log.events:
        if ev.text.startswith(_LANDING_EVENT_PREFIXES):
            later_changes = t[change_idx][t[change_idx] > ev.t_s]
            end = later_changes[0] if later_changes.size else np.inf
            landing |= (t >= ev.t_s) & (t < end)
    holding = armed & ~landing
    settled = holding & (t - last_change_t >= settle_s)
    return holding, settled


def _num(x: Any) -> Any:
    """A JSON-safe number: float/int, or None for NaN, inf and missing values."""
    if x is None:
        return None
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    v = float(x)
    return v if math.isfinite(v) else None


def _rms(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if x.size else None


def _sigma_window(log: FlightLog, window_s: float) -> np.ndarray:
    """Mask over ``ctrl_t_s``: the last ``window_s`` seconds ending at the last tick with a finite
    sigma while holding (armed, not landing); without "SMC" records, at the last finite sigma."""
    t = log.ctrl_t_s
    finite = np.any(np.isfinite(log.sigma), axis=1)
    if log.has_smc and log.ctrl_t_s is log.smc_t_s:
        holding, _ = _tracking_masks(log, 0.0)
        if np.any(finite & holding):
            finite = finite & holding
    if not finite.any():
        return np.zeros(t.size, dtype=bool)
    t_end = t[np.flatnonzero(finite)[-1]]
    return (t >= t_end - window_s) & (t <= t_end)


def summarize(
    log: FlightLog, *, settle_s: float = DEFAULT_SETTLE_S, sigma_window_s: float = DEFAULT_SIGMA_WINDOW_S
) -> dict[str, Any]:
    """Headline numbers of a flight, as a JSON-serialisable dict (NaN and missing values are None).

    Tracking error is evaluated at the controller ticks (the "SMC" records, which carry the
    set-point), with the vehicle position held from the latest state sample:

    - the *position error* is the 3-D distance from the vehicle (north, east, altitude) to the
      position set-point; the *yaw error* is yaw minus the heading set-point, wrapped to ±180°;
    - a tick is *holding* when the vehicle is armed and not landing (from a "Landing",
      "FAILSAFE ..." or "State back ..." event until the next set-point change);
    - a tick is *settled* when it is holding and at least ``settle_s`` seconds have passed since
      the last set-point change (any change of the north/east/altitude/heading target, or
      arming); the first tick of the log counts as a change;
    - ``position_error_rms_m`` / ``_max_m`` (and the yaw RMS) are over the settled ticks
      (``settled_time_s`` says how much flight that is; None if none);
    - ``position_error_final_m`` and ``yaw_error_final_deg`` are at the last holding tick,
      settled or not, so a log that ends mid-manoeuvre reports the error it ended with.

    Other entries: ``duration_s`` (simulated, see :attr:`FlightLog.duration_s`), ``armed_time_s``
    (sum of the actuator-message intervals that start armed), ``max_tilt_deg`` (largest
    acos(cos roll · cos pitch)), ``chi_hat_final`` (last finite value per channel phi, theta, psi,
    z), ``sigma_rms_last_s`` (RMS of sigma per channel over the last ``sigma_window_s`` seconds of
    flight while holding, i.e. before a final landing; NaN samples ignored), ``overruns`` (last OVERRUN count), ``message_counts`` and ``events``.
    """
    out: dict[str, Any] = {
        "log": log.name,
        "path": str(log.path),
        "records": log.records,
        "truncated": log.truncated,
        "read_error": log.read_error,
        "warnings": list(log.warnings),
        "lockstep": log.lockstep,
        "state_source": log.state_source,
        "controller_data": log.ctrl_source,
        "duration_s": _num(log.duration_s) if log.records else None,
        "message_counts": dict(log.message_counts),
        "overruns": log.overruns,
    }

    # Armed time.
    if log.act_t_s.size:
        t = log.act_t_s
        dt = np.diff(t)
        last_dt = float(np.median(dt)) if dt.size else 0.0
        dt = np.append(dt, last_dt)
        out["armed_time_s"] = _num(np.sum(dt[log.armed]))
    else:
        out["armed_time_s"] = None
    out["max_tilt_deg"] = _num(np.nanmax(log.tilt_deg)) if log.att_t_s.size and np.isfinite(log.tilt_deg).any() else None

    # Tracking.
    out["settle_s"] = settle_s
    tracking: dict[str, Any] = {
        "settled_time_s": None,
        "position_error_final_m": None,
        "position_error_final_ned_m": None,
        "position_error_rms_m": None,
        "position_error_max_m": None,
        "yaw_error_final_deg": None,
        "yaw_error_rms_deg": None,
    }
    if log.has_smc and log.pos_t_s.size:
        t = log.smc_t_s
        holding, settled = _tracking_masks(log, settle_s)
        pos = _hold(log.pos_t_s, np.column_stack([log.north_m, log.east_m, log.alt_m]), t)
        target = np.column_stack([log.target_north_m, log.target_east_m, log.target_alt_m])
        err_vec = pos - target
        err = np.linalg.norm(err_vec, axis=1)
        yaw_err = (
            _wrap_deg(_hold(log.att_t_s, log.yaw_deg, t) - log.target_yaw_deg) if log.att_t_s.size else np.full(t.size, np.nan)
        )
        if settled.any():
            dt_tick = float(np.median(np.diff(t))) if t.size > 1 else 0.0
            tracking["settled_time_s"] = _num(settled.sum() * dt_tick)
            tracking["position_error_rms_m"] = _num(_rms(err[settled]))
            tracking["position_error_max_m"] = _num(np.nanmax(err[settled])) if np.isfinite(err[settled]).any() else None
            tracking["yaw_error_rms_deg"] = _num(_rms(yaw_err[settled]))
        hold_idx = np.flatnonzero(holding)
        if hold_idx.size:
            k = hold_idx[-1]
            tracking["position_error_final_m"] = _num(err[k])
            tracking["position_error_final_ned_m"] = {
                "north": _num(err_vec[k, 0]),
                "east": _num(err_vec[k, 1]),
                "alt": _num(err_vec[k, 2]),
            }
            tracking["yaw_error_final_deg"] = _num(yaw_err[k])
    out.update(tracking)

    # Adaptive gains and manifolds.
    out["channels"] = list(CHANNELS)
    if log.ctrl_t_s.size:
        chi_final = []
        for j in range(4):
            finite = log.chi_hat[:, j][np.isfinite(log.chi_hat[:, j])]
            chi_final.append(_num(finite[-1]) if finite.size else None)
        window = _sigma_window(log, sigma_window_s)
        sig_rms = [_num(_rms(log.sigma[window, j])) for j in range(4)]
        out["chi_hat_final"] = chi_final if any(v is not None for v in chi_final) else None
        out["sigma_rms_last_s"] = sig_rms if any(v is not None for v in sig_rms) else None
    else:
        out["chi_hat_final"] = None
        out["sigma_rms_last_s"] = None
    out["sigma_window_s"] = sigma_window_s
    out["events"] = [{"t_s": round(e.t_s, 6), "severity": e.severity, "text": e.text} for e in log.events]
    return out


def _fmt(v: Any, spec: str = ".3f", unit: str = "") -> str:
    return "n/a" if v is None else f"{v:{spec}}{unit}"


def print_summary(summary: dict[str, Any], file: TextIO | None = None) -> None:
    """Print a :func:`summarize` dict as a readable text block to ``file`` (default stdout)."""
    f = file if file is not None else sys.stdout
    s = summary
    w = 22

    def line(label: str, text: str) -> None:
        print(f"{label:<{w}}{text}", file=f)

    mode = {True: "lockstep", False: "real time", None: "timing unknown"}[s.get("lockstep")]
    line("Log", f"{s['log']}  ({s['records']} records, {mode})")
    if s.get("truncated"):
        line("  TRUNCATED", str(s.get("read_error")))
    for note in s.get("warnings", []):
        if not (s.get("truncated") and note.startswith("reading stopped")):
            line("  note", note)
    line("Duration", f"{_fmt(s.get('duration_s'), '.2f', ' s simulated')}, armed {_fmt(s.get('armed_time_s'), '.2f', ' s')}")
    line("Overruns", "n/a (no OVERRUN telemetry)" if s.get("overruns") is None else str(s["overruns"]))
    line("State from", s.get("state_source") or "n/a")
    line("Controller data", s.get("controller_data") or "n/a")
    line("Max tilt", _fmt(s.get("max_tilt_deg"), ".1f", " deg"))
    settle = s.get("settle_s")
    if s.get("settled_time_s") is None:
        line("Tracking", f"no settled flight (needs SMC set-points held >= {settle:g} s while armed)")
    else:
        line("Tracking", f"{s['settled_time_s']:.1f} s of settled flight (>= {settle:g} s after a set-point change)")
    line(
        "  position error",
        f"final {_fmt(s.get('position_error_final_m'), '.3g', ' m')}, RMS {_fmt(s.get('position_error_rms_m'), '.3g', ' m')},"
        f" max {_fmt(s.get('position_error_max_m'), '.3g', ' m')}",
    )
    ned = s.get("position_error_final_ned_m")
    if ned:
        line("    final N/E/alt", "  ".join(_fmt(ned[k], "+.3g", " m") for k in ("north", "east", "alt")))
    line(
        "  yaw error",
        f"final {_fmt(s.get('yaw_error_final_deg'), '+.3g', ' deg')}, RMS {_fmt(s.get('yaw_error_rms_deg'), '.3g', ' deg')}",
    )
    chans = s.get("channels", list(CHANNELS))
    chi = s.get("chi_hat_final")
    line("chi_hat final", "n/a" if chi is None else "  ".join(f"{c} {_fmt(v, '.3f')}" for c, v in zip(chans, chi)))
    sig = s.get("sigma_rms_last_s")
    line(
        f"sigma RMS last {s.get('sigma_window_s', DEFAULT_SIGMA_WINDOW_S):g} s",
        "n/a" if sig is None else "  ".join(f"{c} {_fmt(v, '.2e')}" for c, v in zip(chans, sig)),
    )
    counts = s.get("message_counts", {})
    line("Messages", ", ".join(f"{k} {v}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1])) or "none")
    events = s.get("events", [])
    line("Events", "none" if not events else "")
    for e in events:
        print(f"  {e['t_s']:9.3f} s  {e['severity']:<9} {e['text']}", file=f)


# -- plots -------------------------------------------------------------------------------------------
def _pyplot():  # type: ignore[no-untyped-def]
    """matplotlib.pyplot on the Agg backend (imported on first use: summaries do not pay for it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _logged_adaptation(log: FlightLog) -> tuple[tuple[float, float] | None, float | None]:
    """chi_hat's projection bounds (min, max) and sigma's dead zone as the flight's log records
    them (the FC logs its parameters at start); None where the log does not say."""
    p = log.params
    bounds = (p["SMC_CHI_MIN"], p["SMC_CHI_MAX"]) if "SMC_CHI_MIN" in p and "SMC_CHI_MAX" in p else None
    return bounds, p.get("SMC_CHI_DZ")


def _armed_spans(t: np.ndarray, armed: np.ndarray) -> list[tuple[float, float]]:
    """[start, end) times of the armed stretches."""
    if not t.size:
        return []
    a = armed.astype(np.int8)
    edges = np.diff(np.concatenate([[0], a, [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    t_ext = np.append(t, t[-1])
    return [(float(t[s]), float(t_ext[e])) for s, e in zip(starts, ends)]


def _unwrap_deg(a: np.ndarray) -> np.ndarray:
    """Unwrap an angle series [deg] (NaN gaps kept)."""
    out = np.full(a.shape, np.nan)
    ok = np.isfinite(a)
    if ok.any():
        out[ok] = np.degrees(np.unwrap(np.radians(a[ok])))
    return out


def _align_turns(a: np.ndarray, like: np.ndarray) -> np.ndarray:
    """Shift unwrapped angles ``a`` [deg] by whole turns to start near ``like``'s first finite value."""
    fa, fl = a[np.isfinite(a)], like[np.isfinite(like)]
    if not fa.size or not fl.size:
        return a
    return a - 360.0 * np.round((fa[0] - fl[0]) / 360.0)


def _draw_bounds(ax, chi: np.ndarray, bounds: tuple[float, float], source: str) -> None:  # type: ignore[no-untyped-def]
    """chi_hat's projection bounds: lines if they lie near the data, else a note (so growth stays visible)."""
    lo, hi = bounds
    finite = chi[np.isfinite(chi)]
    if not finite.size:
        return
    c_min, c_max = float(finite.min()), float(finite.max())
    pad = max(c_max - c_min, 0.05 * max(abs(c_max), 1.0))
    view = (c_min - pad, c_max + pad)
    far = []
    label: str | None = f"bounds ({source})"
    for b in (lo, hi):
        if not math.isfinite(b):
            continue
        if view[0] - 2 * pad <= b <= view[1] + 2 * pad:
            ax.axhline(b, color="tab:red", ls="--", lw=0.8, label=label)
            label = None
            view = (min(view[0], b - 0.1 * pad), max(view[1], b + 0.1 * pad))
        else:
            far.append(b)
    ax.set_ylim(*view)
    if far:
        ax.text(
            0.01, 0.04, f"bounds [{lo:g}, {hi:g}] ({source}) off-scale", transform=ax.transAxes, fontsize=7, color="tab:red",
        )  # fmt: skip


def _finite(*arrays: np.ndarray) -> bool:
    return any(a.size and np.isfinite(a).any() for a in arrays)


def _mark_events(ax, log: FlightLog, label: bool) -> None:  # type: ignore[no-untyped-def]
    """Dotted vertical lines at the STATUSTEXT events; with ``label``, their texts (same-time ones joined)."""
    merged: dict[float, list[str]] = {}
    for e in log.events:
        merged.setdefault(round(e.t_s, 3), []).append(e.text)
    for t_s, texts in merged.items():
        ax.axvline(t_s, color="0.4", ls=":", lw=0.8)
        if label:
            ax.annotate(
                "; ".join(texts), (t_s, 1.0), xycoords=("data", "axes fraction"), xytext=(2, -2), textcoords="offset points",
                fontsize=7, color="0.3", rotation=90, va="top", ha="left",
            )  # fmt: skip


def _distinct_poses(east_m: np.ndarray, north_m: np.ndarray, yaw_rad: np.ndarray, min_move_m: float, min_turn_rad: float) -> np.ndarray:
    """Indices of poses that moved or turned enough since the last kept one (hover spots keep one arrow)."""
    keep: list[int] = []
    for k in range(east_m.size):
        if not (math.isfinite(east_m[k]) and math.isfinite(north_m[k]) and math.isfinite(yaw_rad[k])):
            continue
        if keep:
            j = keep[-1]
            moved = math.hypot(east_m[k] - east_m[j], north_m[k] - north_m[j])
            turned = abs(math.remainder(yaw_rad[k] - yaw_rad[j], 2 * math.pi))
            if moved < min_move_m and turned < min_turn_rad:
                continue
        keep.append(k)
    return np.asarray(keep, dtype=int)


def _shade_armed(ax, log: FlightLog, label: str | None = None) -> None:  # type: ignore[no-untyped-def]
    for k, (a, b) in enumerate(_armed_spans(log.act_t_s, log.armed)):
        ax.axvspan(a, b, color="tab:green", alpha=0.08, lw=0, label=label if k == 0 else None)


def plot_log(
    log: FlightLog,
    out_dir: str | os.PathLike[str],
    *,
    chi_bounds: tuple[float, float] | None | str = "default",
) -> list[Path]:
    """Write PNG figures of ``log`` into ``out_dir`` (created if needed); return their paths.

    Figures (each skipped when the log has no data for it): ``position.png`` (north, east,
    altitude vs set-point and altitude reference, and the position error), ``attitude.png`` (roll,
    pitch, yaw vs the law's references and the heading set-point), ``motors.png`` (motor commands
    with armed stretches shaded, and mixer saturation), ``controller.png`` (sigma and chi_hat per
    channel) and ``track.png`` (top-down north/east track with set-points and headings). Each is
    titled with the log's file name.

    ``chi_bounds`` = (min, max) names chi_hat's projection bounds (drawn when near the data, else
    written in the panel); the default uses the bounds the log records (the FC logs its parameters
    at start: SMC_CHI_MIN/MAX) and also shades the logged sigma dead zone (SMC_CHI_DZ); an older
    log without them gets neither; None: neither.
    """
    plt = _pyplot()
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LogError(f"cannot create plot directory {out}: {exc.strerror}") from exc
    logged_bounds, dead_zone = _logged_adaptation(log)
    if chi_bounds == "default":
        bounds, bounds_source = logged_bounds, "logged"
    else:
        bounds, bounds_source, dead_zone = chi_bounds, "given", None  # type: ignore[assignment]

    figures: list[tuple[str, Any]] = [
        ("position.png", _figure_position(plt, log)),
        ("attitude.png", _figure_attitude(plt, log)),
        ("motors.png", _figure_motors(plt, log)),
        ("controller.png", _figure_controller(plt, log, bounds, dead_zone, bounds_source)),
        ("track.png", _figure_track(plt, log)),
    ]
    paths: list[Path] = []
    for i, (name, fig) in enumerate(figures):
        if fig is None:
            continue
        path = out / name
        try:
            fig.tight_layout()
            fig.savefig(path, dpi=110)
        except OSError as exc:
            for _, other in figures[i:]:
                if other is not None:
                    plt.close(other)
            raise LogError(f"cannot write {path}: {exc.strerror}") from exc
        plt.close(fig)
        paths.append(path)
    return paths


def _target_ne_alt(log: FlightLog) -> np.ndarray:
    return np.column_stack([log.target_north_m, log.target_east_m, log.target_alt_m])


def _figure_position(plt, log: FlightLog):  # type: ignore[no-untyped-def]
    """(a) north, east, altitude vs set-point (and the shaped altitude reference); position error."""
    has_pos = log.pos_t_s.size > 0
    has_target = log.has_smc and _finite(log.target_north_m)
    if not (has_pos or has_target):
        return None
    rows = 4 if (has_pos and has_target) else 3
    fig, axes = plt.subplots(rows, 1, figsize=(11, 2.1 * rows + 0.9), sharex=True, squeeze=False)
    axes = axes[:, 0]
    fig.suptitle(f"{log.name}: position vs set-point (north, east, altitude up)")
    series = [
        ("north [m]", log.north_m, log.target_north_m, None),
        ("east [m]", log.east_m, log.target_east_m, None),
        ("altitude [m]", log.alt_m, log.target_alt_m, log.ref_alt_m),
    ]
    for k, (ax, (ylabel, actual, target, ref)) in enumerate(zip(axes, series)):
        if has_pos:
            ax.plot(log.pos_t_s, actual, color="tab:blue", lw=1.3, label="vehicle")
        if has_target:
            ax.plot(log.smc_t_s, target, color="k", ls="--", lw=1.0, drawstyle="steps-post", label="set-point")
        if ref is not None and _finite(ref):
            ax.plot(log.smc_t_s, ref, color="tab:orange", lw=0.9, alpha=0.8, label="reference (shaped)")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        if k == 0 or (ref is not None and _finite(ref)):
            ax.legend(fontsize=8, loc="best")
    if rows == 4:
        ax = axes[3]
        pos = _hold(log.pos_t_s, np.column_stack([log.north_m, log.east_m, log.alt_m]), log.smc_t_s)
        holding, settled = _tracking_masks(log, DEFAULT_SETTLE_S)
        err = np.where(holding, np.linalg.norm(pos - _target_ne_alt(log), axis=1), np.nan)  # not landing/disarmed
        ax.plot(log.smc_t_s, err, color="tab:red", lw=1.1, label="|position − set-point| (armed, not landing)")
        ax.fill_between(
            log.smc_t_s, 0, 1, where=settled, transform=ax.get_xaxis_transform(), color="tab:purple", alpha=0.1, lw=0,
            label=f"settled (≥ {DEFAULT_SETTLE_S:g} s after a change)",
        )  # fmt: skip
        if np.any(err > 0):
            ax.set_yscale("log")
        ax.set_ylabel("error [m]")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8, loc="lower right")
    for k, ax in enumerate(axes):
        _mark_events(ax, log, label=k == 0)
    axes[-1].set_xlabel("t [s]")
    return fig


def _figure_attitude(plt, log: FlightLog):  # type: ignore[no-untyped-def]
    """(b) roll, pitch, yaw (unwrapped) vs the law's references and the heading set-point."""
    has_att = log.att_t_s.size > 0
    has_ref = log.has_smc and _finite(log.ref_roll_deg, log.ref_yaw_deg)
    if not (has_att or has_ref):
        return None
    fig, axes = plt.subplots(3, 1, figsize=(11, 7.2), sharex=True)
    fig.suptitle(f"{log.name}: attitude vs reference (NED/FRD)")
    # Unwrap so a turn through ±180° reads as one curve; start the vehicle's yaw in [-180, 180).
    yaw = _unwrap_deg(log.yaw_deg)
    if _finite(yaw):
        yaw = _align_turns(yaw, _wrap_deg(yaw[np.isfinite(yaw)][:1]))
    ref_yaw = _align_turns(_unwrap_deg(log.ref_yaw_deg), yaw)
    target_yaw = _align_turns(_unwrap_deg(log.target_yaw_deg), yaw)
    series = [
        ("roll [deg]", log.roll_deg, log.ref_roll_deg),
        ("pitch [deg]", log.pitch_deg, log.ref_pitch_deg),
        ("yaw [deg] (unwrapped)", yaw, ref_yaw),
    ]
    for k, (ax, (ylabel, actual, ref)) in enumerate(zip(axes, series)):
        if has_att:
            ax.plot(log.att_t_s, actual, color="tab:blue", lw=1.2, label="vehicle")
        if has_ref:
            ax.plot(log.smc_t_s, ref, color="tab:orange", ls="--", lw=1.0, label="reference")
        if k == 2 and has_ref and _finite(target_yaw):
            ax.plot(log.smc_t_s, target_yaw, color="k", ls=":", lw=1.0, drawstyle="steps-post", label="heading set-point")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        _mark_events(ax, log, label=k == 0)
    axes[0].legend(fontsize=8, loc="best")
    axes[2].legend(fontsize=8, loc="best")
    axes[-1].set_xlabel("t [s]")
    return fig


def _figure_motors(plt, log: FlightLog):  # type: ignore[no-untyped-def]
    """(c) motor commands with armed stretches shaded; mixer saturation per channel if any."""
    if not log.act_t_s.size:
        return None
    limited = log.has_smc and bool(np.any(log.limited_mask))
    if limited:
        fig, (ax, axl) = plt.subplots(2, 1, figsize=(11, 5.6), sharex=True, gridspec_kw={"height_ratios": [4, 1]})
    else:
        fig, ax = plt.subplots(1, 1, figsize=(11, 4.6))
    fig.suptitle(f"{log.name}: motor commands (HIL_ACTUATOR_CONTROLS)")
    _shade_armed(ax, log, label="armed")
    for j in range(4):
        ax.plot(log.act_t_s, log.motors[:, j], lw=0.9, label=f"motor {j + 1}")
    ax.set_ylim(-0.03, 1.03)
    ax.set_ylabel("command [0–1]")
    ax.grid(alpha=0.3)
    _mark_events(ax, log, label=True)
    ax.legend(fontsize=8, ncol=5, loc="lower center")
    if limited:
        for j, tag in enumerate(CHANNEL_TAGS):
            on = (log.limited_mask >> j) & 1 > 0
            axl.fill_between(log.smc_t_s, j + 0.1, j + 0.9, where=on, color="tab:red", lw=0, step="post")
        axl.set_yticks([0.5, 1.5, 2.5, 3.5], [c.lower() for c in CHANNEL_TAGS], fontsize=8)
        axl.set_ylim(0, 4)
        axl.set_ylabel("mixer\nlimited", fontsize=8)
        axl.grid(alpha=0.3, axis="x")
        axl.set_xlabel("t [s]")
    else:
        ax.set_xlabel("t [s]")
    return fig


def _figure_controller(  # type: ignore[no-untyped-def]
    plt, log: FlightLog, bounds: tuple[float, float] | None, dead_zone: float | None, bounds_source: str
):
    """(d) sigma (symlog, with chi_hat's dead zone) and chi_hat (with its bounds) per channel."""
    has_sigma = _finite(log.sigma)
    has_chi = _finite(log.chi_hat)
    if not (has_sigma or has_chi):
        return None
    cols = [c for c, present in (("sigma", has_sigma), ("chi", has_chi)) if present]
    fig, axes = plt.subplots(4, len(cols), figsize=(11 if len(cols) == 2 else 8, 8.5), sharex=True, squeeze=False)
    fig.suptitle(f"{log.name}: PID manifold σ and adaptive gain χ̂ per channel (from {log.ctrl_source})")
    symbols = {"phi": "φ", "theta": "θ", "psi": "ψ", "z": "z"}
    for i, c in enumerate(CHANNELS):
        for k, what in enumerate(cols):
            ax = axes[i, k]
            _shade_armed(ax, log)
            if what == "sigma":
                ax.plot(log.ctrl_t_s, log.sigma[:, i], color="tab:purple", lw=0.9, label="σ")
                if dead_zone:
                    ax.axhspan(
                        -dead_zone, dead_zone, color="0.5", alpha=0.15, lw=0,
                        label=f"dead zone ±{dead_zone:g} ({bounds_source}): χ̂ holds",
                    )  # fmt: skip
                ax.set_yscale("symlog", linthresh=1e-3)
                ax.set_ylabel(f"σ_{symbols[c]}")
            else:
                ax.plot(log.ctrl_t_s, log.chi_hat[:, i], color="tab:green", lw=1.2, label="χ̂")
                if bounds is not None:
                    _draw_bounds(ax, log.chi_hat[:, i], bounds, bounds_source)
                ax.set_ylabel(f"χ̂_{symbols[c]}")
            ax.grid(alpha=0.3)
    for k in range(len(cols)):
        axes[0, k].legend(fontsize=8, loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    return fig


def _figure_track(plt, log: FlightLog):  # type: ignore[no-untyped-def]
    """(e) the north/east track seen from above, with headings and the set-points."""
    has_pos = log.pos_t_s.size > 0
    has_target = log.has_smc and _finite(log.target_north_m)
    if not (has_pos or has_target):
        return None
    fig, ax = plt.subplots(1, 1, figsize=(7.5, 7.5))
    fig.suptitle(f"{log.name}: track seen from above")
    if has_pos:
        ax.plot(log.east_m, log.north_m, color="tab:blue", lw=1.3, label="vehicle")
        ax.plot(log.east_m[0], log.north_m[0], "o", color="tab:green", ms=7, label="start")
        ax.plot(log.east_m[-1], log.north_m[-1], "s", color="tab:blue", ms=6, label="end")
        if log.att_t_s.size > 1:
            # Heading arrows every 2 s, only where the vehicle moved or turned since the last one.
            step_s = 2.0
            marks = np.arange(log.pos_t_s[0], log.pos_t_s[-1] + 1e-9, step_s)
            e = _hold(log.pos_t_s, log.east_m, marks)
            n = _hold(log.pos_t_s, log.north_m, marks)
            psi = np.radians(_hold(log.att_t_s, log.yaw_deg, marks))
            span = max(float(np.ptp(log.east_m)), float(np.ptp(log.north_m)), 1.0)
            keep = _distinct_poses(e, n, psi, span / 25.0, math.radians(15.0))
            if keep.size:
                ax.quiver(
                    e[keep], n[keep], np.sin(psi[keep]), np.cos(psi[keep]), angles="xy", scale_units="xy",
                    scale=8.0 / span, width=0.004, color="tab:blue", alpha=0.6, label=f"heading (every {step_s:g} s)",
                )  # fmt: skip
    if has_target:
        target = _target_ne_alt(log)
        stacked: dict[tuple[float, float], int] = {}
        for k in np.flatnonzero(_setpoint_changes(log)):
            n_t, e_t, alt_t = target[k]
            if not (math.isfinite(n_t) and math.isfinite(e_t)):
                continue
            ax.plot(e_t, n_t, "x", color="tab:red", ms=10, mew=2, label="set-point" if not stacked else None)
            key = (round(e_t, 2), round(n_t, 2))
            ax.annotate(
                f"t={log.smc_t_s[k]:.1f} s, alt {alt_t:.1f} m, yaw {log.target_yaw_deg[k]:.0f}°",
                (e_t, n_t), xytext=(8, 8 + 13 * stacked.get(key, 0)), textcoords="offset points", fontsize=8,
                color="tab:red",
            )  # fmt: skip
            stacked[key] = stacked.get(key, 0) + 1
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.margins(0.12)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    return fig


# -- command line ------------------------------------------------------------------------------------
def add_plot_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``smcpilot plot LOG [--out DIR]``."""
    p.add_argument("log", type=Path, metavar="LOG", help="a .tlog written by the flight controller")
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="directory for the PNGs (created if needed; default: <log stem>-plots/ next to the log)",
    )


def plot_main(args: argparse.Namespace) -> int:
    """``smcpilot plot``: write the figures, print their paths. Exit 1 if the log has nothing to plot."""
    log_path: Path = args.log
    out_dir: Path = args.out if args.out is not None else log_path.with_name(f"{log_path.stem}-plots")
    log = load_log(log_path)
    for note in log.warnings:
        print(f"note: {note}", file=sys.stderr)
    paths = plot_log(log, out_dir)
    if not paths:
        print(f"nothing to plot: {log_path} has no state, actuator or controller messages", file=sys.stderr)
        return 1
    for path in paths:
        print(path)
    return 0


def add_log_arguments(p: argparse.ArgumentParser) -> None:
    """Subcommands of ``smcpilot log``: ``summary LOG [--json PATH]`` (room for more)."""
    sub = p.add_subparsers(dest="log_command", metavar="SUBCOMMAND")
    sub.required = True
    s = sub.add_parser(
        "summary",
        help="headline numbers of a flight: duration, overruns, tracking error, chi_hat, events",
        description="Read a flight-controller .tlog and print its summary (see ground.logtools.summarize"
        " for the definitions).",
    )
    s.add_argument("log", type=Path, metavar="LOG", help="a .tlog written by the flight controller")
    s.add_argument(
        "--json", type=Path, default=None, metavar="PATH", help="also write the summary as JSON to PATH ('-': stdout, instead of text)"
    )
    s.add_argument(
        "--settle-s",
        type=float,
        default=DEFAULT_SETTLE_S,
        metavar="S",
        help=f"seconds a set-point change is given before tracking error counts (default {DEFAULT_SETTLE_S:g})",
    )
    s.set_defaults(log_handler=_summary_main)


def log_main(args: argparse.Namespace) -> int:
    """``smcpilot log SUBCOMMAND``: dispatch to the chosen subcommand."""
    handler: Callable[[argparse.Namespace], int] = args.log_handler
    return handler(args)


def _summary_main(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.settle_s) and args.settle_s >= 0.0):
        raise LogError(f"--settle-s must be a finite number >= 0, got {args.settle_s}")
    summary = summarize(load_log(args.log), settle_s=args.settle_s)
    text = json.dumps(summary, indent=2, allow_nan=False)
    if args.json is not None and str(args.json) == "-":
        print(text)
        return 0
    print_summary(summary)
    if args.json is not None:
        try:
            args.json.write_text(text + "\n")
        except OSError as exc:
            raise LogError(f"cannot write {args.json}: {exc.strerror}") from exc
    return 0

