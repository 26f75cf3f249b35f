"""Figures of a flight log: :func:`plot_log` writes PNGs (position, attitude, motors,
sigma/chi_hat, track) of a :class:`~ground.logs.load.FlightLog`. Axes: time in seconds since the
log's first record; north/east/altitude-up in metres; angles in degrees (NED/FRD)."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from ground.logs.load import CHANNELS, FlightLog, LogError, _wrap_deg
from ground.logs.metrics import SIGMA_TAU_S, lowpass
from ground.logs.summary import DEFAULT_SETTLE_S, _hold, _setpoint_changes, _tracking_masks
from smcpilot.protocol import CHANNEL_TAGS

__all__ = ["plot_log"]


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

    Figures (each skipped, and an older file of its name in ``out_dir`` deleted, when the log
    has no data for it): ``position.png`` (north, east,
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
            # No data for it in this log: an earlier log's figure of that name must not stay
            # beside this one's (a cascade_pid log has no controller.png).
            (out / name).unlink(missing_ok=True)
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
    units = {"phi": ("rad/s", "rad/s²"), "theta": ("rad/s", "rad/s²"), "psi": ("rad/s", "rad/s²"), "z": ("m/s", "m/s²")}
    for i, c in enumerate(CHANNELS):
        sigma_unit, chi_unit = units[c]
        for k, what in enumerate(cols):
            ax = axes[i, k]
            _shade_armed(ax, log)
            if what == "sigma":
                sigma = log.sigma[:, i]
                ax.plot(log.ctrl_t_s, sigma, color="tab:purple", lw=0.6, alpha=0.45, label="σ (every tick)")
                ok = np.isfinite(sigma)
                if ok.sum() > 2:
                    smooth = np.full(sigma.shape, np.nan)
                    smooth[ok] = lowpass(log.ctrl_t_s[ok], sigma[ok], SIGMA_TAU_S)
                    ax.plot(log.ctrl_t_s, smooth, color="indigo", lw=1.0, label=f"σ low-passed (τ = {SIGMA_TAU_S:g} s)")
                if dead_zone:
                    # Lines, not a band: on the symlog axis a band of ±dead_zone would cover most of it.
                    for sign in (1.0, -1.0):
                        ax.axhline(sign * dead_zone, color="0.35", ls="--", lw=0.8,
                                   label=f"dead zone |σ| < {dead_zone:g} ({bounds_source}): χ̂ does not grow" if sign > 0 else None)  # fmt: skip
                ax.set_yscale("symlog", linthresh=1e-3)
                ax.set_ylabel(f"σ_{symbols[c]} [{sigma_unit}]")
            else:
                ax.plot(log.ctrl_t_s, log.chi_hat[:, i], color="tab:green", lw=1.2, label="χ̂")
                if bounds is not None:
                    _draw_bounds(ax, log.chi_hat[:, i], bounds, bounds_source)
                ax.set_ylabel(f"χ̂_{symbols[c]} [{chi_unit}]")
            ax.grid(alpha=0.3)
    for k in range(len(cols)):
        axes[0, k].legend(fontsize=7, loc="lower left" if cols[k] == "sigma" else "upper left")
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
        ax.plot(log.east_m, log.north_m, color="tab:blue", lw=1.3, label="vehicle", zorder=2)
        # Hollow and drawn last, so that a set-point at the same spot (home) shows through.
        ax.plot(log.east_m[0], log.north_m[0], "o", mfc="none", mec="tab:green", mew=2, ms=13, label="start", zorder=5)
        ax.plot(log.east_m[-1], log.north_m[-1], "s", mfc="none", mec="navy", mew=1.5, ms=9, label="end", zorder=5)
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
        # One label per spot, a line per set-point there (home is visited at take-off, on return, at landing).
        spots: dict[tuple[float, float], list[str]] = {}
        for k in np.flatnonzero(_setpoint_changes(log)):
            n_t, e_t, alt_t = target[k]
            if not (math.isfinite(n_t) and math.isfinite(e_t)):
                continue
            spots.setdefault((round(float(e_t), 2), round(float(n_t), 2)), []).append(
                f"t={log.smc_t_s[k]:.1f} s: alt {alt_t:.1f} m, yaw {log.target_yaw_deg[k]:.0f}°"
            )
        if spots:
            es = [e for e, _ in spots]
            ns = [n for _, n in spots]
            ax.plot(es, ns, "x", color="tab:red", ms=10, mew=2, label="set-point", zorder=4)
            all_e = np.concatenate([log.east_m[np.isfinite(log.east_m)], es]) if has_pos else np.asarray(es)
            mid_e = 0.5 * (float(np.min(all_e)) + float(np.max(all_e)))
            for (e_t, n_t), lines in spots.items():
                right_half = e_t > mid_e
                ax.annotate(
                    "\n".join(lines), (e_t, n_t), xytext=(-10 if right_half else 10, -10), textcoords="offset points",
                    ha="right" if right_half else "left", va="top", fontsize=8, color="tab:red", zorder=6,
                    bbox={"boxstyle": "round,pad=0.25", "fc": "white", "ec": "none", "alpha": 0.8},
                )  # fmt: skip
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.margins(0.15)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    return fig
