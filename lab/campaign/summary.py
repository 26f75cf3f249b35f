"""Campaign summaries: per controller × scenario group, the mean and 95 % interval of the main
metrics and the failure rate; the N worst runs with the command that replays each."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from lab.campaign.flight import badness, is_failure

#: the metrics the tables report, in order, with their labels.
MAIN_METRICS = (
    ("max_tilt_deg", "max tilt °"),
    ("max_pos_err_m", "max pos. err. m"),
    ("iae_pos_m_s", "IAE pos. m·s"),
    ("iae_att_rad_s", "IAE att. rad·s"),
    ("recover_s", "recover s"),
    ("motor_tv_per_s", "motor TV /s"),
)


def _finite(values: Sequence[Any]) -> np.ndarray:
    return np.asarray([v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)], dtype=float)


def ci95(values: Sequence[Any]) -> tuple[float, float, float] | None:
    """(mean, low, high) of a Student-t 95 % interval of the finite numbers in ``values``; None
    without any."""
    x = _finite(values)
    if x.size == 0:
        return None
    mean = float(x.mean())
    if x.size < 2:
        return mean, mean, mean
    from scipy import stats

    half = float(stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size))
    return mean, mean - half, mean + half


def summarize(rows: Sequence[dict[str, Any]], *, group_key: str = "group", metrics: Sequence[tuple[str, str]] = MAIN_METRICS) -> list[dict[str, Any]]:
    """Per (group, controller), in first-seen order: flights, failures (any status but ok), the
    failure and crash rates, the count of each status, and the mean / 95 % interval of ``metrics``
    (over the flights with a value)."""
    groups: dict[tuple[Any, Any], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r.get(group_key), r.get("controller")), []).append(r)
    out = []
    for (group, ctrl), rs in groups.items():
        statuses: dict[str, int] = {}
        for r in rs:
            statuses[str(r.get("status"))] = statuses.get(str(r.get("status")), 0) + 1
        entry: dict[str, Any] = {group_key: group, "controller": ctrl, "flights": len(rs), "failures": sum(is_failure(r) for r in rs),
                                 "statuses": statuses}  # fmt: skip
        entry["failure_rate"] = entry["failures"] / len(rs)
        entry["crash_rate"] = sum(bool(r.get("crashed")) for r in rs) / len(rs)
        for key, _label in metrics:
            ci = ci95([r.get(key) for r in rs])
            entry[key] = None if ci is None else {"mean": ci[0], "ci95": [ci[1], ci[2]]}
        out.append(entry)
    return out


def cell(entry: dict[str, Any], key: str) -> str:
    """``mean ± half-width`` of a summary entry's metric (– without values)."""
    v = entry.get(key)
    if v is None:
        return "–"
    mean, (lo, hi) = v["mean"], v["ci95"]
    digits = 1 if key == "max_tilt_deg" else 2 if abs(mean) >= 1 else 3
    return f"{mean:.{digits}f} ± {max(hi - mean, mean - lo):.{digits}f}"


def markdown_table(summary: Sequence[dict[str, Any]], *, group_key: str = "group", failures: str = "failed",
                   metrics: Sequence[tuple[str, str]] = MAIN_METRICS, order: Sequence[str] = ()) -> str:  # fmt: skip
    """One row per group × controller: failures (``failed``: any status but ok; ``crashed``: the
    metrics' crash detection), then the metrics (mean ± 95 % half-width)."""
    head = f"| {'case' if group_key == 'case' else 'group'} | controller | {failures} | " + " | ".join(label for _, label in metrics) + " |"
    lines = [head, "|" + "---|" * (3 + len(metrics))]
    rank = {c: i for i, c in enumerate(order)}
    names: list[Any] = []
    for e in summary:
        if e[group_key] not in names:
            names.append(e[group_key])
    for g in names:
        for e in sorted((e for e in summary if e[group_key] == g), key=lambda e: rank.get(e["controller"], 99)):
            n = e["flights"]
            bad = e["failures"] if failures == "failed" else round(e["crash_rate"] * n)
            lines.append(f"| {g} | {e['controller']} | {bad}/{n} | " + " | ".join(cell(e, k) for k, _ in metrics) + " |")
    return "\n".join(lines) + "\n"


def worst(rows: Sequence[dict[str, Any]], n: int) -> list[dict[str, Any]]:
    """The ``n`` worst rows: failures first, then the largest max position error (ties: unit order)."""
    return sorted(rows, key=lambda r: (tuple(-x for x in badness(r)), r.get("unit", 0)))[:n]


def worst_markdown(rows: Sequence[dict[str, Any]], out_dir: str) -> str:
    """The worst runs as a Markdown list, each with its one-line replay command."""
    lines = []
    for r in rows:
        err = r.get("max_pos_err_m")
        err_s = f"{err:.3g} m" if isinstance(err, (int, float)) and math.isfinite(err) else "–"
        msg = f" — {r['message']}" if r.get("message") else ""
        lines.append(f"- unit {r['unit']} ({r['controller']}, {r['group']}, seed index {r['seed_index']}): {r['status']}{msg};"
                     f" max position error {err_s}\n  `smcpilot campaign replay {out_dir} {r['unit']}`")  # fmt: skip
    return "\n".join(lines) + ("\n" if lines else "")
