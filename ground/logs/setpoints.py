"""The set-points of another autopilot's flight, to score a served flight against (``smcpilot log
summary SERVED.tlog --setpoints AUTOPILOT.tlog``).

A served flight's log (``smcpilot sim --serve``, :mod:`sim_bridge.serve_log`) holds what our
simulator knows: the state, sensed and true, the motor commands, the faults. What the autopilot
was asked to fly is in *its* log, which its ground station writes (MAVProxy, QGroundControl and
PX4's and ArduPilot's tools write ``.tlog`` files):

- ``POSITION_TARGET_LOCAL_NED`` (ArduCopter sends it in GUIDED, PX4 in its position modes): the
  position set-point, NED metres in the autopilot's local frame (``coordinate_frame``
  MAV_FRAME_LOCAL_NED; other frames are skipped, counted), and the heading set-point ``yaw``;
  ``type_mask`` bits 0-2 mark the position ignored, bit 10 the yaw;
- ``ATTITUDE_TARGET``: the attitude set-point, a quaternion (FRD body in NED), unless
  ``type_mask`` bit 7 marks it ignored: the reference of the attitude error;
- or our own flight controller's log (its per-tick ``SMC`` record: position and heading
  set-point, the law's attitude references and its landing flag), for our FC flown as the
  autopilot of a served simulator (``python -m fc --sim px4``).

The times are the autopilot's ``time_boot_ms`` (our FC: its ticks' ``time_usec``), taken as
served time: both autopilots run their clock on the physics in lockstep (PX4 on
``HIL_SENSOR.time_usec``; ArduPilot on the JSON ``timestamp``, from its first frame: within one
physics frame), and so does our FC. A set-point holds until the next one, for at most
:data:`SETPOINT_MAX_AGE_S`: a stream that stops (a mode without position control) leaves no
set-point after it, rather than a stale one. The local frame's origin is where the vehicle
started (both autopilots set it at their first GPS fix, the vehicle at rest), as the served log's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ground.logs.load import LogError, load_log
from smcpilot.errors import TlogError, TlogFormatError
from smcpilot.protocol import FLAG_FAILSAFE, FLAG_LANDING
from smcpilot.tlog import read_tlog

__all__ = ["SETPOINT_MAX_AGE_S", "SetPoints", "load_setpoints"]

#: a set-point older than this (s) is no set-point: the autopilot stopped sending it.
SETPOINT_MAX_AGE_S = 1.0
#: POSITION_TARGET_LOCAL_NED.type_mask: position x, y, z ignored; yaw ignored.
_POSITION_IGNORED = 0x7
_YAW_IGNORED = 0x400
#: ATTITUDE_TARGET.type_mask: the attitude quaternion ignored.
_ATTITUDE_IGNORED = 0x80
_LOCAL_NED = 1


@dataclass(frozen=True)
class SetPoints:
    """Set-points on the autopilot's clock (s): each array (n,) or (n, 3), NaN where not given."""

    #: what they are and where they came from, for the reader of a score.
    source: str
    #: position and heading set-points: times, north/east/altitude-up (m), heading (rad, NED).
    pos_t_s: np.ndarray
    target_m: np.ndarray
    target_yaw_rad: np.ndarray
    #: attitude set-points: times, roll/pitch/yaw (rad, FRD body in NED).
    att_t_s: np.ndarray
    ref_rad: np.ndarray
    #: landing on purpose (our FC's log only; None: not known), at ``pos_t_s``.
    landing: np.ndarray | None = None

    def span_s(self) -> tuple[float, float]:
        """The first and the last set-point time (s)."""
        ts = np.concatenate([self.pos_t_s, self.att_t_s])
        return float(ts.min()), float(ts.max())

    def at(self, t_s: np.ndarray, max_age_s: float = SETPOINT_MAX_AGE_S) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(target (n, 3), heading (n,), attitude reference (n, 3), landing (n,)) at the times
        ``t_s`` (served time, s): the latest set-point at or before each, NaN (landing: False) if
        there is none younger than ``max_age_s``."""
        target = _hold(self.pos_t_s, self.target_m, t_s, max_age_s)
        yaw = _hold(self.pos_t_s, self.target_yaw_rad[:, None], t_s, max_age_s)[:, 0]
        ref = _hold(self.att_t_s, self.ref_rad, t_s, max_age_s)
        if self.landing is None:
            landing = np.zeros(t_s.size, dtype=bool)
        else:
            landing = _hold(self.pos_t_s, self.landing.astype(float)[:, None], t_s, max_age_s)[:, 0] > 0.5
        return target, yaw, ref, landing


def _hold(t_src: np.ndarray, values: np.ndarray, t_query: np.ndarray, max_age_s: float) -> np.ndarray:
    """Zero-order hold with a limit: the latest row at or before each query time (1 µs slack), NaN
    where there is none or it is older than ``max_age_s``."""
    idx = np.searchsorted(t_src, t_query + 1e-6, side="right") - 1
    out = np.full((t_query.size, values.shape[1]), math.nan)
    ok = idx >= 0
    if t_src.size:
        ok &= t_query - t_src[np.maximum(idx, 0)] <= max_age_s
        out[ok] = values[idx[ok]]
    return out


def _euler_of_quat(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """Roll, pitch, yaw (rad, ZYX) of a quaternion (FRD body in NED)."""
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def load_setpoints(path: Path) -> SetPoints:
    """The set-points in the ``.tlog`` (or ``.tlog.gz``) at ``path`` (see the module docstring);
    raises :class:`LogError` when it is missing, not a ``.tlog``, or holds none."""
    p = Path(path)
    if not p.exists():
        raise LogError(f"--setpoints: no such file: {p}")
    if p.is_dir():
        raise LogError(f"--setpoints: {p} is a directory, not a .tlog file")
    pos: dict[tuple[int, int], list[tuple[float, ...]]] = {}
    att: dict[tuple[int, int], list[tuple[float, ...]]] = {}
    other_frames = 0
    has_smc = False
    records = 0
    try:
        for _, msg in read_tlog(p):
            records += 1
            kind = msg.get_type()
            if kind == "POSITION_TARGET_LOCAL_NED":
                if msg.coordinate_frame != _LOCAL_NED:
                    other_frames += 1
                    continue
                m = msg.type_mask
                x, y, z = (math.nan, math.nan, math.nan) if m & _POSITION_IGNORED else (msg.x, msg.y, msg.z)
                yaw = math.nan if m & _YAW_IGNORED else msg.yaw
                pos.setdefault((msg.get_srcSystem(), msg.get_srcComponent()), []).append((msg.time_boot_ms * 1e-3, x, y, -z, yaw))
            elif kind == "ATTITUDE_TARGET":
                euler = (math.nan,) * 3 if msg.type_mask & _ATTITUDE_IGNORED else _euler_of_quat(*msg.q)
                att.setdefault((msg.get_srcSystem(), msg.get_srcComponent()), []).append((msg.time_boot_ms * 1e-3, *euler))
            elif kind == "DEBUG_FLOAT_ARRAY" and msg.name == "SMC":
                has_smc = True
    except TlogFormatError as exc:
        if records == 0:
            raise LogError(f"--setpoints: {p} is not a MAVLink telemetry log (.tlog)") from exc
    except TlogError as exc:
        raise LogError(f"--setpoints: {exc}") from exc
    if has_smc:
        return _fc_setpoints(p)
    if not pos and not att:
        what = "is empty" if records == 0 else f"has no POSITION_TARGET_LOCAL_NED (in MAV_FRAME_LOCAL_NED), ATTITUDE_TARGET or SMC record in its {records} records"
        raise LogError(f"--setpoints: {p} {what}: no set-points to score against")
    # the autopilot: the source that sent the most set-points
    key = max(set(pos) | set(att), key=lambda k: len(pos.get(k, ())) + len(att.get(k, ())))
    prow = sorted(pos.get(key, []), key=lambda r: r[0])
    arow = sorted(att.get(key, []), key=lambda r: r[0])
    pa = np.asarray(prow, dtype=float).reshape(-1, 5)
    aa = np.asarray(arow, dtype=float).reshape(-1, 4)
    parts = []
    if prow:
        parts.append(f"{len(prow)} POSITION_TARGET_LOCAL_NED")
    if arow:
        parts.append(f"{len(arow)} ATTITUDE_TARGET")
    note = f"; {other_frames} in other frames skipped" if other_frames else ""
    source = f"the autopilot's set-points in {p.name} ({' and '.join(parts)} of system {key[0]}, component {key[1]}{note})"
    return SetPoints(source, pa[:, 0], pa[:, 1:4], pa[:, 4], aa[:, 0], aa[:, 1:4])


def _fc_setpoints(p: Path) -> SetPoints:
    """Our flight controller's set-points: its per-tick SMC record (position, heading, the law's
    attitude references, landing), at the ticks' times."""
    log = load_log(p)
    assert log.t0_us is not None
    t = log.smc_t_s + log.t0_us * 1e-6
    target = np.column_stack([log.target_north_m, log.target_east_m, log.target_alt_m])
    ref = np.radians(np.column_stack([log.ref_roll_deg, log.ref_pitch_deg, log.ref_yaw_deg]))
    flags = log.smc.get("flags")
    landing = None
    if flags is not None and np.all(np.isfinite(flags)) and np.any(flags != 0):
        landing = (flags.astype(np.int64) & (FLAG_LANDING | FLAG_FAILSAFE)) != 0
    source = f"our flight controller's set-points in {p.name} ({t.size} SMC records: position, heading, the law's attitude references, landing)"
    return SetPoints(source, t, target, np.radians(log.target_yaw_deg), t, ref, landing)
