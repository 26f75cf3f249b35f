"""Running a campaign into a results directory, resuming it, and replaying one of its units.

The directory (``--out DIR``):

- ``campaign.json``: the campaign as flown (its document with the base scenario inline, the
  mode, the unit count and a fingerprint of every unit), so ``--resume`` can refuse a different
  campaign and ``replay`` can rebuild any unit without the original files;
- ``results.csv``: one row per flight, appended as each finishes (:mod:`lab.campaign.results`);
- ``summary.json``, ``table.md``: per controller × scenario group (:mod:`lab.campaign.summary`);
- ``worst.md``: the N worst runs, each with the command that replays it;
- ``figures/``: ECDF and box plots, and the worst runs' time series;
- ``replay/unit-N/``: what ``smcpilot campaign replay DIR N`` wrote (``.tlog``, scenario, plots).
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lab.campaign.engine import ClusterOptions, Engine
from lab.campaign.flight import Trace, fly_unit, is_crash, is_error
from lab.campaign.results import ResultsWriter, columns, finished_units, read_rows
from lab.campaign.spec import CampaignError, CampaignSpec, parse_campaign
from lab.campaign.summary import markdown_table, summarize, worst, worst_markdown
from lab.campaign.units import Unit, expand

__all__ = ["CampaignRun", "run_campaign", "replay_unit", "fingerprint", "Progress"]


def fingerprint(units: Sequence[Unit]) -> str:
    """A hash of every unit's flight (scenario, plant vehicle, values, scoring): equal campaigns,
    equal fingerprints."""
    h = hashlib.sha256()
    for u in units:
        h.update(json.dumps([u.index, u.group, u.controller, u.seed_index, u.scenario.to_mapping(),
                             None if u.plant_vehicle is None else u.plant_vehicle.to_dict(), [list(v) for v in u.values],
                             u.score_from_s, u.sitl], sort_keys=True, default=str).encode())  # fmt: skip
    return h.hexdigest()[:16]


class Progress:
    """One live line on a terminal (tqdm): done / total, crashed (the vehicle), errors (the
    software: an exception or the time limit), flights per second, ETA; without a terminal (a log
    file, CI), the same as a plain line every ``every_s`` seconds and at the end."""

    def __init__(self, total: int, done: int = 0, *, label: str = "campaign", quiet: bool = False, every_s: float = 10.0) -> None:
        self.crashed = 0
        self.errors = 0
        self.total, self.done, self.start_done = total, done, done
        self.label, self.quiet, self.every_s = label, quiet, every_s
        self.t0 = self.last = time.perf_counter()
        self.bar: Any = None
        if not quiet and sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=done, desc=label, unit="flight", file=sys.stderr, dynamic_ncols=True, smoothing=0.1)

    def update(self, row: dict[str, Any]) -> None:
        self.crashed += is_crash(row) and not is_error(row)
        self.errors += is_error(row)
        self.done += 1
        if self.bar is not None:
            self.bar.set_postfix_str(self.outcomes(), refresh=False)
            self.bar.update(1)
        elif not self.quiet:
            now = time.perf_counter()
            if now - self.last >= self.every_s or self.done == self.total:
                self.last = now
                print(self.line(now), file=sys.stderr, flush=True)

    def line(self, now: float) -> str:
        rate = (self.done - self.start_done) / (now - self.t0) if now > self.t0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else math.inf
        return (f"{self.label}: {self.done}/{self.total} flights, {self.outcomes()}, {rate:.2f} flights/s, "
                + (f"ETA {eta:.0f} s" if math.isfinite(eta) else "ETA –"))  # fmt: skip

    def outcomes(self) -> str:
        """``N crashed, M errors``: the vehicle's end and the software's, never one word for both."""
        return f"{self.crashed} crashed, {self.errors} error{'' if self.errors == 1 else 's'}"

    def note(self, text: str) -> None:
        if self.quiet:
            return
        if self.bar is not None:
            self.bar.write(text, file=sys.stderr)
        else:
            print(text, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


@dataclass
class CampaignRun:
    out: Path
    units: list[Unit]
    rows: list[dict[str, Any]]
    flown: int
    skipped: int
    paths: dict[str, Path]


def _record(spec: CampaignSpec, units: Sequence[Unit], sitl: bool) -> dict[str, Any]:
    doc = dict(spec.doc)
    doc["scenario"] = spec.base.to_mapping()
    doc.pop("duration_s", None)  # already in the inline scenario
    return {"name": spec.name, "description": spec.description, "source": spec.source, "sitl": sitl, "units": len(units),
            "fingerprint": fingerprint(units), "document": doc}  # fmt: skip


def load_recorded(out: Path) -> tuple[CampaignSpec, dict[str, Any]]:
    """The campaign of a results directory (from its ``campaign.json``)."""
    path = out / "campaign.json"
    try:
        rec = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CampaignError(f"{out} holds no campaign (no campaign.json): give the --out directory of `smcpilot campaign run`") from None
    except (OSError, ValueError) as exc:
        raise CampaignError(f"cannot read {path}: {exc}") from None
    return parse_campaign(rec["document"], source=str(path)), rec


def run_campaign(
    spec: CampaignSpec,
    out: Path,
    cluster: ClusterOptions,
    *,
    sitl: bool = False,
    resume: bool = False,
    worst_n: int = 5,
    figures: bool = True,
    quiet: bool = False,
    echo: Callable[[str], None] | None = None,
    task: Any = None,
) -> CampaignRun:
    """Fly ``spec`` into ``out`` (see the module docstring); with ``resume``, only the units
    ``results.csv`` does not hold yet. Every check (spec, units, results directory, cluster) is
    done before the first unit is submitted."""
    say = echo or (lambda s: None)
    units = expand(spec, sitl=sitl)
    record = _record(spec, units, sitl)
    results_path = out / "results.csv"
    sysids = [v.sysid for v in units[0].scenario.fleet()] if units and units[0].scenario.swarm is not None else []
    cols = columns([c for c, _ in units[0].values] if units else [], sysids)
    done_units: set[int] = set()
    existing = read_rows(results_path)
    if not existing and results_path.exists():
        results_path.unlink()  # a header and no finished flight: nothing to keep
    if existing:
        if not resume:
            raise CampaignError(f"{out} already holds results: add --resume to fly only the missing units, or use another --out")
        try:
            old = json.loads((out / "campaign.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            raise CampaignError(f"{out}: results.csv without a readable campaign.json: use another --out") from None
        if old.get("fingerprint") != record["fingerprint"]:
            raise CampaignError(f"{out} holds another campaign (its units differ from this file's): use another --out")
        done_units = finished_units(existing)
    todo = [u for u in units if u.index not in done_units]
    engine = Engine(cluster, task=task, tag=spec.name)
    with engine:  # an unreachable scheduler fails here, before anything is written or flown
        if not cluster.local:
            engine.wait_for_workers(1)
        out.mkdir(parents=True, exist_ok=True)
        (out / "campaign.json").write_text(json.dumps(record, indent=2, default=str) + "\n", encoding="utf-8")
        dash = engine.dashboard
        say(f"campaign {spec.name}: {len(units)} flights ({spec.n_groups} groups × {len(spec.variants)} controllers × {spec.seeds} seeds),"
            f" {'SITL processes' if sitl else 'in-process'} on the {engine.where}"
            + (f"; {len(done_units)} already done, {len(todo)} to fly" if done_units else "")
            + (f"\ndashboard: {dash}" if dash else ""))  # fmt: skip
        progress = Progress(len(units), len(done_units), label=spec.name, quiet=quiet)
        t0 = time.perf_counter()
        try:
            with ResultsWriter(results_path, cols) as writer:

                def take(unit: Unit, row: dict[str, Any]) -> None:
                    writer.write(row)
                    progress.update(row)

                engine.run(todo, take)
        finally:
            progress.close()
        elapsed = time.perf_counter() - t0
        rows = sorted(read_rows(results_path), key=lambda r: r["unit"])
        paths = write_outputs(spec, units, rows, out, engine=engine if figures else None, worst_n=worst_n)
    if todo:
        say(f"flew {len(todo)} flights in {elapsed:.1f} s ({len(todo) / elapsed if elapsed > 0 else math.nan:.2f} flights/s)")
    return CampaignRun(out, units, rows, len(todo), len(done_units), paths)


def retrace(engine: Engine | None, units: Sequence[Unit]) -> list[Trace | None]:
    """The time series of ``units`` (flown again on the cluster, or here without one)."""
    if engine is None:
        return _traced(units)
    parts = engine.batches(units)
    futs = engine.client.map(_traced, parts, key=[f"{engine.tag}-trace-{p[0].index}-{len(p)}" for p in parts], pure=False)
    return [t for part in engine.client.gather(futs) for t in part]


def _traced(units: Sequence[Unit]) -> list[Trace | None]:
    return [fly_unit(u, trace=True)[1] for u in units]


def write_outputs(spec: CampaignSpec, units: Sequence[Unit], rows: Sequence[dict[str, Any]], out: Path, *, engine: Engine | None,
                  worst_n: int) -> dict[str, Path]:  # fmt: skip
    """summary.json, table.md, worst.md and (with an engine) the figures."""
    paths: dict[str, Path] = {"results": out / "results.csv"}
    summary = summarize(rows)
    paths["summary"] = out / "summary.json"
    paths["summary"].write_text(json.dumps({"campaign": spec.name, "flights": len(rows), "groups": summary}, indent=2, default=str) + "\n",
                                encoding="utf-8")  # fmt: skip
    order = [v.label for v in spec.variants]
    paths["table"] = out / "table.md"
    paths["table"].write_text(markdown_table(summary, order=order), encoding="utf-8")
    bad = worst(rows, worst_n)
    paths["worst"] = out / "worst.md"
    paths["worst"].write_text(f"# The {len(bad)} worst runs of {spec.name}\n\n" + worst_markdown(bad, str(out)), encoding="utf-8")
    if engine is not None and rows:
        from lab.campaign.figures import write_distribution_figures, write_worst_figure

        fig_dir = out / "figures"
        write_distribution_figures(rows, fig_dir, title=spec.name)
        by_index = {u.index: u for u in units}
        traced = [by_index[r["unit"]] for r in bad if r["unit"] in by_index]
        traces = retrace(engine, traced)
        pairs = [(r, t) for r, t in zip(bad, traces) if t is not None and t.t_s]
        if pairs:
            write_worst_figure(pairs, fig_dir / "worst_runs.png", title=f"{spec.name}: the {len(pairs)} worst runs", score_from_s=spec.score_from_s)
        paths["figures"] = fig_dir
    return paths


def replay_unit(out: Path, index: int, *, echo: Callable[[str], None] | None = None) -> tuple[dict[str, Any], Path, dict[str, Any] | None]:
    """Fly unit ``index`` of the campaign in ``out`` again, exactly, with its ``.tlog``, into
    ``out/replay/unit-N/``: (the new row, the tlog, the recorded row or None)."""
    spec, rec = load_recorded(out)
    units = expand(spec, sitl=bool(rec.get("sitl")))
    if not 0 <= index < len(units):
        raise CampaignError(f"{out}: no unit {index} (the campaign has units 0 to {len(units) - 1})")
    unit = units[index]
    if fingerprint(units) != rec.get("fingerprint"):
        raise CampaignError(f"{out}: the units rebuilt from campaign.json differ from those flown (another smcpilot version?)")
    udir = out / "replay" / f"unit-{index}"
    udir.mkdir(parents=True, exist_ok=True)
    unit.scenario.save(udir / f"unit-{index}.scenario.toml")
    if unit.plant_vehicle is not None:
        (udir / "plant-vehicle.toml").write_text(
            "# the simulated vehicle of this unit (the FC flies the scenario's): `smcpilot run` cannot say this; replay can\n"
            + "\n".join(f"{k} = {v!r}" for k, v in unit.plant_vehicle.to_dict().items()) + "\n", encoding="utf-8")  # fmt: skip
    tlog = udir / f"unit-{index}.tlog"
    row, _ = fly_unit(unit, tlog=tlog)
    recorded = next((r for r in read_rows(out / "results.csv") if r["unit"] == index), None)
    return row, tlog, recorded


def same_result(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Two rows of one unit agree on everything but the wall time (as CSV would write them)."""
    from lab.campaign.results import _cell, _value

    keys = (set(a) | set(b)) - {"wall_s"}
    return all(_value(str(_cell(a.get(k)))) == _value(str(_cell(b.get(k)))) for k in keys)
