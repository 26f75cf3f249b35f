"""Campaign summaries: per controller × scenario group, the mean and 95 % interval of the main
metrics, the crash rate (the vehicle) and the error rate (the software); the N worst runs with
the command that replays each."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from lab.campaign.flight import badness, is_crash, is_error

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
    """Per (group, controller), in first-seen order: flights; crashes (the vehicle: status crashed
    or diverged, or the metrics' crash detection) and errors (the software: status error or timed
    out), with their rates; the count of each status; and the mean / 95 % interval of ``metrics``
    (over the flights with a value)."""
    groups: dict[tuple[Any, Any], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r.get(group_key), r.get("controller")), []).append(r)
    out = []
    for (group, ctrl), rs in groups.items():
        statuses: dict[str, int] = {}
        for r in rs:
            statuses[str(r.get("status"))] = statuses.get(str(r.get("status")), 0) + 1
        errors = sum(is_error(r) for r in rs)
        crashes = sum(is_crash(r) and not is_error(r) for r in rs)
        entry: dict[str, Any] = {group_key: group, "controller": ctrl, "flights": len(rs), "crashes": crashes, "errors": errors,
                                 "statuses": statuses}  # fmt: skip
        entry["crash_rate"] = crashes / len(rs)
        entry["error_rate"] = errors / len(rs)
        for key, _label in metrics:
            ci = ci95([r.get(key) for r in rs])
            entry[key] = None if ci is None else {"mean": ci[0], "ci95": [ci[1], ci[2]]}
        out.append(entry)
    return out


#: fewer flights than this per row, and the table says its intervals are rough.
FEW_FLIGHTS = 5
#: the mark of a cell whose 95 % interval is wider than its mean.
WIDE = "†"


def _wide(v: dict[str, Any]) -> bool:
    mean, (lo, hi) = v["mean"], v["ci95"]
    return max(hi - mean, mean - lo) > abs(mean)


def cell(entry: dict[str, Any], key: str) -> str:
    """``mean ± half-width`` of a summary entry's metric (– without values; † when the interval
    is wider than the mean: too few flights to tell)."""
    v = entry.get(key)
    if v is None:
        return "–"
    mean, (lo, hi) = v["mean"], v["ci95"]
    digits = 1 if key == "max_tilt_deg" else 2 if abs(mean) >= 1 else 3
    return f"{mean:.{digits}f} ± {max(hi - mean, mean - lo):.{digits}f}" + (f" {WIDE}" if _wide(v) else "")


def markdown_table(summary: Sequence[dict[str, Any]], *, group_key: str = "group", metrics: Sequence[tuple[str, str]] = MAIN_METRICS,
                   order: Sequence[str] = ()) -> str:  # fmt: skip
    """One row per group × controller: crashed (the vehicle), errors (the software; a column only
    when there are any), then the metrics (mean ± 95 % half-width); under the table, a note when
    a row has fewer than :data:`FEW_FLIGHTS` flights or a cell's interval is wider than its mean."""
    show_errors = any(e.get("errors") for e in summary)
    head = (f"| {'case' if group_key == 'case' else 'group'} | controller | crashed |" + (" errors |" if show_errors else "")
            + " " + " | ".join(label for _, label in metrics) + " |")  # fmt: skip
    lines = [head, "|" + "---|" * (3 + show_errors + len(metrics))]
    rank = {c: i for i, c in enumerate(order)}
    names: list[Any] = []
    for e in summary:
        if e[group_key] not in names:
            names.append(e[group_key])
    for g in names:
        for e in sorted((e for e in summary if e[group_key] == g), key=lambda e: rank.get(e["controller"], 99)):
            n = e["flights"]
            crashed = e["crashes"] if "crashes" in e else round(e["crash_rate"] * n)
            errors = f" {e.get('errors', 0)}/{n} |" if show_errors else ""
            lines.append(f"| {g} | {e['controller']} | {crashed}/{n} |{errors} " + " | ".join(cell(e, k) for k, _ in metrics) + " |")
    return "\n".join(lines) + "\n" + small_sample_note(summary, metrics)


def small_sample_note(summary: Sequence[dict[str, Any]], metrics: Sequence[tuple[str, str]] = MAIN_METRICS) -> str:
    """The note under a table whose intervals rest on few flights ("" when none do)."""
    if not summary:
        return ""
    notes = []
    fewest = min(e["flights"] for e in summary)
    if fewest < FEW_FLIGHTS:
        notes.append(f"Only {fewest} flight{'s' if fewest != 1 else ''} per row{' (seeds)' if fewest > 1 else ''}: the 95 % intervals"
                     f" (Student t) are rough below {FEW_FLIGHTS}; fly more seeds before reading differences.")  # fmt: skip
    wide = sum(1 for e in summary for k, _ in metrics if e.get(k) is not None and _wide(e[k]))
    if wide:
        notes.append(f"{WIDE} {wide} cell{'s' if wide != 1 else ''}: the interval is wider than the mean itself.")
    return ("\n" + "\n".join(f"Note: {n}" for n in notes) + "\n") if notes else ""


def worst(rows: Sequence[dict[str, Any]], n: int) -> list[dict[str, Any]]:
    """The ``n`` worst rows: crashes and errors first, then the largest max position error (ties: unit order)."""
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
