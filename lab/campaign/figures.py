"""Campaign figures (PNG, matplotlib's Agg backend): ECDF and box plots of the main metrics per
controller and scenario group, and the worst runs' time series."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from lab.campaign.flight import Trace

FIGURE_METRICS = (("max_pos_err_m", "max position error (m)"), ("iae_pos_m_s", "IAE position (m·s)"), ("max_tilt_deg", "max tilt (°)"))


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _values(rows: Sequence[dict[str, Any]], group: Any, ctrl: Any, key: str, group_key: str) -> list[float]:
    return sorted(float(r[key]) for r in rows if r.get(group_key) == group and r.get("controller") == ctrl
                  and isinstance(r.get(key), (int, float)) and not isinstance(r.get(key), bool) and math.isfinite(r[key]))  # fmt: skip


def _layout(n: int) -> tuple[int, int]:
    ncol = min(4, n)
    return (n + ncol - 1) // ncol, ncol


def _order(rows: Sequence[dict[str, Any]], key: str) -> list[Any]:
    seen: list[Any] = []
    for r in rows:
        if r.get(key) not in seen:
            seen.append(r.get(key))
    return seen


def _wide(values: Sequence[Sequence[float]]) -> bool:
    """Values spanning more than 20× (a crashed controller next to ones that held): log axis."""
    flat = [v for vs in values for v in vs]
    return bool(flat) and min(flat) > 0 and max(flat) > 20.0 * min(flat)


def write_distribution_figures(rows: Sequence[dict[str, Any]], fig_dir: Path, *, group_key: str = "group", title: str = "") -> list[Path]:
    """``ecdf_<metric>.png`` and ``box_<metric>.png`` of each figure metric: one panel per group,
    one line or box per controller. Crashed flights and flights with an error count in the ECDF only where they have a value."""
    plt = _plt()
    fig_dir.mkdir(parents=True, exist_ok=True)
    groups, ctrls = _order(rows, group_key), _order(rows, "controller")
    nrow, ncol = _layout(len(groups))
    paths = []
    for key, label in FIGURE_METRICS:
        for kind in ("ecdf", "box"):
            fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol, 3.0 * nrow + 0.6), squeeze=False)
            flat = [ax for row_axes in axes for ax in row_axes]
            for ax in flat[len(groups):]:
                ax.set_visible(False)
            for ax, g in zip(flat, groups):
                data = [_values(rows, g, c, key, group_key) for c in ctrls]
                if kind == "ecdf":
                    for c, vs in zip(ctrls, data):
                        if vs:
                            n = len(vs)
                            ax.step([vs[0], *vs], [0.0, *((i + 1) / n for i in range(n))], where="post", label=f"{c} (n={n})", lw=1.2)
                    ax.set_ylim(0.0, 1.02)
                    ax.set_ylabel("fraction of flights ≤ x", fontsize=8)
                    ax.set_xlabel(label, fontsize=8)
                    ax.legend(fontsize=7, loc="lower right")
                    ax.grid(alpha=0.3)
                else:
                    ax.boxplot([d if d else [math.nan] for d in data], tick_labels=[str(c) for c in ctrls], showfliers=True)
                    ax.tick_params(axis="x", labelrotation=30, labelsize=7)
                    ax.set_ylabel(label, fontsize=8)
                    ax.grid(axis="y", alpha=0.3)
                if _wide(data):
                    ax.set_xscale("log") if kind == "ecdf" else ax.set_yscale("log")
                ax.set_title(str(g), fontsize=8)
                ax.tick_params(labelsize=7)
            what = "ECDF" if kind == "ecdf" else "distribution (box: quartiles, whiskers 1.5 IQR)"
            fig.suptitle(f"{title + ': ' if title else ''}{label}, {what}, per {'case' if group_key == 'case' else 'scenario group'}", fontsize=9)
            fig.tight_layout()
            p = fig_dir / f"{kind}_{key}.png"
            fig.savefig(p, dpi=110)
            plt.close(fig)
            paths.append(p)
    return paths


def until_crash(row: dict[str, Any], trace: Trace) -> tuple[list[float], list[float], list[float], float | None]:
    """(t, position error, tilt) of a trace up to and including its crash (``crash_t_s`` of the
    row), and the crash time (None without one): what a vehicle did after it crashed is not flight."""
    t_crash = row.get("crash_t_s") if row.get("crashed") else None
    if not (isinstance(t_crash, (int, float)) and not isinstance(t_crash, bool) and math.isfinite(t_crash)):
        return list(trace.t_s), list(trace.pos_err_m), list(trace.tilt_deg), None
    n = next((i + 1 for i, t in enumerate(trace.t_s) if t >= t_crash), len(trace.t_s))
    return list(trace.t_s[:n]), list(trace.pos_err_m[:n]), list(trace.tilt_deg[:n]), float(t_crash)


def write_worst_figure(worst: Sequence[tuple[dict[str, Any], Trace]], path: Path, *, title: str = "worst runs", score_from_s: float = 0.0) -> Path:
    """Position error and tilt against time of the worst runs (one line each, labelled with the
    unit); a crashed run ends at its crash, marked ×; the part before ``score_from_s`` (not
    scored: the take-off) shaded; the axes end where the data do."""
    plt = _plt()
    path.parent.mkdir(parents=True, exist_ok=True)
    legend_rows = (len(worst) + 3 + 1) // 2  # the runs, crash, fault start, not scored; two columns
    height = 5.5 + 0.17 * legend_rows
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(11.5, height), sharex=True)
    fault_shown = crash_shown = False
    t_end, err_top, tilt_top = 0.0, 0.0, 0.0
    for row, tr in worst:
        t, err, tilt, t_crash = until_crash(row, tr)
        lab = f"unit {row['unit']}: {row['controller']}, {row['group']}, seed {row['seed_index']} ({row['status']})"
        (line,) = a1.plot(t, err, lw=1, label=lab)
        a2.plot(t, tilt, lw=1, color=line.get_color())
        if t:
            t_end = max(t_end, t[-1])
            err_top = max([err_top, *(e for e in err if math.isfinite(e))])
            tilt_top = max([tilt_top, *(x for x in tilt if math.isfinite(x))])
        if t_crash is not None and t:
            for ax, ys in ((a1, err), (a2, tilt)):
                ax.plot([t[-1]], [ys[-1]], "x", color=line.get_color(), ms=8, mew=2,
                        label="crash" if ax is a1 and not crash_shown else None)  # fmt: skip
            crash_shown = True
        start = row.get("fault_start_s")
        if isinstance(start, (int, float)) and math.isfinite(start):
            for ax in (a1, a2):
                ax.axvline(start, color="k", ls=":", lw=0.8, label="fault start" if ax is a1 and not fault_shown else None)
            fault_shown = True
    if score_from_s > 0:
        for ax in (a1, a2):
            ax.axvspan(0.0, score_from_s, color="0.85", alpha=0.6, lw=0, label="not scored (take-off)" if ax is a1 else None)
    a1.set_ylabel("position error (m)")
    a1.set_yscale("symlog", linthresh=0.1)
    a1.set_ylim(0.0, max(err_top, 0.1) * 1.3)
    a1.grid(alpha=0.3)
    a2.set_ylabel("tilt (°)")
    a2.set_ylim(0.0, max(tilt_top, 1.0) * 1.1)
    a2.set_xlabel("simulated time (s)")
    a2.grid(alpha=0.3)
    if t_end > 0:
        a2.set_xlim(0.0, t_end)
    a1.set_title(title, fontsize=9)
    # Below the axes, across the figure: the axes keep the full width (a legend beside them
    # left an empty column under it).
    handles, labels = a1.get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=7, frameon=False)
    fig.tight_layout(rect=(0.0, 0.17 * legend_rows / height + 0.01, 1.0, 1.0))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
