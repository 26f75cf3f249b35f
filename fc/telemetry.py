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

To the log only (lockstep): a ``DEBUG_FLOAT_ARRAY`` named ``SMC`` every control tick, carrying
the law's internals at full rate; :data:`smcpilot.protocol.SMC_FIELDS` names its entries.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc.flight import PipelineOutput, VehicleState
from smcpilot.frames import euler_flu_to_frd, nwu_to_ned, rates_flu_to_frd
from smcpilot.protocol import CHI_NAMES, SIG_NAMES, SMC_FIELDS

if TYPE_CHECKING:  # pragma: no cover
    from fc.core import FlightCore, TickOutput

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


def sys_status(mav: mavlink.MAVLink, load_permille: int, healthy: bool, prearm_ok: bool) -> mavlink.MAVLink_message:
    """SYS_STATUS: every sensor present and enabled; all healthy unless ``healthy`` is False
    (failsafe, no state); PREARM_CHECK healthy when arming would pass (or the vehicle is armed)."""
    health = _SENSORS if healthy else _SENSORS & ~_CONTROL_BITS
    if not prearm_ok:
        health &= ~mavlink.MAV_SYS_STATUS_PREARM_CHECK
    return mav.sys_status_encode(_SENSORS, _SENSORS, health, max(0, min(1000, load_permille)), 12600, -1, -1, 0, 0, 0, 0, 0, 0)


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


def statustext(mav: mavlink.MAVLink, severity: int, text: str) -> mavlink.MAVLink_message:
    return mav.statustext_encode(severity, text[:50].encode("ascii", "replace"))


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


def smc_record(core: "FlightCore", out: "TickOutput") -> list[float]:
    """The per-tick ``SMC`` record of a flight-core tick (every runner logs the same one)."""
    f = core.flight
    return smc_data(out.pipeline, f.target, f.yaw_target_rad, out.flags, out.mode)
