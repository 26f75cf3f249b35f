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
    one line or box per controller. Failed flights count in the ECDF only where they have a value."""
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


def write_worst_figure(worst: Sequence[tuple[dict[str, Any], Trace]], path: Path, *, title: str = "worst runs", score_from_s: float = 0.0) -> Path:
    """Position error and tilt against time of the worst runs (one line each, labelled with the
    unit); the part before ``score_from_s`` (not scored: the take-off) shaded."""
    plt = _plt()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(11.5, 5.5), sharex=True)
    fault_shown = False
    for row, tr in worst:
        lab = f"unit {row['unit']}: {row['controller']}, {row['group']}, seed {row['seed_index']} ({row['status']})"
        a1.plot(tr.t_s, tr.pos_err_m, lw=1, label=lab)
        a2.plot(tr.t_s, tr.tilt_deg, lw=1)
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
    a1.set_ylim(bottom=0.0)
    a1.grid(alpha=0.3)
    a2.set_ylabel("tilt (°)")
    a2.set_xlabel("simulated time (s)")
    a2.grid(alpha=0.3)
    a1.set_title(title, fontsize=9)
    a1.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
