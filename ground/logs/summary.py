"""Summaries of a flight log: :func:`summarize` reduces a :class:`~ground.logs.load.FlightLog`
to a JSON-ready dict of headline numbers (tracking error in metres and degrees, tilt in degrees,
times in seconds), :func:`print_summary` prints them."""

from __future__ import annotations

import math
import sys
from typing import Any, TextIO

import numpy as np

from ground.logs.load import CHANNELS, FlightLog, _wrap_deg
from ground.logs.metrics import (
    RECOVER_RADIUS_M,
    SETPOINT_TOLERANCE,
    SIGMA_WINDOW_S,
    divergence_from_events,
    fault_starts_from_events,
    flight_metrics,
    sigma_metrics,
)
from ground.logs.setpoints import SetPoints
from smcpilot.protocol import FLAG_ARMED, FLAG_FAILSAFE, FLAG_LANDING

__all__ = ["DEFAULT_SETTLE_S", "DEFAULT_SIGMA_WINDOW_S", "format_metrics", "log_metrics", "print_summary", "served_metrics", "summarize"]

#: Seconds a set-point change is given before the tracking error counts (see :func:`summarize`).
DEFAULT_SETTLE_S = 8.0
#: Length of the window over which sigma's RMS is taken: the last seconds of flight before landing.
DEFAULT_SIGMA_WINDOW_S = SIGMA_WINDOW_S
# Target changes smaller than this (m or rad) are float noise, not a new set-point.
_SETPOINT_TOLERANCE = SETPOINT_TOLERANCE
# STATUSTEXT prefixes after which the FC descends on purpose (tracking is not assessed).
_LANDING_EVENT_PREFIXES = ("Landing", "FAILSAFE", "State back", "Mode LAND", "Mode RTL", "Failsafe")


# Samples stamped within this of a query time count as at it: a state's time comes from its
# time_boot_ms (ms) and a tick's from the record stamp (µs), and the two differ by float rounding
# (1.8e-15 s), which must not make a tick see the previous state.
_SAME_TIME_S = 1e-6


def _hold(t_src: np.ndarray, values: np.ndarray, t_query: np.ndarray) -> np.ndarray:
    """Zero-order hold: the latest sample of ``values`` at or before each ``t_query`` (within
    1 µs; NaN before the first)."""
    idx = np.searchsorted(t_src, t_query + _SAME_TIME_S, side="right") - 1
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
    _, _, holding, settled = _flight_masks(log, settle_s)
    return holding, settled


def _flight_masks(log: FlightLog, settle_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(armed, landing, holding, settled) masks over ``smc_t_s``; see :func:`summarize`."""
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
        return armed, landing, holding, settled
    # Older logs: landing (or failsafe descent) from its event until the next set-point change.
    landing = np.zeros(n, dtype=bool)
    for ev in log.events:
        if ev.text.startswith(_LANDING_EVENT_PREFIXES):
            later_changes = t[change_idx][t[change_idx] > ev.t_s]
            end = later_changes[0] if later_changes.size else np.inf
            landing |= (t >= ev.t_s) & (t < end)
    holding = armed & ~landing
    settled = holding & (t - last_change_t >= settle_s)
    return armed, landing, holding, settled


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


def log_metrics(
    log: FlightLog, *, sigma_window_s: float = DEFAULT_SIGMA_WINDOW_S, recover_radius_m: float = RECOVER_RADIUS_M, truth: bool = False,
    setpoints: SetPoints | None = None,
) -> dict[str, Any] | None:
    """The :func:`ground.logs.metrics.flight_metrics` of a flight log, or None when the log lacks
    what they need (the per-tick "SMC" records, which carry the set-point, and the state).

    ``truth``: score the plant's true state (the simulator's ``ODOMETRY``, what the vehicle did,
    as ``smcpilot compare`` scores its flights) instead of the sensed state the FC flew on
    (``ATTITUDE`` + ``LOCAL_POSITION_NED``: sensor noise and faults included); None when the log
    has no truth.

    The samples are the controller ticks (``smc_t_s``): position (north, east, altitude up),
    velocity (north, east, up) and attitude (roll, pitch, yaw of FRD in NED) held from the latest
    state sample, the motor commands from the latest ``HIL_ACTUATOR_CONTROLS``, the law's
    references and the set-point from the record itself; armed and landing as in
    :func:`summarize` (the FC's logged flags, else the events); the fault starts from the
    simulator's ``SIM:`` events, a divergence from an event saying so, the LAND speed from the
    logged ``LAND_SPD`` parameter. Times in the result (``fault_start_s``, ``crash_t_s``) are
    seconds since the log's first record.

    A served flight's log (:attr:`FlightLog.served_to`: another autopilot flew our plant) is
    scored by :func:`served_metrics`, against ``setpoints`` if given.
    """
    if log.served_to is not None and not log.has_smc:
        return served_metrics(log, truth=truth, setpoints=setpoints, sigma_window_s=sigma_window_s, recover_radius_m=recover_radius_m)
    if not (log.has_smc and log.pos_t_s.size and log.att_t_s.size):
        return None
    t = log.smc_t_s
    armed, landing, _, _ = _flight_masks(log, 0.0)
    if truth:
        if not log.has_truth:
            return None
        tt = log.truth_t_s
        pos = _hold(tt, np.column_stack([log.truth_north_m, log.truth_east_m, log.truth_alt_m]), t)
        vel = _hold(tt, np.column_stack([log.truth_v_north_mps, log.truth_v_east_mps, -log.truth_v_down_mps]), t)
        euler = _hold(tt, np.radians(np.column_stack([log.truth_roll_deg, log.truth_pitch_deg, log.truth_yaw_deg])), t)
    else:
        pos = _hold(log.pos_t_s, np.column_stack([log.north_m, log.east_m, log.alt_m]), t)
        vel = _hold(log.pos_t_s, np.column_stack([log.v_north_mps, log.v_east_mps, -log.v_down_mps]), t)
        euler = _hold(log.att_t_s, np.radians(np.column_stack([log.roll_deg, log.pitch_deg, log.yaw_deg])), t)
    ref = np.radians(np.column_stack([log.ref_roll_deg, log.ref_pitch_deg, log.ref_yaw_deg]))
    target = np.column_stack([log.target_north_m, log.target_east_m, log.target_alt_m])
    if log.act_t_s.size:
        motors = _hold(log.act_t_s, log.motors, t)
    else:
        motors = np.column_stack([log.smc[f"motor{i}"] for i in range(1, 5)])
    events = [(e.t_s, e.severity, e.text) for e in log.events]
    land_speed = log.params.get("LAND_SPD")
    return flight_metrics(
        t,
        pos,
        target,
        euler,
        ref,
        motors,
        armed,
        landing,
        fault_starts_s=fault_starts_from_events(events),
        velocity_m_s=vel,
        target_yaw_rad=np.radians(log.target_yaw_deg),
        sigma=log.sigma if log.ctrl_t_s is log.smc_t_s else None,
        sigma_window_s=sigma_window_s,
        land_speed_mps=land_speed if land_speed is not None and math.isfinite(land_speed) and land_speed > 0 else None,
        diverged_t_s=divergence_from_events(events),
        recover_radius_m=recover_radius_m,
    )


#: the keys of a served flight's metrics that need a position set-point, and those that need an attitude one.
_POSITION_KEYS = ("iae_pos_m_s", "ise_pos_m2_s", "itae_pos_m_s2", "max_pos_err_m", "recover_s", "recovered")
_ATTITUDE_KEYS = ("iae_att_rad_s", "ise_att_rad2_s", "itae_att_rad_s2")


def served_metrics(
    log: FlightLog, *, truth: bool = False, setpoints: SetPoints | None = None, sigma_window_s: float = DEFAULT_SIGMA_WINDOW_S,
    recover_radius_m: float = RECOVER_RADIUS_M,
) -> dict[str, Any] | None:
    """The :func:`ground.logs.metrics.flight_metrics` of a served flight's log (``smcpilot sim
    --serve``: another autopilot flew our plant), or None without its states.

    The samples are the served states (every physics step): the true state (``ODOMETRY``,
    ``truth``) or the sensors' output as served (``ATTITUDE`` + ``LOCAL_POSITION_NED``), the motor
    commands flown from the step's ``HIL_ACTUATOR_CONTROLS`` and armed while the rotors spin; the
    faults from the simulator's events. The autopilot's set-points are not in this log: with
    ``setpoints`` (:func:`ground.logs.setpoints.load_setpoints`, the autopilot's log or our FC's)
    the position, heading and attitude errors are scored against them where they hold (landing
    too, from our FC's log; otherwise never), and without them those metrics (IAE/ISE/ITAE,
    the in-flight max error, the recovery) are None: only the set-point-free ones (effort, motor
    total variation, tilt, crash, flight and armed time) are scored. ``"scored_against"`` in the
    result says which.
    """
    tt = log.truth_t_s if truth else log.pos_t_s
    if tt.size == 0 or (truth and not log.has_truth) or log.act_t_s.size == 0:
        return None
    t = tt
    if truth:
        pos = np.column_stack([log.truth_north_m, log.truth_east_m, log.truth_alt_m])
        vel = np.column_stack([log.truth_v_north_mps, log.truth_v_east_mps, -log.truth_v_down_mps])
        euler = np.radians(np.column_stack([log.truth_roll_deg, log.truth_pitch_deg, log.truth_yaw_deg]))
    else:
        pos = np.column_stack([log.north_m, log.east_m, log.alt_m])
        vel = np.column_stack([log.v_north_mps, log.v_east_mps, -log.v_down_mps])
        euler = _hold(log.att_t_s, np.radians(np.column_stack([log.roll_deg, log.pitch_deg, log.yaw_deg])), t)
    motors = _hold(log.act_t_s, log.motors, t)
    armed = _hold(log.act_t_s, log.armed.astype(float), t) > 0.5
    n = t.size
    if setpoints is not None:
        served_s = t + (log.t0_us or 0) * 1e-6  # the set-points' clock is served time
        target, target_yaw, ref, landing = setpoints.at(served_s)
        against = setpoints.source
    else:
        target, target_yaw, ref = np.full((n, 3), math.nan), np.full(n, math.nan), np.full((n, 3), math.nan)
        landing = np.zeros(n, dtype=bool)
        against = "no set-points (give the autopilot's log: --setpoints): the position and attitude errors and the recovery are not scored"
    events = [(e.t_s, e.severity, e.text) for e in log.events]
    m = flight_metrics(
        t, pos, target, euler, ref, motors, armed, landing,
        fault_starts_s=fault_starts_from_events(events), velocity_m_s=vel, target_yaw_rad=target_yaw,
        sigma_window_s=sigma_window_s, diverged_t_s=divergence_from_events(events), recover_radius_m=recover_radius_m,
    )  # fmt: skip
    flying = armed & ~landing
    if not np.any(flying & np.all(np.isfinite(target), axis=1)):
        for key in _POSITION_KEYS:
            m[key] = None
    if not np.any(flying & np.all(np.isfinite(ref), axis=1)):
        for key in _ATTITUDE_KEYS:
            m[key] = None
    m["scored_against"] = against
    return m


def summarize(
    log: FlightLog, *, settle_s: float = DEFAULT_SETTLE_S, sigma_window_s: float = DEFAULT_SIGMA_WINDOW_S,
    setpoints: SetPoints | None = None,
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
    acos(cos roll · cos pitch), over the whole log), ``chi_hat_final`` (last finite value per
    channel phi, theta, psi, z), ``sigma_lpf_rms`` and ``sigma_dither_rms`` (per channel, over the
    last ``sigma_window_s`` seconds of flight while holding, i.e. before a final landing: the RMS
    of sigma low-passed with tau = 0.1 s, how far sigma stays from the sliding surface, and the
    RMS of what the low-pass removes, the chattering; see :mod:`ground.logs.metrics`),
    ``overruns`` (last OVERRUN count), ``comm_errors`` (the FC's last SYS_STATUS rejected-packet
    counters, None without one), ``message_counts``, ``events``, ``metrics``
    (:func:`log_metrics`: IAE/ISE/ITAE, effort, crash, recovery; None without "SMC" records) on
    the sensed state the FC flew on, and ``truth_metrics``, the same on the plant's true state
    when the log has it (``ODOMETRY`` from the simulator; None otherwise), with
    ``metrics_sources`` naming the state each was computed on.
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
        "comm_errors": dict(log.comm_errors) if log.comm_errors is not None else None,
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
        lpf, dither = sigma_metrics(log.ctrl_t_s, log.sigma, window)
        out["chi_hat_final"] = chi_final if any(v is not None for v in chi_final) else None
        out["sigma_lpf_rms"] = lpf
        out["sigma_dither_rms"] = dither
    else:
        out["chi_hat_final"] = None
        out["sigma_lpf_rms"] = None
        out["sigma_dither_rms"] = None
    out["sigma_window_s"] = sigma_window_s
    out["served"] = log.served_to
    out["metrics"] = log_metrics(log, sigma_window_s=sigma_window_s, setpoints=setpoints)
    out["truth_metrics"] = log_metrics(log, sigma_window_s=sigma_window_s, truth=True, setpoints=setpoints)
    sensed = "sensed state: ATTITUDE + LOCAL_POSITION_NED"
    out["metrics_sources"] = {
        "metrics": (f"{sensed}: the sensors' output as served to {log.served_to}" if log.served_to is not None
                    else f"{sensed} from the {log.state_source}") if log.state_source else None,
        "truth_metrics": "true state: ODOMETRY from the simulator" if log.has_truth else None,
    }  # fmt: skip
    if log.served_to is not None:
        m = out["truth_metrics"] or out["metrics"]
        out["metrics_sources"]["setpoints"] = m["scored_against"] if m is not None else None
    out["events"] = [{"t_s": round(e.t_s, 6), "severity": e.severity, "text": e.text} for e in log.events]
    return out


def _fmt(v: Any, spec: str = ".3f", unit: str = "") -> str:
    return "n/a" if v is None else f"{v:{spec}}{unit}"


def format_metrics(m: dict[str, Any], time_note: str = "") -> list[tuple[str, str]]:
    """(label, text) lines of a :func:`ground.logs.metrics.flight_metrics` dict, for the summary
    and the mission report (``time_note`` follows the first line, e.g. which clock the times use)."""
    if m.get("crashed"):
        crash = f"YES at {_fmt(m.get('crash_t_s'), '.2f', ' s')}: {m.get('crash_detail') or m.get('crash_reason')}"
    else:
        crash = "no"
    if m.get("fault_start_s") is None:
        recovery = "n/a (no fault)"
    else:
        where = f"fault at {m['fault_start_s']:.2f} s, radius {m.get('recover_radius_m', RECOVER_RADIUS_M):g} m"
        if m.get("recovered") is None and "scored_against" in m and m.get("iae_pos_m_s") is None:
            recovery = f"n/a: no position set-point to come back to ({where})"
        elif m.get("recovered") is None:
            recovery = f"n/a: not in flight after the fault ({where})"
        elif m.get("recovered"):
            recovery = f"back for good {m['recover_s']:.2f} s after the fault ({where})"
        else:
            recovery = f"NOT recovered ({where})"
    return [
        ("Metrics", f"over {_fmt(m.get('flight_time_s'), '.2f', ' s')} in flight (armed, not landing),"
                    f" {_fmt(m.get('armed_time_s'), '.2f', ' s')} armed{time_note}"),
        ("  position error", f"IAE {_fmt(m.get('iae_pos_m_s'), '.4g', ' m s')}, ISE {_fmt(m.get('ise_pos_m2_s'), '.4g', ' m^2 s')},"
                             f" ITAE {_fmt(m.get('itae_pos_m_s2'), '.4g', ' m s^2')}, in-flight max {_fmt(m.get('max_pos_err_m'), '.3g', ' m')}"),
        ("  attitude error", f"IAE {_fmt(m.get('iae_att_rad_s'), '.4g', ' rad s')}, ISE {_fmt(m.get('ise_att_rad2_s'), '.4g', ' rad^2 s')},"
                             f" ITAE {_fmt(m.get('itae_att_rad_s2'), '.4g', ' rad s^2')}"),
        ("  motor effort", f"int sum c^2 {_fmt(m.get('effort_u2_s'), '.4g', ' s')}, total variation {_fmt(m.get('motor_tv'), '.4g')}"
                           f" ({_fmt(m.get('motor_tv_per_s'), '.3g', ' /s')})"),
        ("  max tilt armed", _fmt(m.get("max_tilt_deg"), ".1f", " deg")),
        ("  recovery", recovery),
        ("  crashed", crash),
    ]  # fmt: skip


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
    c = s.get("comm_errors")
    line(
        "Rejected packets",
        "n/a (no SYS_STATUS from the FC)" if c is None else
        f"{c['errors_comm']}: {c['errors_count1']} bad frames, {c['errors_count2']} signing, {c['errors_count3']} refused,"
        f" {c['errors_count4']} on the sim link",
    )  # fmt: skip
    if s.get("served"):
        line("Served", f"our plant as the physics of {s['served']} (smcpilot sim --serve): another autopilot flew it")
        line("  scored against", (s.get("metrics_sources") or {}).get("setpoints") or "n/a (no served state)")
    line("State from", s.get("state_source") or "n/a")
    line("Controller data", s.get("controller_data") or "n/a")
    line("Max tilt", _fmt(s.get("max_tilt_deg"), ".1f", " deg"))
    settle = s.get("settle_s")
    if s.get("served"):
        line("Tracking", "n/a (another autopilot's flight: scored against its set-points under Metrics, with --setpoints)")
    elif s.get("settled_time_s") is None:
        line("Tracking", f"no settled flight (needs SMC set-points held >= {settle:g} s while armed)")
    else:
        line("Tracking", f"{s['settled_time_s']:.1f} s of settled flight (>= {settle:g} s after a set-point change)")
    if not s.get("served"):
        # Two windows hold a "max position error": settled flight here, all flight under Metrics;
        # each number says which.
        line(
            "  position error",
            f"final {_fmt(s.get('position_error_final_m'), '.3g', ' m')}; settled RMS {_fmt(s.get('position_error_rms_m'), '.3g', ' m')},"
            f" settled max {_fmt(s.get('position_error_max_m'), '.3g', ' m')}",
        )
        ned = s.get("position_error_final_ned_m")
        if ned:
            line("    final N/E/alt", "  ".join(_fmt(ned[k], "+.3g", " m") for k in ("north", "east", "alt")))
        line(
            "  yaw error",
            f"final {_fmt(s.get('yaw_error_final_deg'), '+.3g', ' deg')}; settled RMS {_fmt(s.get('yaw_error_rms_deg'), '.3g', ' deg')}",
        )
    chans = s.get("channels", list(CHANNELS))
    chi = s.get("chi_hat_final")
    line("chi_hat final", "n/a" if chi is None else "  ".join(f"{c} {_fmt(v, '.3f')}" for c, v in zip(chans, chi)))
    window = s.get("sigma_window_s", DEFAULT_SIGMA_WINDOW_S)
    for key, label in (("sigma_lpf_rms", "sigma LPF RMS"), ("sigma_dither_rms", "sigma dither")):
        sig = s.get(key)
        line(f"{label} ({window:g} s)", "n/a" if sig is None else "  ".join(f"{c} {_fmt(v, '.2e')}" for c, v in zip(chans, sig)))
    m = s.get("metrics")
    if m is None:
        line("Metrics", "n/a (they need the FC's per-tick SMC records and the state)" if not s.get("served") else "n/a (no served state)")
    else:
        truth_m = s.get("truth_metrics")
        sensed = " (on the sensors' output as served)" if s.get("served") else " (on the sensed state the FC flew on)"
        for label, text in format_metrics(m, sensed if truth_m is not None else ""):
            line(label, text)
        if truth_m is not None:
            for label, text in format_metrics(truth_m, " (on the true state: the simulator's ODOMETRY)"):
                line("Truth metrics" if label == "Metrics" else label, text)
    counts = s.get("message_counts", {})
    line("Messages", ", ".join(f"{k} {v}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1])) or "none")
    events = s.get("events", [])
    line("Events", "none" if not events else "")
    for e in events:
        print(f"  {e['t_s']:9.3f} s  {e['severity']:<9} {e['text']}", file=f)
