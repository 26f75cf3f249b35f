"""``results.csv``: one row per flight, appended as each flight finishes, read back for resume.

CSV, not Parquet: a row is appended and flushed (and fsynced) the moment its flight finishes, so
a crash, a Ctrl-C or a killed driver loses nothing that finished, and the file is valid at every
moment (a Parquet file is unreadable until its footer is written, and appending means rewriting
row groups); it needs no dependency beyond the standard library; ``pandas.read_csv`` and every
spreadsheet read it directly. Vectors (the per-channel σ metrics) are JSON lists in their cell,
missing values are empty cells, booleans ``True``/``False``.

The columns are fixed when the campaign starts (the unit's identity, its status, every varied
field, then every metric of :func:`ground.logs.metrics.flight_metrics`), so a resumed campaign
appends rows of the same shape.
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from lab.campaign.spec import CampaignError

ID_COLUMNS = ("unit", "group", "controller", "seed_index", "seed", "status", "message", "wall_s", "sim_s")


def metric_columns() -> list[str]:
    """The metric names of :func:`~ground.logs.metrics.flight_metrics`, in its order (computed on a
    three-sample flight, so the columns follow the function)."""
    import numpy as np

    from ground.logs.metrics import flight_metrics

    n = 3
    z3 = np.zeros((n, 3))
    out = flight_metrics(np.arange(n) * 0.01, z3, z3, z3, z3, np.full((n, 4), 0.5), np.ones(n, bool), np.zeros(n, bool),
                         velocity_m_s=z3, target_yaw_rad=np.zeros(n), sigma=np.zeros((n, 4)))  # fmt: skip
    return list(out)


#: a swarm unit's own columns (lab.campaign.swarm_unit), before each vehicle's metrics.
SWARM_COLUMNS = ("vehicles", "crashed_vehicles", "min_separation_m", "contacts", "worst_vehicle")


def columns(varied: Sequence[str], sysids: Sequence[int] = ()) -> list[str]:
    """The results' columns: the unit's, the varied fields, the metrics; for a swarm (its vehicles'
    ``sysids``) the swarm's and each vehicle's metrics (``v2_iae_pos_m_s``)."""
    metrics = metric_columns()
    out = [*ID_COLUMNS, *varied, *(m for m in metrics if m not in varied)]
    if sysids:
        out += [*SWARM_COLUMNS, *(f"v{sid}_{m}" for sid in sysids for m in metrics)]
    return out


def _cell(v: Any) -> Any:
    if v is None:
        return ""
    if isinstance(v, float) and not math.isfinite(v):
        return "" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, (list, tuple)):
        return json.dumps([None if isinstance(x, float) and not math.isfinite(x) else x for x in v])
    return v


class ResultsWriter:
    """Appends rows to ``path`` (header first if the file is new), each flushed and fsynced."""

    def __init__(self, path: Path, cols: Sequence[str]) -> None:
        self.path = path
        self.cols = list(cols)
        new = not path.exists() or path.stat().st_size == 0
        if not new:
            with path.open(encoding="utf-8", newline="") as f:
                head = next(csv.reader(f), [])
            if head != self.cols:
                raise CampaignError(f"{path}: its columns are not this campaign's (another campaign, or another version): use another --out")
            _drop_partial_last_line(path)
        self._f = path.open("a", encoding="utf-8", newline="")
        self._w = csv.DictWriter(self._f, fieldnames=self.cols, extrasaction="ignore")
        if new:
            self._w.writeheader()
            self._sync()

    def _sync(self) -> None:
        self._f.flush()
        os.fsync(self._f.fileno())

    def write(self, row: dict[str, Any]) -> None:
        self._w.writerow({k: _cell(row.get(k)) for k in self.cols})
        self._sync()

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> ResultsWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _drop_partial_last_line(path: Path) -> None:
    """Cut a last line left without its newline by a process killed mid-write (appending would glue to it)."""
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        with path.open("r+b") as f:
            f.truncate(data.rfind(b"\n") + 1)


def _value(text: str) -> Any:
    if text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    if text[0] == "[":
        try:
            return json.loads(text)
        except ValueError:
            return text
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def read_rows(path: Path) -> list[dict[str, Any]]:
    """The rows of a results file, values typed back (numbers, booleans, lists, None for empty).
    A last line cut short by a process killed mid-write is dropped."""
    if not path.exists():
        return []
    with path.open(encoding="utf-8", newline="") as f:
        reader = csv.reader(f)
        head = next(reader, None)
        if head is None:
            return []
        rows = []
        for cells in reader:
            if len(cells) != len(head):
                continue
            row = {k: _value(v) for k, v in zip(head, cells)}
            if k_ok(row):
                rows.append(row)
    return rows


def k_ok(row: dict[str, Any]) -> bool:
    return isinstance(row.get("unit"), int) and isinstance(row.get("status"), str)


def finished_units(rows: Iterable[dict[str, Any]]) -> set[int]:
    return {int(r["unit"]) for r in rows}
