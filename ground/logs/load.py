"""Loading the flight controller's ``.tlog`` files: :func:`load_log` turns a log into a
:class:`FlightLog` of numpy arrays in user-facing units and the MAVLink NED convention.

What the flight controller logs (see :mod:`fc.app` and :mod:`fc.telemetry`):

- from the simulator (source component 200), every control tick: ``ATTITUDE`` (roll, pitch, yaw
  and body rates, FRD body in NED) and ``LOCAL_POSITION_NED``, ``time_boot_ms`` = simulated time;
- to the simulator, every tick: ``HIL_ACTUATOR_CONTROLS`` (controls[0..3] = motor commands in
  [0, 1]; mode bit 128 = armed; flags bit 0 = lockstep);
- from the simulator with each state: ``HIGHRES_IMU`` (the sensed IMU, counted) and ``ODOMETRY``
  (``estimator_type`` MOCAP: the plant's true state, never flown on): position and velocity NED,
  attitude quaternion FRD in NED, ``time_usec`` = simulated time; read into the ``truth_*`` arrays;
- log-only, every tick: ``DEBUG_FLOAT_ARRAY`` "SMC" (array_id 1) whose entries
  :data:`smcpilot.protocol.SMC_FIELDS` names, in the paper's frames (NWU world, FLU body);
- a served flight's log (``smcpilot sim --serve``: another autopilot flew our plant) holds the
  same state, IMU, truth and actuator messages, no SMC record, and starts with the STATUSTEXT
  ``smcpilot sim --serve PROTOCOL`` (:attr:`FlightLog.served_to`);
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

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ground.vehicle.telemetry import StatusTextAssembler
from smcpilot.errors import SmcpilotError, TlogError, TlogFormatError
from smcpilot.frames import euler_flu_to_frd, nwu_to_ned
from smcpilot.protocol import CHI_NAMES, FC_COMPONENT_ID, SIG_NAMES, SIM_COMPONENT_ID, SMC_ARRAY_ID, SMC_FIELDS, TRUTH_ESTIMATOR_TYPE

_COMM_FIELDS = ("errors_comm", "drop_rate_comm", "errors_count1", "errors_count2", "errors_count3", "errors_count4")
from smcpilot.tlog import read_tlog

__all__ = ["CHANNELS", "SIM_COMPONENT", "FlightLog", "LogError", "LogEvent", "TimeSeries", "load_log"]

#: Channel order of the controller arrays (chi_hat, sigma, s, u): the paper's (phi, theta, psi, z).
CHANNELS: tuple[str, ...] = ("phi", "theta", "psi", "z")

SIM_COMPONENT = SIM_COMPONENT_ID
#: the first STATUSTEXT of a served flight's log, before the protocol's name (:mod:`sim_bridge.serve_log`
#: writes it; a test checks the two agree).
SERVED_PREFIX = "smcpilot sim --serve "
_ARMED_BIT = 128  # MAV_MODE_FLAG_SAFETY_ARMED in HIL_ACTUATOR_CONTROLS.mode
_LOCKSTEP_FLAG = 1  # HIL_ACTUATOR_CONTROLS.flags bit 0
_TRUTH_ESTIMATOR = TRUTH_ESTIMATOR_TYPE  # ODOMETRY.estimator_type of the simulator's truth
_SMC_USED = len(SMC_FIELDS)  # 29 of the 58 floats carry data
_SMC_INDEX = {name: i for i, name in enumerate(SMC_FIELDS)}

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
    #: a served flight's log (``smcpilot sim --serve``): the protocol served (``px4``,
    #: ``ardupilot-json``), from its first STATUSTEXT; None for our flight controller's logs.
    served_to: str | None = None

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

    # ODOMETRY from the simulator: the plant's true state (north, east, altitude up; NED
    # velocities; roll, pitch, yaw of FRD in NED from the quaternion, degrees).
    truth_t_s: np.ndarray = field(default_factory=_empty)
    truth_north_m: np.ndarray = field(default_factory=_empty)
    truth_east_m: np.ndarray = field(default_factory=_empty)
    truth_alt_m: np.ndarray = field(default_factory=_empty)
    truth_v_north_mps: np.ndarray = field(default_factory=_empty)
    truth_v_east_mps: np.ndarray = field(default_factory=_empty)
    truth_v_down_mps: np.ndarray = field(default_factory=_empty)
    truth_roll_deg: np.ndarray = field(default_factory=_empty)
    truth_pitch_deg: np.ndarray = field(default_factory=_empty)
    truth_yaw_deg: np.ndarray = field(default_factory=_empty)

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
    #: the FC's last SYS_STATUS communication counters (errors_comm, drop_rate_comm,
    #: errors_count1..4: rejected packets, docs/security.md); None if it sent none.
    comm_errors: dict[str, int] | None = None

    @property
    def name(self) -> str:
        """The log's file name."""
        return self.path.name

    @property
    def has_smc(self) -> bool:
        """True when the log holds the per-tick ``DEBUG_FLOAT_ARRAY`` "SMC" records."""
        return self.smc_t_s.size > 0

    @property
    def has_truth(self) -> bool:
        """True when the log holds the simulator's true state (``ODOMETRY``)."""
        return self.truth_t_s.size > 0

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


def _euler_frd_ned_of_quat(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Roll, pitch, yaw (rad, ZYX) of quaternions (n, 4: w, x, y, z), FRD body in NED."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


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
    truth: list[tuple] = []
    act: list[tuple] = []
    lockstep_flags: list[bool] = []
    smc_t: list[int] = []
    smc_rows: list[list[float]] = []
    named_f: dict[str, list[tuple[int, float]]] = {}
    named_i: dict[str, list[tuple[int, int]]] = {}
    events: list[tuple[int, int, str]] = []
    log_s = [0.0]  # STATUSTEXT chunks (texts over 50 characters) are joined on the log's own clock
    texts = StatusTextAssembler(clock_s=lambda: log_s[0])
    first_us: int | None = None
    last_us = 0
    sim_state_us = 0

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
                if key[1] == SIM_COMPONENT_ID:
                    sim_state_us = msg.time_boot_ms * 1000
            elif mtype == "ODOMETRY":
                if msg.get_srcComponent() == SIM_COMPONENT_ID and msg.estimator_type == _TRUTH_ESTIMATOR:
                    q = msg.q
                    truth.append((time_us, msg.time_usec * 1e-3, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, q[0], q[1], q[2], q[3]))
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
            elif mtype == "SYS_STATUS":
                if msg.get_srcComponent() == FC_COMPONENT_ID:
                    log.comm_errors = {name: int(getattr(msg, name)) for name in _COMM_FIELDS}
            elif mtype == "STATUSTEXT":
                # The simulator announces a fault right after the first state it acts on; a lockstep
                # FC logs the whole datagram batch before its clock reaches that state's time.
                t_ev = max(time_us, sim_state_us) if msg.get_srcComponent() == SIM_COMPONENT_ID else time_us
                log_s[0] = time_us * 1e-6
                for whole in texts.feed(msg):
                    events.append((t_ev, whole.severity, whole.text))
                    if whole.text.startswith(SERVED_PREFIX) and msg.get_srcComponent() == SIM_COMPONENT_ID and log.served_to is None:
                        log.served_to = whole.text[len(SERVED_PREFIX) :].strip() or "?"
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
    if truth:
        r = np.asarray(truth, dtype=float)
        log.truth_t_s = _state_times(r, t0, use_boot)
        log.truth_north_m, log.truth_east_m, log.truth_alt_m = r[:, 2], r[:, 3], -r[:, 4]
        log.truth_v_north_mps, log.truth_v_east_mps, log.truth_v_down_mps = r[:, 5], r[:, 6], r[:, 7]
        roll, pitch, yaw = (np.degrees(a) for a in _euler_frd_ned_of_quat(r[:, 8:12]))
        log.truth_roll_deg, log.truth_pitch_deg, log.truth_yaw_deg = roll, pitch, _wrap_deg(yaw)
    if att_key is not None or pos_key is not None:
        log.state_source = _describe_source(att_key if att_key is not None else pos_key)  # type: ignore[arg-type]
        if att_key is not None and att_key[1] != SIM_COMPONENT:
            log.warnings.append(f"no simulator state in the log: using ATTITUDE from {_describe_source(att_key)}")

    # Controller internals.
    if smc_rows:
        m = np.asarray(smc_rows, dtype=float)
        log.smc_t_s = (np.asarray(smc_t, dtype=float) - t0) * 1e-6
        log.smc = {name: m[:, i] for i, name in enumerate(SMC_FIELDS)}
        col: dict[str, Any] = log.smc  # numpy columns through the scalar frame functions (they broadcast)
        log.s = m[:, _SMC_INDEX["s_phi"] : _SMC_INDEX["s_phi"] + 4]
        log.u = m[:, _SMC_INDEX["u_phi"] : _SMC_INDEX["u_phi"] + 4]
        roll_r, pitch_r, yaw_r = euler_flu_to_frd(col["ref_phi"], col["ref_theta"], col["ref_psi"])
        log.ref_roll_deg = np.degrees(roll_r)
        log.ref_pitch_deg = np.degrees(pitch_r)
        log.ref_yaw_deg = _wrap_deg(np.degrees(yaw_r))
        log.ref_alt_m = col["ref_z"].copy()  # paper z is already up
        north, east, down = nwu_to_ned((col["target_x"], col["target_y"], col["target_z"]))
        log.target_north_m, log.target_east_m, log.target_alt_m = north, east, -down  # type: ignore[assignment]
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
