"""Telemetry the flight controller publishes: what ground stations and our tools read.

To ground stations (every control tick decides, by simulated or wall time, what is due):

- ``HEARTBEAT`` at 1 Hz: MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_ARDUPILOTMEGA, base_mode with
  CUSTOM_MODE_ENABLED (+ SAFETY_ARMED when armed), custom_mode = ArduCopter mode number;
- ``SYS_STATUS`` at 1 Hz;
- ``ATTITUDE`` and ``LOCAL_POSITION_NED`` (NED/FRD), and the adaptive gains and manifolds as
  ``NAMED_VALUE_FLOAT`` ``CHI_PHI``, ``CHI_THETA``, ``CHI_PSI``, ``CHI_Z``, ``SIG_PHI``,
  ``SIG_THETA``, ``SIG_PSI``, ``SIG_Z`` at ``telemetry_rate_hz`` (10 Hz by default);
- ``NAMED_VALUE_INT`` ``OVERRUN`` (missed deadlines so far) at 1 Hz;
- ``STATUSTEXT`` for events (failsafe, arming, landing).

Ground-station messages are built by :func:`build` from a :class:`TelemetrySnapshot`: a frozen
copy of everything telemetry reads, taken once when something is due (:func:`snapshot`), so the
builders are pure functions of (message id, snapshot, encoder) and never reach into the FC.

To the log only (lockstep): a ``DEBUG_FLOAT_ARRAY`` named ``SMC`` every control tick, carrying
the law's internals at full rate; :data:`smcpilot.protocol.SMC_FIELDS` names its entries.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, NamedTuple

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc.estimate import EST_ATTITUDE_LOST, EST_DEAD_RECKONING, EST_OK, MISSING_POSITION, MISSING_VELOCITY
from fc.flight import PipelineOutput, VehicleState
from smcpilot import __version__
from smcpilot.frames import (
    euler_flu_to_frd,
    euler_frd_to_flu,
    nwu_to_ned,
    rates_flu_to_frd,
)
from smcpilot.geo import Home, ned_to_global
from smcpilot.protocol import CHI_NAMES, OVERRUN_NAME, SIG_NAMES

if TYPE_CHECKING:  # pragma: no cover
    from fc.core import FlightCore, TickOutput

M = mavlink

CAPABILITIES = (
    M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
)
_VERSION = tuple(int(p) for p in __version__.split(".")[:3])
FLIGHT_SW_VERSION = (_VERSION[0] << 24) | (_VERSION[1] << 16) | (_VERSION[2] << 8) | 0xFF  # FIRMWARE_VERSION_TYPE_OFFICIAL

# POSITION_TARGET_TYPEMASK bits
IGNORE_POS = 0x7
IGNORE_YAW = 0x400

# Health bits MAVSDK and MAVProxy look at (gcs-interop-notes.md).
_SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | mavlink.MAV_SYS_STATUS_GEOFENCE
    | mavlink.MAV_SYS_STATUS_AHRS
    | mavlink.MAV_SYS_STATUS_PREARM_CHECK
)

#: the bits a failsafe or a missing state marks unhealthy
_CONTROL_BITS = (
    mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | mavlink.MAV_SYS_STATUS_AHRS
)

_NAN = float("nan")


def _f(v: float | None) -> float:
    return _NAN if v is None else float(v)


def heartbeat(mav: mavlink.MAVLink, armed: bool, custom_mode: int, system_status: int) -> mavlink.MAVLink_message:
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
    if armed:
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    return mav.heartbeat_encode(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base, custom_mode, system_status
    )


#: SYS_STATUS's communication counters: (errors_comm, drop_rate_comm c%, errors_count1..4);
#: see :meth:`fc.gcs.GcsHandler.comm_errors` for what each counts.
NO_COMM_ERRORS = (0, 0, 0, 0, 0, 0)


def sys_status(
    mav: mavlink.MAVLink, load_permille: int, healthy: bool, prearm_ok: bool, comm: Sequence[int] = NO_COMM_ERRORS
) -> mavlink.MAVLink_message:
    """SYS_STATUS: every sensor present and enabled; all healthy unless ``healthy`` is False
    (failsafe, no state); PREARM_CHECK healthy when arming would pass (or the vehicle is armed);
    ``comm`` the link counters (:data:`NO_COMM_ERRORS`), each clamped to uint16."""
    health = _SENSORS if healthy else _SENSORS & ~_CONTROL_BITS
    if not prearm_ok:
        health &= ~mavlink.MAV_SYS_STATUS_PREARM_CHECK
    e = [max(0, min(0xFFFF, int(v))) for v in comm]
    return mav.sys_status_encode(
        _SENSORS, _SENSORS, health, max(0, min(1000, load_permille)), 12600, -1, -1, min(e[1], 10000), e[0], e[2], e[3], e[4], e[5]
    )


def attitude(mav: mavlink.MAVLink, time_boot_ms: int, st: VehicleState, body_rates_flu: Sequence[float]) -> mavlink.MAVLink_message:
    roll, pitch, yaw = euler_flu_to_frd(st.phi_rad, st.theta_rad, st.psi_rad)
    p, q, r = rates_flu_to_frd(*body_rates_flu)
    return mav.attitude_encode(time_boot_ms & 0xFFFFFFFF, roll, pitch, yaw, p, q, r)


def local_position(mav: mavlink.MAVLink, time_boot_ms: int, st: VehicleState) -> mavlink.MAVLink_message:
    x, y, z = nwu_to_ned((st.x_m, st.y_m, st.z_m))
    vx, vy, vz = nwu_to_ned((st.vx_mps, st.vy_mps, st.vz_mps))
    return mav.local_position_ned_encode(time_boot_ms & 0xFFFFFFFF, x, y, z, vx, vy, vz)


def named_values(mav: mavlink.MAVLink, time_boot_ms: int, out: PipelineOutput | None) -> list[mavlink.MAVLink_message]:
    d = out.diag if out is not None else None
    chi = d.chi_hat if d is not None and d.chi_hat is not None else (_NAN,) * 4
    sig = d.sigma if d is not None and d.sigma is not None else (_NAN,) * 4
    t = time_boot_ms & 0xFFFFFFFF
    enc = mav.named_value_float_encode
    return [enc(t, CHI_NAMES[i].encode(), float(chi[i])) for i in range(4)] + [
        enc(t, SIG_NAMES[i].encode(), float(sig[i])) for i in range(4)
    ]


#: characters of text one STATUSTEXT carries.
STATUSTEXT_CHUNK = 50
_text_ids: weakref.WeakKeyDictionary[mavlink.MAVLink, int] = weakref.WeakKeyDictionary()


def statustext(mav: mavlink.MAVLink, severity: int, text: str) -> mavlink.MAVLink_message:
    """One STATUSTEXT of at most 50 characters (longer text is cut: use :func:`statustexts`)."""
    return mav.statustext_encode(severity, text[:STATUSTEXT_CHUNK].encode("ascii", "replace"))


def statustexts(mav: mavlink.MAVLink, severity: int, text: str) -> list[mavlink.MAVLink_message]:
    """``text`` as STATUSTEXT, in MAVLink 2 chunks when longer than 50 characters: every chunk
    has the same non-zero ``id`` (one counter per encoder, so a log stays reproducible) and
    ``chunk_seq`` 0, 1, ...; the last chunk is shorter than 50 characters (an empty one follows a
    text of a multiple of 50), which tells the receiver the text is complete. A text of up to 50
    characters is one message with ``id`` 0, as before."""
    data = text.encode("ascii", "replace")
    if len(data) <= STATUSTEXT_CHUNK:
        return [mav.statustext_encode(severity, data)]
    text_id = _text_ids.get(mav, 0) % 65535 + 1
    _text_ids[mav] = text_id
    chunks = [data[i : i + STATUSTEXT_CHUNK] for i in range(0, len(data), STATUSTEXT_CHUNK)]
    if len(chunks[-1]) == STATUSTEXT_CHUNK:
        chunks.append(b"")
    return [mav.statustext_encode(severity, c, text_id, k) for k, c in enumerate(chunks[:256])]


def smc_data(out: PipelineOutput, target: Sequence[float], yaw_target: float, flags: int = 0, mode: int = 0) -> list[float]:
    """The 58 floats of the per-tick ``DEBUG_FLOAT_ARRAY`` "SMC" (see :data:`SMC_FIELDS`)."""
    d = out.diag
    # Unused slots stay 0.0 so MAVLink 2 trims them off the wire; unknown values are NaN.
    data = [_NAN] * 29 + [0.0] * 29  # (flags and mode, entries 29 and 30, are always set)
    if d is not None:
        chi, sig, s = d.chi_hat, d.sigma, d.s
        if chi is not None:
            data[0:4] = chi
        if sig is not None:
            data[4:8] = sig
        if s is not None:
            data[8:12] = s
    data[12:16] = out.u
    data[16:20] = out.ref
    data[20:24] = out.motors
    data[24], data[25], data[26] = target
    data[27] = yaw_target
    lim = out.limited
    data[28] = float(lim[0] + 2 * lim[1] + 4 * lim[2] + 8 * lim[3])
    data[29] = float(flags)
    data[30] = float(mode)
    return data


def smc_record(core: FlightCore, out: TickOutput) -> list[float]:
    """The per-tick ``SMC`` record of a flight-core tick (every runner logs the same one)."""
    f = core.flight
    return smc_data(out.pipeline, f.target, f.yaw_target_rad, out.flags, out.mode)


# -- the snapshot and the ground-station messages ------------------------------------------------
class TelemetrySnapshot(NamedTuple):
    """Everything ground-station telemetry reads, frozen at one moment (paper frame)."""

    #: the FC's clock (simulated time in lockstep), µs.
    time_us: int
    #: the latest vehicle state, None before the first.
    state: VehicleState | None
    #: body rates p, q, r (FLU), rad/s.
    body_rates: tuple[float, float, float]
    armed: bool
    #: ArduCopter custom-mode number.
    mode: int
    #: in the state-loss failsafe.
    failsafe: bool
    #: arming would pass now (or the vehicle is armed): SYS_STATUS PREARM_CHECK.
    prearm_ok: bool
    #: MAV_LANDED_STATE_*.
    landed_state: int
    #: the position set-point (paper frame), m.
    target: tuple[float, float, float]
    #: the heading set-point (FLU, wrapped), rad.
    yaw_target_rad: float
    #: the last tick's pipeline output, None before the first tick.
    pipeline: PipelineOutput | None
    #: missed control deadlines so far.
    overruns: int
    mission_current: int
    #: stored mission items, home included.
    mission_count: int
    home: Home
    system_id: int
    #: the estimate's status (``fc.estimate.EST_*``) and which groups were not measured
    #: (``fc.estimate.MISSING_*`` bits) after the latest tick.
    estimate_status: int = 0
    estimate_missing: int = 0
    #: the latest state is fresh (False: stale in real time, or none).
    state_fresh: bool = True
    #: SYS_STATUS's communication counters (:data:`NO_COMM_ERRORS` layout).
    comm_errors: tuple[int, int, int, int, int, int] = NO_COMM_ERRORS


def snapshot(core: FlightCore, *, time_us: int, state: VehicleState | None, body_rates: tuple[float, float, float],
             overruns: int, comm_errors: tuple[int, int, int, int, int, int] = NO_COMM_ERRORS) -> TelemetrySnapshot:  # fmt: skip
    """The snapshot of a flight core now, with the runner's clock, latest state and counters."""
    c = core.commander
    f = core.flight
    last = core.last
    mission = c.mission
    return TelemetrySnapshot(
        time_us, state, body_rates, f.armed, int(c.mode), core.failsafe, f.armed or c.prearm_failure() is None,
        c.landed_state(), f.target, f.yaw_target_rad, last.pipeline if last is not None else None, overruns,
        mission.current, len(mission.items), core.home, core.config.system_id, core.estimate_status,
        core.estimate_missing, c.state_fresh, comm_errors,
    )  # fmt: skip


Builder = Callable[[TelemetrySnapshot, mavlink.MAVLink, int], list]


def _b_heartbeat(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    status = M.MAV_STATE_CRITICAL if s.failsafe else M.MAV_STATE_ACTIVE if s.armed else M.MAV_STATE_STANDBY
    return [heartbeat(mav, s.armed, s.mode, status)]


def _b_sys_status(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    return [sys_status(mav, 0, not s.failsafe and s.state is not None, s.prearm_ok, s.comm_errors)]


def _b_system_time(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    return [mav.system_time_encode(0, t_ms)]


def _b_extended_sys_state(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    return [mav.extended_sys_state_encode(M.MAV_VTOL_STATE_UNDEFINED, s.landed_state)]


def _b_mission_current(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    n_items = s.mission_count
    return [mav.mission_current_encode(s.mission_current, n_items - 1 if n_items else 0xFFFF)]


def _b_position_target(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    if not s.armed:
        return []
    tn, te, td = nwu_to_ned(s.target)
    yaw_ned = euler_flu_to_frd(0.0, 0.0, s.yaw_target_rad)[2]
    mask = 0xFFF & ~(IGNORE_POS | IGNORE_YAW)  # position and yaw are the set-point
    return [mav.position_target_local_ned_encode(t_ms, M.MAV_FRAME_LOCAL_NED, mask, tn, te, td, 0, 0, 0, 0, 0, 0, yaw_ned, 0)]


def _b_overruns(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    return [mav.named_value_int_encode(t_ms, OVERRUN_NAME.encode(), s.overruns)]


def _b_named_values(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    return named_values(mav, t_ms, s.pipeline)


def _b_autopilot_version(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    return [
        mav.autopilot_version_encode(
            CAPABILITIES, FLIGHT_SW_VERSION, 0, 0, 0, b"\0" * 8, b"\0" * 8, b"\0" * 8, 0x1209, 0x5350,
            0x534D435049000000 | s.system_id,
        )  # fmt: skip
    ]


def _b_home_position(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    h = s.home
    return [
        mav.home_position_encode(
            int(round(h.lat_deg * 1e7)), int(round(h.lon_deg * 1e7)), int(round(h.alt_m * 1000)),
            0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
        )  # fmt: skip
    ]


def _b_attitude(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    return [attitude(mav, t_ms, s.state, s.body_rates)] if s.state is not None else []


def _b_local_position(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    return [local_position(mav, t_ms, s.state)] if s.state is not None else []


def _global(s: TelemetrySnapshot, st: VehicleState):
    """(lat, lon, alt AMSL, down, vn, ve, vd, heading deg) of a state."""
    n, e, d = nwu_to_ned((st.x_m, st.y_m, st.z_m))
    vn, ve, vd = nwu_to_ned((st.vx_mps, st.vy_mps, st.vz_mps))
    lat, lon, alt = ned_to_global(s.home, n, e, d)
    heading_deg = math.degrees(euler_frd_to_flu(0.0, 0.0, st.psi_rad)[2]) % 360.0
    return lat, lon, alt, d, vn, ve, vd, heading_deg


def _b_global_position(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    st = s.state
    if st is None:
        return []
    lat, lon, alt, d, vn, ve, vd, heading_deg = _global(s, st)
    return [
        mav.global_position_int_encode(
            t_ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)), int(round(-d * 1000)),
            _i16(vn * 100), _i16(ve * 100), _i16(vd * 100), int(round(heading_deg * 100)) % 36000,
        )  # fmt: skip
    ]


def _b_gps_raw(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    st = s.state
    if st is None:
        return []
    lat, lon, alt, _d, vn, ve, _vd, _heading_deg = _global(s, st)
    ground_speed = math.hypot(vn, ve)
    cog = int(round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100)) % 36000 if ground_speed > 0.2 else 65535
    return [
        mav.gps_raw_int_encode(
            s.time_us, M.GPS_FIX_TYPE_3D_FIX, int(round(lat * 1e7)), int(round(lon * 1e7)),
            int(round(alt * 1000)), 80, 120, min(65534, int(round(ground_speed * 100))), cog, 12,
        )  # fmt: skip
    ]


# EKF_STATUS_REPORT flags (ArduPilot's EKF_STATUS_FLAGS).
EKF_POSITION_FLAGS = (
    M.EKF_POS_HORIZ_REL | M.EKF_POS_HORIZ_ABS | M.EKF_POS_VERT_ABS | M.EKF_POS_VERT_AGL
    | M.EKF_PRED_POS_HORIZ_REL | M.EKF_PRED_POS_HORIZ_ABS
)  # fmt: skip
EKF_VELOCITY_FLAGS = M.EKF_VELOCITY_HORIZ | M.EKF_VELOCITY_VERT
EKF_HEALTHY_FLAGS = M.EKF_ATTITUDE | EKF_VELOCITY_FLAGS | EKF_POSITION_FLAGS
#: the variances (normalised innovation test ratios, as ArduPilot reports them) when healthy;
#: 1.0 is the limit, reported for what is not estimated.
EKF_HEALTHY_VARIANCE = 0.01


def ekf_flags(s: TelemetrySnapshot) -> int:
    """The ``EKF_STATUS_REPORT`` flags of the FC's estimate (``fc.estimate``): everything while
    the state is fresh and measured; the position (or velocity) flags cleared while they are
    dead-reckoned; attitude only once the position is lost or in the state-loss failsafe;
    nothing without a fresh state or with the attitude lost. Never CONST_POS_MODE."""
    if s.state is None or not s.state_fresh or s.estimate_status == EST_ATTITUDE_LOST:
        return 0
    if s.failsafe or s.estimate_status not in (EST_OK, EST_DEAD_RECKONING):
        return M.EKF_ATTITUDE
    flags = EKF_HEALTHY_FLAGS
    if s.estimate_status == EST_DEAD_RECKONING:
        if s.estimate_missing & MISSING_POSITION:
            flags &= ~EKF_POSITION_FLAGS
        if s.estimate_missing & MISSING_VELOCITY:
            flags &= ~EKF_VELOCITY_FLAGS
    return flags


def _b_ekf_status(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    flags = ekf_flags(s)
    ok, bad = EKF_HEALTHY_VARIANCE, 1.0
    vel = ok if flags & M.EKF_VELOCITY_HORIZ else bad
    pos_h = ok if flags & M.EKF_POS_HORIZ_ABS else bad
    pos_v = ok if flags & M.EKF_POS_VERT_ABS else bad
    att = ok if flags & M.EKF_ATTITUDE else bad
    return [mav.ekf_status_report_encode(flags, vel, pos_h, pos_v, att, 0.0)]


def _b_vfr_hud(s: TelemetrySnapshot, mav: mavlink.MAVLink, t_ms: int) -> list:
    st = s.state
    if st is None:
        return []
    _lat, _lon, _alt, d, vn, ve, vd, heading_deg = _global(s, st)
    ground_speed = math.hypot(vn, ve)
    out = s.pipeline
    throttle = int(round(100 * sum(out.motors) / 4)) if out is not None else 0
    return [mav.vfr_hud_encode(ground_speed, ground_speed, int(round(heading_deg)) % 360, throttle, -d, -vd)]


_BUILDERS: dict[int, Builder] = {
    M.MAVLINK_MSG_ID_HEARTBEAT: _b_heartbeat,
    M.MAVLINK_MSG_ID_SYS_STATUS: _b_sys_status,
    M.MAVLINK_MSG_ID_SYSTEM_TIME: _b_system_time,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: _b_extended_sys_state,
    M.MAVLINK_MSG_ID_MISSION_CURRENT: _b_mission_current,
    M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: _b_position_target,
    M.MAVLINK_MSG_ID_NAMED_VALUE_INT: _b_overruns,
    M.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT: _b_named_values,
    M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: _b_autopilot_version,
    M.MAVLINK_MSG_ID_HOME_POSITION: _b_home_position,
    M.MAVLINK_MSG_ID_ATTITUDE: _b_attitude,
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: _b_local_position,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: _b_global_position,
    M.MAVLINK_MSG_ID_GPS_RAW_INT: _b_gps_raw,
    M.MAVLINK_MSG_ID_VFR_HUD: _b_vfr_hud,
    M.MAVLINK_MSG_ID_EKF_STATUS_REPORT: _b_ekf_status,
}


def build(msg_id: int, snap: TelemetrySnapshot, mav: mavlink.MAVLink) -> list[mavlink.MAVLink_message]:
    """The message(s) of this id for the snapshot; [] when there is nothing to say (unknown id,
    no state yet for the state's messages, no set-point while disarmed)."""
    builder = _BUILDERS.get(msg_id)
    if builder is None:
        return []
    return builder(snap, mav, (snap.time_us // 1000) & 0xFFFFFFFF)


def _i16(v: float) -> int:
    return max(-32768, min(32767, int(round(v))))
