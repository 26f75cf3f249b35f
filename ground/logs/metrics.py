"""Flight metrics: pure functions over sampled arrays (numpy; no I/O, no project state).

:func:`flight_metrics` reduces the time-stamped samples of one flight to a JSON-ready dict of
performance and robustness numbers. ``smcpilot log summary`` (:func:`ground.logs.summary.log_metrics`
builds the arrays from a ``.tlog``), ``smcpilot run --json``, the mission reports and in-process
studies without a log all call this one function, so a number means the same everywhere.

Inputs (``n`` samples)
----------------------
``t_s`` (n,), seconds, non-decreasing; ``position_m`` and ``target_m`` (n, 3) in any one
Cartesian frame whose **third axis points up** (the paper's x north, y west, z up, or north,
east, altitude): the ground-impact check reads the altitude from it; ``euler_rad`` and
``euler_ref_rad`` (n, 3) roll, pitch, yaw of the vehicle and of the law's attitude references
(rad, any one Euler convention: FRD-in-NED and FLU-in-NWU differ only in the signs of pitch and
yaw, which no metric here depends on); ``motors`` (n, 4) commands in [0, 1]; ``armed`` and
``landing`` (n,) booleans (``landing``: the FC descends on purpose: LAND, RTL's descent, a
failsafe). Optional: ``velocity_m_s`` (n, 3) same frame (else a backward difference of the
altitude), ``target_yaw_rad`` (n,) the heading set-point, ``sigma`` (n, 4) the law's σ per
channel (phi, theta, psi, z), ``land_speed_mps`` the FC's LAND speed, ``diverged_t_s`` when the
simulation ended in a divergence. NaN samples (a sensor dropout, a law without σ) are skipped:
an integral leaves out every interval with a NaN end, a maximum ignores NaN.

Windows
-------
- *in flight*: armed and not landing. *Armed*: armed.
- A *set-point change* is a sample whose position target (or heading target, if given) differs
  from the previous sample's by more than 1e-4 m (rad), or is given (finite) where the previous
  one was not or the other way round; a *segment* starts at each change and wherever the
  in-flight window (re)starts.
- Integrals are trapezoids on the sample times over the intervals [t_k, t_k+1] whose both ends
  lie in the window: for a signal f, ∫ f dt = Σ_k ½ (f_k + f_k+1)(t_k+1 − t_k). A window
  without any interval gives None (the vehicle never flew / never armed).

Metrics (keys carry the units)
------------------------------
- ``iae_pos_m_s`` = ∫ |e_p| dt, ``ise_pos_m2_s`` = ∫ |e_p|² dt, ``itae_pos_m_s2`` = ∫ (t − t_seg) |e_p| dt
  over the in-flight window, where e_p = position − target (3-D, m) and t_seg is the start of
  the sample's segment (the ITAE clock restarts at every set-point change).
- ``iae_att_rad_s``, ``ise_att_rad2_s``, ``itae_att_rad_s2``: the same of the attitude error
  |e_a| = sqrt((φ − φ_r)² + (θ − θ_r)² + wrap(ψ − ψ_r)²) (rad; yaw error wrapped to [−π, π)).
- ``effort_u2_s`` = ∫ Σ_i c_i² dt over the armed window (c_i ∈ [0, 1]; four motors at hover
  thrust 0.5 for 10 s give 10); ``motor_tv`` = Σ_k Σ_i |c_i[k] − c_i[k−1]| over consecutive
  armed pairs (dimensionless), ``motor_tv_per_s`` = ``motor_tv`` / ``armed_time_s``.
- ``max_tilt_deg``: the largest tilt acos(cos φ cos θ) (the angle of the body z axis to the
  vertical) over armed samples; ``max_pos_err_m``: the largest |e_p| in flight.
- ``flight_time_s``, ``armed_time_s``: the lengths of the two windows (Σ of their intervals).
- Recovery: with ``fault_start_s`` the first fault start (``fault_starts_s``; from a log, the
  ``SIM:`` start events, see :func:`fault_starts_from_events`), the assessed stretch runs from
  the fault start to the next set-point change, landing or disarm (exclusive) or the end of
  the data. ``recover_s`` is the time from the fault start until |e_p| last exceeded
  ``recover_radius_m`` (default 0.3 m) in that stretch (the down-crossing, linearly
  interpolated between the samples): 0 if it never left the radius, None if it had not come
  back by the end of the stretch (then ``recovered`` is False), or if there was no fault or the
  vehicle was not in flight at the first sample at or after the fault start (then
  ``recovered`` is None: not assessable). A NaN error counts as outside; a crash after the
  fault start is never a recovery.
- ``crashed`` with ``crash_reason`` (``"tilt"``, ``"impact"`` or ``"diverged"``), ``crash_t_s``
  and ``crash_detail``: the earliest of tilt > 60° while armed; ground impact: altitude
  < 0.05 m while descending faster than 1.0 m/s (at this sample or the one before: a rigid
  ground stops the vehicle within one step; while landing the limit is raised to
  1.5 × ``land_speed_mps`` if that is higher, so a touchdown at the configured LAND speed is
  never an impact); the simulation diverging (``diverged_t_s``).
- σ (the law's sliding variable): ``sigma_lpf_rms`` per channel is the RMS of σ low-passed
  causally with τ = 0.1 s, y_k = y_k−1 + (1 − e^(−Δt/τ)) (σ_k − y_k−1) (restarted after a NaN),
  i.e. how far the mean σ is from the sliding surface; ``sigma_dither_rms`` the RMS of σ − y,
  the chattering. Both over the last ``sigma_window_s`` (5 s) up to the last in-flight sample
  with a finite σ (before a final landing), the filter having run over the whole flight.
  A pure ±1 sign dither at 500 Hz gives ≈ 0.01 and ≈ 1; a constant σ gives that constant and 0.

Every value is a float, int, bool, str, None or a list of them (no NaN, no inf).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from smcpilot.errors import SmcpilotError

__all__ = [
    "IMPACT_ALT_M",
    "IMPACT_SPEED_MPS",
    "MetricsError",
    "RECOVER_RADIUS_M",
    "SETPOINT_TOLERANCE",
    "SIGMA_TAU_S",
    "SIGMA_WINDOW_S",
    "TILT_CRASH_DEG",
    "divergence_from_events",
    "fault_starts_from_events",
    "flight_metrics",
    "integrate",
    "lowpass",
    "score_compiled",
    "setpoint_changes",
    "sigma_metrics",
    "sigma_window",
    "tilt_rad",
]

#: Radius around the set-point the vehicle must return within after a fault, m.
RECOVER_RADIUS_M = 0.3
#: Time constant of the σ low-pass, s.
SIGMA_TAU_S = 0.1
#: Length of the σ window: the last seconds of flight before landing, s.
SIGMA_WINDOW_S = 5.0
#: Tilt beyond which an armed vehicle counts as crashed, deg.
TILT_CRASH_DEG = 60.0
#: Altitude below which a fast descent is a ground impact, m.
IMPACT_ALT_M = 0.05
#: Descent speed above which touching the ground is an impact, m/s.
IMPACT_SPEED_MPS = 1.0
#: Target changes smaller than this (m or rad) are float noise, not a new set-point.
SETPOINT_TOLERANCE = 1e-4
# Severity name and number (MAV_SEVERITY_WARNING) of a fault start; a stop is INFO, a refused
# SIM_* parameter ERROR.
_START_SEVERITIES = frozenset({"WARNING", 4})
_NOT_A_FAULT = ("reject", "refuse", "diverg")


class MetricsError(SmcpilotError, ValueError):
    """The arrays given to :func:`flight_metrics` do not fit together (the message names the argument)."""


# -- small pure pieces ----------------------------------------------------------------------------
def integrate(t_s: np.ndarray, f: np.ndarray, mask: np.ndarray) -> float:
    """Trapezoid ∫ f dt over the intervals [t_k, t_k+1] whose both ends are in ``mask`` with a
    finite ``f`` (units of f times seconds; 0.0 when there is no such interval)."""
    if t_s.size < 2:
        return 0.0
    return _integral(np.diff(t_s), f, mask)


def _integral(dt_s: np.ndarray, f: np.ndarray, mask: np.ndarray) -> float:
    """:func:`integrate` on the sample intervals ``dt_s`` (``np.diff(t_s)``)."""
    ok = mask & np.isfinite(f)
    pair = ok[:-1] & ok[1:]
    if not pair.any():
        return 0.0
    return _trapezoid(f, pair, dt_s[pair])


def _trapezoid(f: np.ndarray, pair: np.ndarray, dt_pair_s: np.ndarray) -> float:
    """Σ ½ (f_k + f_k+1)(t_k+1 − t_k) over the intervals ``pair`` selects, whose lengths are
    ``dt_pair_s`` (the trapezoid sum every integral here is)."""
    return float(np.sum(0.5 * (f[:-1][pair] + f[1:][pair]) * dt_pair_s))


def _span(dt_s: np.ndarray, mask: np.ndarray) -> float:
    """Σ of the intervals ``dt_s`` (``np.diff(t_s)``) whose both ends are in ``mask``, s."""
    return float(np.sum(dt_s[mask[:-1] & mask[1:]]))


def _row_sum(x: np.ndarray) -> np.ndarray:
    """Σ over the few columns of ``x`` (n, m), left to right: ``np.sum(x, axis=1)``'s numbers, bit
    for bit (numpy reduces a row in that order), without its slow reduction along a short axis."""
    if x.shape[1] == 0:
        return np.zeros(x.shape[0])
    out = x[:, 0].copy()
    for j in range(1, x.shape[1]):
        out += x[:, j]
    return out


def _row_any(b: np.ndarray) -> np.ndarray:
    """``np.any(b, axis=1)`` of a boolean (n, m) with few columns, column by column."""
    if b.shape[1] == 0:
        return np.zeros(b.shape[0], dtype=bool)
    out = b[:, 0].copy()
    for j in range(1, b.shape[1]):
        out |= b[:, j]
    return out


def _row_norm(x: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(x, axis=1)`` of a real (n, m) with few columns, bit for bit."""
    return np.sqrt(_row_sum(x * x))


def tilt_rad(roll_rad: np.ndarray, pitch_rad: np.ndarray) -> np.ndarray:
    """Angle between the body z axis and the vertical, acos(cos φ cos θ), rad (NaN stays NaN)."""
    c = np.cos(roll_rad) * np.cos(pitch_rad)
    return np.arccos(np.clip(c, -1.0, 1.0))


def _wrap_pi(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to [−π, π) (rad)."""
    w = np.mod(a + math.pi, 2.0 * math.pi) - math.pi
    return np.where(w >= math.pi, w - 2.0 * math.pi, w)


def setpoint_changes(target_m: np.ndarray, target_yaw_rad: np.ndarray | None = None, tolerance: float = SETPOINT_TOLERANCE) -> np.ndarray:
    """Mask of the samples whose position target (or wrapped heading target) differs from the
    previous sample's by more than ``tolerance`` (m, rad), or is given where the previous one was
    not (NaN) or the other way round; the first sample counts as a change."""
    n = target_m.shape[0]
    changed = np.zeros(n, dtype=bool)
    if n:
        changed[0] = True
        given = np.isfinite(target_m)
        changed[1:] |= _row_any(given[1:] != given[:-1])
        with np.errstate(invalid="ignore"):
            changed[1:] |= _row_any(np.abs(np.diff(target_m, axis=0)) > tolerance)
            if target_yaw_rad is not None:
                yaw_given = np.isfinite(target_yaw_rad)
                changed[1:] |= yaw_given[1:] != yaw_given[:-1]
                changed[1:] |= np.abs(_wrap_pi(np.diff(target_yaw_rad))) > tolerance
    return changed


def lowpass(t_s: np.ndarray, x: np.ndarray, tau_s: float = SIGMA_TAU_S) -> np.ndarray:
    """Causal first-order low-pass of ``x`` (n,) or (n, m) on the sample times ``t_s`` [s]:
    y_k = y_k−1 + (1 − exp(−(t_k − t_k−1)/τ)) (x_k − y_k−1), y = x at the first sample and at the
    first finite sample after a NaN (a NaN input gives a NaN output), per column.

    In a process that flies compiled (:func:`score_compiled` was called), the loop runs compiled:
    the same numbers, bit for bit."""
    if not (math.isfinite(tau_s) and tau_s > 0.0):
        raise MetricsError(f"tau_s must be a finite number > 0, got {tau_s!r}")
    xs = np.asarray(x, dtype=float)
    cols = xs.reshape(xs.shape[0], -1)
    n, m = cols.shape
    out = np.full((n, m), math.nan)
    if n == 0:
        return out.reshape(xs.shape)
    alpha = np.concatenate(([0.0], -np.expm1(-np.diff(np.asarray(t_s, dtype=float)) / tau_s)))
    compiled = _COMPILED[0]
    if compiled is not None:
        for j in range(m):
            yj = np.full(n, math.nan)
            compiled(alpha, np.ascontiguousarray(cols[:, j]), yj)
            out[:, j] = yj
    else:  # CPython: lists index faster than arrays
        alpha_l = alpha.tolist()
        for j in range(m):
            yl = [math.nan] * n
            _lowpass_column(alpha_l, cols[:, j].tolist(), yl)
            out[:, j] = yl
    return out.reshape(xs.shape)


def _lowpass_column(alpha: Any, x: Any, out: Any) -> None:
    """:func:`lowpass` of one column ``x`` with the gains ``alpha`` into ``out`` (NaN where ``x``
    is): lists in CPython, float64 arrays compiled (pure style)."""
    y = math.nan
    for k in range(len(x)):
        v = x[k]
        if v != v:  # NaN: the filter restarts at the next finite sample
            y = math.nan
            continue
        y = v if y != y else y + alpha[k] * (v - y)
        out[k] = y


#: :func:`lowpass`'s compiled loop, once :func:`score_compiled` made it (None: CPython).
_COMPILED: list[Any] = [None]


def score_compiled() -> bool:
    """Score with the compiled loop from now on in this process (the flight kernel's processes
    call it: numba is loaded there already, and its cached twin loads in milliseconds). Commands
    that only read logs never call it, so they never import numba. False (and CPython stays) when
    the compiled path is off or unavailable."""
    if _COMPILED[0] is None:
        from smcpilot.jit import compile_pure, jit_enabled

        if not jit_enabled(say=False):
            return False
        _COMPILED[0] = compile_pure([_lowpass_column])[_lowpass_column]
    return True


def _rms(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if x.size else None


def sigma_metrics(t_s: np.ndarray, sigma: np.ndarray, window: np.ndarray, tau_s: float = SIGMA_TAU_S) -> tuple[list[float | None] | None, list[float | None] | None]:
    """(``sigma_lpf_rms``, ``sigma_dither_rms``) per channel: the RMS over the samples in
    ``window`` of σ low-passed with ``tau_s`` over the whole series (:func:`lowpass`), and of σ
    minus that low-pass. None for a channel without finite samples; None for both when no
    channel has one."""
    y = lowpass(t_s, sigma, tau_s)[window]
    s = sigma[window]
    lpf = [_rms(y[:, j]) for j in range(sigma.shape[1])]
    dither = [_rms(s[:, j] - y[:, j]) for j in range(sigma.shape[1])]
    if all(v is None for v in lpf):
        return None, None
    return lpf, dither


def sigma_window(t_s: np.ndarray, sigma: np.ndarray, holding: np.ndarray | None, window_s: float = SIGMA_WINDOW_S) -> np.ndarray:
    """Mask of the last ``window_s`` seconds ending at the last sample with a finite σ (any
    channel) while ``holding`` (in flight); if σ is never finite while holding, at the last
    finite σ at all."""
    finite = _row_any(np.isfinite(sigma)) if sigma.size else np.zeros(t_s.size, dtype=bool)
    if holding is not None and np.any(finite & holding):
        finite = finite & holding
    if not finite.any():
        return np.zeros(t_s.size, dtype=bool)
    t_end = t_s[np.flatnonzero(finite)[-1]]
    return (t_s >= t_end - window_s) & (t_s <= t_end)


def fault_starts_from_events(events: Iterable[tuple[float, int | str, str]]) -> list[float]:
    """Times [s] of the fault starts among ``(t_s, severity, text)`` events (severity a
    MAV_SEVERITY number or its name): a text starting with ``"SIM:"`` sent with severity WARNING
    (the simulator announces a start as WARNING, a stop as INFO, a refused parameter as ERROR),
    and not saying "rejected", "refused" or "diverged"."""
    out = []
    for t, severity, text in events:
        sev: int | str = severity.upper() if isinstance(severity, str) else int(severity)
        low = text.lower()
        if text.startswith("SIM:") and sev in _START_SEVERITIES and not any(w in low for w in _NOT_A_FAULT):
            out.append(float(t))
    return out


def divergence_from_events(events: Iterable[tuple[float, int | str, str]]) -> float | None:
    """Time [s] of the first event reporting that the simulation diverged ("diverged" in its text), or None."""
    for t, _, text in events:
        if "diverged" in text.lower():
            return float(t)
    return None


def _num(x: Any) -> float | None:
    """A JSON-safe float (None for NaN and inf)."""
    v = float(x)
    return v if math.isfinite(v) else None


# -- validation -----------------------------------------------------------------------------------
def _array(name: str, a: Any, n: int, columns: int | None, dtype: Any = float) -> np.ndarray:
    arr = np.asarray(a, dtype=dtype)
    want = (n,) if columns is None else (n, columns)
    if arr.shape != want:
        raise MetricsError(f"{name} must have shape {want} (as t_s has {n} samples), got {arr.shape}")
    return arr


def _finite_param(name: str, v: float, *, positive: bool = False) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise MetricsError(f"{name} must be a number, got {v!r}") from None
    if not math.isfinite(f) or (positive and f <= 0.0):
        raise MetricsError(f"{name} must be a finite number{' > 0' if positive else ''}, got {v!r}")
    return f


# -- the metrics ----------------------------------------------------------------------------------
def _crash(
    t: np.ndarray,
    tilt: np.ndarray,
    alt: np.ndarray,
    climb: np.ndarray,
    armed: np.ndarray,
    landing: np.ndarray,
    land_speed_mps: float | None,
    diverged_t_s: float | None,
) -> tuple[str, float, str] | None:
    """(reason, time, detail) of the earliest crash, or None."""
    found: list[tuple[float, str, str]] = []
    with np.errstate(invalid="ignore"):
        over = armed & (tilt > math.radians(TILT_CRASH_DEG))
    if over.any():
        k = int(np.flatnonzero(over)[0])
        found.append((float(t[k]), "tilt", f"tilt {math.degrees(tilt[k]):.1f} deg > {TILT_CRASH_DEG:g} deg while armed"))
    descent = -climb
    before = np.concatenate(([math.nan], descent[:-1])) if descent.size else descent
    rate = np.fmax(descent, before)  # a rigid ground zeroes the velocity of the sample that touches it
    limit = np.full(t.size, IMPACT_SPEED_MPS)
    if land_speed_mps is not None:
        limit[landing] = max(IMPACT_SPEED_MPS, 1.5 * land_speed_mps)
    with np.errstate(invalid="ignore"):
        hit = (alt < IMPACT_ALT_M) & (rate > limit)
    if hit.any():
        k = int(np.flatnonzero(hit)[0])
        found.append((float(t[k]), "impact", f"ground impact at {rate[k]:.1f} m/s (altitude {alt[k]:.2f} m)"))
    if diverged_t_s is not None:
        found.append((float(diverged_t_s), "diverged", "the simulation diverged"))
    if not found:
        return None
    t_c, reason, detail = min(found, key=lambda f: f[0])
    return reason, t_c, detail


def _recovery(
    t: np.ndarray,
    err: np.ndarray,
    armed: np.ndarray,
    landing: np.ndarray,
    changed: np.ndarray,
    t_fault: float,
    radius_m: float,
    crash_t_s: float | None,
) -> tuple[float | None, bool | None]:
    """(recover_s, recovered) for a fault starting at ``t_fault`` (see the module docstring)."""
    first = int(np.searchsorted(t, t_fault, side="left"))
    new_setpoint = changed.copy()
    new_setpoint[:1] = False  # the first sample is not a change the vehicle was asked to fly
    stop = (~armed | landing | new_setpoint) & (t > t_fault)
    stop_idx = np.flatnonzero(stop[first:])
    end = first + int(stop_idx[0]) if stop_idx.size else t.size
    if end <= first or not armed[first] or landing[first]:
        return None, None  # not in flight when the fault started: not assessable
    if crash_t_s is not None and crash_t_s >= t_fault:
        return None, False
    e = err[first:end]
    with np.errstate(invalid="ignore"):
        out = ~(e <= radius_m)  # NaN counts as outside
    if not out.any():
        return 0.0, True
    j = int(np.flatnonzero(out)[-1])
    if j == e.size - 1:
        return None, False
    t_j, t_n = t[first + j], t[first + j + 1]
    e_j, e_n = e[j], e[j + 1]
    t_back = t_j + (e_j - radius_m) / (e_j - e_n) * (t_n - t_j) if math.isfinite(e_j) and e_j > e_n else t_n
    return max(0.0, float(t_back - t_fault)), True


def flight_metrics(
    t_s: Any,
    position_m: Any,
    target_m: Any,
    euler_rad: Any,
    euler_ref_rad: Any,
    motors: Any,
    armed: Any,
    landing: Any,
    *,
    fault_starts_s: Sequence[float] = (),
    recover_radius_m: float = RECOVER_RADIUS_M,
    velocity_m_s: Any = None,
    target_yaw_rad: Any = None,
    sigma: Any = None,
    sigma_window_s: float = SIGMA_WINDOW_S,
    sigma_tau_s: float = SIGMA_TAU_S,
    land_speed_mps: float | None = None,
    diverged_t_s: float | None = None,
) -> dict[str, Any]:
    """The metrics of one flight from its samples (shapes, units, frames and every definition in
    the module docstring). Raises :class:`MetricsError` for arrays that do not fit together or
    a non-finite parameter."""
    t = np.asarray(t_s, dtype=float)
    if t.ndim != 1:
        raise MetricsError(f"t_s must be one-dimensional, got shape {t.shape}")
    n = t.size
    if not np.all(np.isfinite(t)):
        raise MetricsError(f"t_s must be finite: sample {int(np.flatnonzero(~np.isfinite(t))[0])} is {t[~np.isfinite(t)][0]}")
    dt = np.diff(t)  # the sample intervals, s (every integral's)
    if n > 1 and np.any(dt < 0.0):
        raise MetricsError(f"t_s must not decrease: sample {int(np.flatnonzero(dt < 0.0)[0]) + 1} goes back in time")
    pos = _array("position_m", position_m, n, 3)
    tgt = _array("target_m", target_m, n, 3)
    eul = _array("euler_rad", euler_rad, n, 3)
    ref = _array("euler_ref_rad", euler_ref_rad, n, 3)
    mot = _array("motors", motors, n, 4)
    arm = _array("armed", armed, n, None, bool)
    land = _array("landing", landing, n, None, bool)
    vel = _array("velocity_m_s", velocity_m_s, n, 3) if velocity_m_s is not None else None
    yaw_t = _array("target_yaw_rad", target_yaw_rad, n, None) if target_yaw_rad is not None else None
    sig = _array("sigma", sigma, n, 4) if sigma is not None else None
    radius = _finite_param("recover_radius_m", recover_radius_m, positive=True)
    window_s = _finite_param("sigma_window_s", sigma_window_s, positive=True)
    tau = _finite_param("sigma_tau_s", sigma_tau_s, positive=True)
    land_speed = _finite_param("land_speed_mps", land_speed_mps, positive=True) if land_speed_mps is not None else None
    diverged = _finite_param("diverged_t_s", diverged_t_s) if diverged_t_s is not None else None
    starts = [_finite_param(f"fault_starts_s[{i}]", v) for i, v in enumerate(fault_starts_s)]

    flying = arm & ~land
    changed = setpoint_changes(tgt, yaw_t)
    # Segment starts: set-point changes and (re)entries into the in-flight window.
    seg = flying & changed
    if n:
        seg[0] = flying[0]
        seg[1:] |= flying[1:] & ~flying[:-1]
    seg_idx = np.maximum.accumulate(np.where(seg, np.arange(n), 0)) if n else np.zeros(0, dtype=int)
    since = t - t[seg_idx] if n else t

    err_p = _row_norm(pos - tgt)
    d_att = eul - ref
    d_att[:, 2] = _wrap_pi(d_att[:, 2])
    err_a = _row_norm(d_att)
    tilt = tilt_rad(eul[:, 0], eul[:, 1])
    alt = pos[:, 2]
    if vel is not None:
        climb = vel[:, 2]
    else:
        climb = np.full(n, math.nan)
        if n > 1:
            with np.errstate(invalid="ignore", divide="ignore"):
                climb[1:] = np.where(dt > 0.0, np.diff(alt) / np.where(dt > 0.0, dt, 1.0), math.nan)

    flying_pair = flying[:-1] & flying[1:]  # the in-flight window's intervals (every in-flight integral's)
    dt_flying = dt[flying_pair]
    flight_time = float(np.sum(dt_flying))
    armed_time = _span(dt, arm)
    effort = _integral(dt, _row_sum(mot * mot), arm)
    if n > 1:
        pair = arm[:-1] & arm[1:]
        steps = _row_sum(np.abs(np.diff(mot, axis=0)))
        tv = float(np.sum(steps[pair & np.isfinite(steps)]))
    else:
        tv = 0.0
    tilt_armed = tilt[arm & np.isfinite(tilt)]
    err_flying = err_p[flying & np.isfinite(err_p)]

    crash = _crash(t, tilt, alt, climb, arm, land, land_speed, diverged)
    crash_t = crash[1] if crash is not None else None
    t_fault = min(starts) if starts else None
    if t_fault is None:
        recover_s, recovered = None, None
    else:
        recover_s, recovered = _recovery(t, err_p, arm, land, changed, t_fault, radius, crash_t)

    flew, spun = flight_time > 0.0, armed_time > 0.0  # without any interval an integral says nothing: None

    def over_flight(f: np.ndarray) -> float | None:
        if not flew:
            return None
        if np.isfinite(f).all():  # every interval of the window counts (the common case: the same sum, fewer steps)
            return _trapezoid(f, flying_pair, dt_flying)
        return _integral(dt, f, flying)

    out: dict[str, Any] = {
        "samples": int(n),
        "flight_time_s": flight_time,
        "armed_time_s": armed_time,
        "iae_pos_m_s": over_flight(err_p),
        "ise_pos_m2_s": over_flight(err_p * err_p),
        "itae_pos_m_s2": over_flight(since * err_p),
        "iae_att_rad_s": over_flight(err_a),
        "ise_att_rad2_s": over_flight(err_a * err_a),
        "itae_att_rad_s2": over_flight(since * err_a),
        "effort_u2_s": effort if spun else None,
        "motor_tv": tv if spun else None,
        "motor_tv_per_s": tv / armed_time if spun else None,
        "max_tilt_deg": _num(math.degrees(float(np.max(tilt_armed)))) if tilt_armed.size else None,
        "max_pos_err_m": _num(np.max(err_flying)) if err_flying.size else None,
        "fault_start_s": t_fault,
        "recover_radius_m": radius,
        "recover_s": recover_s,
        "recovered": recovered,
        "crashed": crash is not None,
        "crash_reason": crash[0] if crash is not None else None,
        "crash_t_s": crash_t,
        "crash_detail": crash[2] if crash is not None else None,
        "sigma_tau_s": tau,
        "sigma_window_s": window_s,
        "sigma_lpf_rms": None,
        "sigma_dither_rms": None,
    }
    if sig is not None:
        window = sigma_window(t, sig, flying, window_s)
        out["sigma_lpf_rms"], out["sigma_dither_rms"] = sigma_metrics(t, sig, window, tau)
    return out
