"""A campaign unit that is a swarm (its scenario has a ``[swarm]`` table): K vehicles, one row.

The unit flies in-process on K flight cores (:func:`lab.swarm_run.fly_swarm_in_process`) or, with
``sitl``, as the swarm's processes (:func:`lab.swarm_run.fly_swarm_sitl`), into a temporary
directory (or beside the unit's ``.tlog``: ``NAME-vN.tlog``). Each vehicle is scored from its own
log with :func:`ground.logs.summary.log_metrics` (the FC's view, as a SITL unit is scored). The
row holds:

- every vehicle's metrics, prefixed with its system id (``v2_iae_pos_m_s``, ``v2_crashed``, ...);
- the swarm's: ``vehicles``, ``crashed_vehicles``, ``min_separation_m``, ``contacts``;
- the unit's own metric columns, those of its **worst vehicle** (a crashed one first, then the
  largest position IAE; its system id in ``worst_vehicle``), so the campaign's summary, figures
  and worst-runs list read a swarm unit as they read one flight.

A swarm unit takes no ``plant.*`` variation (those change one plant's vehicle): its row says so.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path
from typing import Any

from lab.campaign.units import Unit

#: the unit-level metric the worst vehicle is chosen by (after a crash).
WORST_BY = "iae_pos_m_s"


def fly_swarm_unit(unit: Unit, row: dict[str, Any], tlog: Path | None) -> str:
    """Fly ``unit``'s swarm, fill ``row``; the flight's status ("ok", "timed out", ...)."""
    from ground.logs import load_log
    from ground.logs.summary import log_metrics
    from lab.swarm_run import fly_swarm_in_process, fly_swarm_sitl

    if unit.plant_vehicle is not None:
        row["message"] = "a swarm unit takes no plant.* variation (it changes one plant's vehicle)"
        return "error"
    with tempfile.TemporaryDirectory(prefix="smcpilot-swarm-unit-") as tmp:
        path = tlog if tlog is not None else Path(tmp) / "unit.tlog"
        path.parent.mkdir(parents=True, exist_ok=True)
        deadline = time.perf_counter() + unit.timeout_s
        if unit.sitl:
            result = fly_swarm_sitl(unit.scenario, path)
        else:
            result = fly_swarm_in_process(unit.scenario, path, stop=lambda: time.perf_counter() > deadline)
        status = result.status
        row["message"] = next((r.message for r in result.vehicles if r.message), "")
        row["sim_s"] = max((r.sim_s for r in result.vehicles), default=0.0)
        per: dict[int, dict[str, Any]] = {}
        for sid, r in zip(result.sysids, result.vehicles):
            if r.tlog.exists() and r.tlog.stat().st_size > 0:
                m = log_metrics(load_log(r.tlog))
                if m is not None:
                    per[sid] = m
    prox = result.proximity or {}
    row["vehicles"] = len(result.sysids)
    row["min_separation_m"] = prox.get("min_separation_m")
    row["contacts"] = len(prox.get("contacts") or [])
    row["crashed_vehicles"] = sum(1 for m in per.values() if m.get("crashed"))
    for sid, m in per.items():
        row.update({f"v{sid}_{k}": v for k, v in m.items() if not isinstance(v, (list, dict))})
    if per:
        worst = max(per, key=lambda sid: (bool(per[sid].get("crashed")), _num(per[sid].get(WORST_BY))))
        row.update(per[worst])
        row["worst_vehicle"] = worst
    return status


def _num(v: Any) -> float:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else -math.inf
