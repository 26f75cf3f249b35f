"""``smcpilot compare``: the robustness study: scenarios × controllers × seeds, in-process, one table.

Each flight is the flight core (:class:`fc.core.FlightCore`, the FC's own tick) on the simulator's
rigid-body plant (:func:`sim_bridge.build.plant_for`), as ``smcpilot run`` flies it: take-off to
3 m, then the case's fault, disturbance or model error, with sensor noise on (the seed decides the
noise and gust draws). Every flight is scored with :func:`ground.logs.metrics.flight_metrics`
(the same code ``smcpilot log summary`` uses; definitions in ``docs/metrics.md``) on the plant's
*true* state from 6 s on (after the take-off), so a sensor fault is scored by what the vehicle did,
not by what its faulty sensors said.

The flights are units of the campaign engine (:mod:`lab.campaign`): a local Dask cluster of
``--jobs`` worker processes, or a running scheduler (``--cluster``), the flight and its scoring
:func:`lab.campaign.flight.fly_unit`, the table's statistics :mod:`lab.campaign.summary`; a
flight's status is ``ok``, ``crashed``, ``diverged``, ``timed out`` or ``error``.

Outputs in ``--out`` (default ``out/compare``):

- ``results.csv``: one row per flight (case, controller, seed, status, every metric);
- ``summary.json`` and ``table.md``: per case × controller, the mean and 95 % confidence interval
  (Student t over the seeds) of each metric, and the crash rate;
- ``figures/``: box plots of the main metrics per case, and the worst flight's time series per case
  (position error and tilt of every controller);
- each case's scenario as ``scenarios/<case>.toml`` (``smcpilot run`` flies it; the plant-side
  model errors of ``mass+30`` and ``inertia+30`` are the one thing a scenario file cannot say).

The cases are those of the robustness study (:func:`study_cases`, docs/robustness.md); the controllers are the FC's laws
and the adaptive PID-SMC without its disturbance observer (the paper's law as printed).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from lab.campaign.engine import ClusterOptions, Engine
from lab.campaign.figures import until_crash
from lab.campaign.flight import Trace
from lab.campaign.flight import fly_unit as campaign_fly_unit
from lab.campaign.run import Progress, retrace
from lab.campaign.spec import Variant
from lab.campaign.summary import MAIN_METRICS, ci95, summarize
from lab.campaign.summary import markdown_table as campaign_table
from lab.campaign.units import Unit as CampaignUnit
from smcpilot.errors import ConfigError
from smcpilot.faults import FaultSpec
from smcpilot.plan import PlanStep
from smcpilot.scenario import EnvironmentSpec, Scenario
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams

#: the metrics the table reports, in order, with their labels (the campaign tables').
TABLE_METRICS = MAIN_METRICS


#: the controllers compared.
VARIANTS: tuple[Variant, ...] = (
    Variant("adaptive", "adaptive_pid_smc", (), "adaptive PID-SMC, disturbance observer at the input (FC default)"),
    Variant("known-bound", "pid_smc", (), "PID-SMC with the known bound chi (Theorem 1), same observer"),
    Variant("adaptive-paper", "adaptive_pid_smc", (("DOB_MODE", 0.0),), "adaptive PID-SMC without observer: the paper's nominal-model sigma"),
    Variant("cascade", "cascade_pid", (), "cascaded PID (angle P, rate PID)"),
    Variant("cascade+dob", "cascade_pid", (("DOB_MODE", 3.0),), "the same cascade with the PID-SMC's disturbance observer at its input"),
    Variant("se3", "se3_geometric", (), "geometric tracking control on SE(3) (Lee et al. 2010), whole stack, with integral terms"),
    Variant("indi", "indi", (), "incremental nonlinear dynamic inversion (Smeur et al. 2016)"),
)


@dataclass(frozen=True)
class Case:
    """One scenario of the study; ``plant_vehicle`` (if given) is what the simulator flies while the FC
    keeps the scenario's vehicle (a model error the FC is not told of)."""

    name: str
    description: str
    scenario: Scenario
    plant_vehicle: VehicleParams | None = None

    #: metrics from this time on (simulated s): after the take-off has settled.
    window_from_s: float = 6.0

    @property
    def fault_starts_s(self) -> tuple[float, ...]:
        """Starts of the faults that begin inside the scored window (recovery is timed from them;
        a fault on from the start, such as continuous gusts, has no recovery)."""
        return tuple(sorted(f.start_s for f in self.scenario.faults if f.start_s >= self.window_from_s))


def study_cases(duration_s: float = 20.0, t_event_s: float = 10.0) -> tuple[Case, ...]:
    """The study's cases: hover at 3 m (take-off at t = 0), the event at ``t_event_s``."""
    takeoff = PlanStep(0.0, "takeoff", alt_m=3.0)
    hover = (takeoff,)
    noisy = EnvironmentSpec(noise=True)

    def sc(name: str, description: str, *, plan=hover, env: EnvironmentSpec = noisy, faults: Sequence[FaultSpec] = ()) -> Scenario:
        return Scenario(name=name, description=description, duration_s=duration_s, plan=tuple(plan), environment=env,
                        faults=tuple(faults))  # fmt: skip

    t = t_event_s
    v = DEFAULT_VEHICLE
    step = (takeoff, PlanStep(t, "goto", north_m=4.0, east_m=0.0, alt_m=3.0))
    return (
        Case("motor30-hover", "motor 1 at 70 % thrust at hover", sc("motor30-hover", "motor 1 at 70 % at hover",
             faults=[FaultSpec("motor", start_s=t, motor=1, efficiency=0.7)])),
        Case("motor30-step", "motor 1 at 70 % in the middle of a 4 m step", sc("motor30-step", "motor 1 at 70 % mid-step",
             plan=step, faults=[FaultSpec("motor", start_s=t + 1.5, motor=1, efficiency=0.7)])),
        Case("wind-0.5", "0.5 N constant wind from the north", sc("wind-0.5", "0.5 N wind", env=replace(noisy, wind_force_ned_n=(-0.5, 0.0, 0.0)))),
        Case("wind-1.0", "1 N constant wind from the north", sc("wind-1.0", "1 N wind", env=replace(noisy, wind_force_ned_n=(-1.0, 0.0, 0.0)))),
        Case("gusts", "gusts: 0.5 N force and 0.01 N m torque std, 1 s", sc("gusts", "force and torque gusts",
             faults=[FaultSpec("gust", start_s=0.0, force_std_n=0.5, torque_std_n_m=0.01, tau_s=1.0)])),
        Case("mass+30", "plant 30 % heavier than the FC's model", sc("mass+30", "mass +30 % (plant only)"),
             plant_vehicle=replace(v, mass_kg=v.mass_kg * 1.3)),
        Case("inertia+30", "plant inertia 30 % above the FC's model", sc("inertia+30", "inertia +30 % (plant only)"),
             plant_vehicle=replace(v, ixx_kg_m2=v.ixx_kg_m2 * 1.3, iyy_kg_m2=v.iyy_kg_m2 * 1.3, izz_kg_m2=v.izz_kg_m2 * 1.3)),
        Case("gyro-bias", "gyro bias 0.05 rad/s on roll and pitch", sc("gyro-bias", "gyro bias",
             faults=[FaultSpec("sensor", start_s=t, sensor="gyro", mode="bias", value=(0.05, 0.05, 0.0))])),
        Case("pos-dropout", "position lost for 0.5 s", sc("pos-dropout", "0.5 s position dropout",
             faults=[FaultSpec("sensor", start_s=t, stop_s=t + 0.5, sensor="position", mode="dropout")])),
        Case("paper-dist", "the paper's sensor-failure disturbances", sc("paper-dist", "paper disturbances",
             env=replace(noisy, paper_disturbance=True))),
    )  # fmt: skip


# -- the flights: units of the campaign engine (lab.campaign) ------------------------------------------
def study_unit(case: Case, variant: Variant, seed: int, index: int = 0) -> CampaignUnit:
    """The campaign unit of one flight of the study: the case's scenario with the variant's law,
    parameters and the noise seed ``seed``, the case's plant (model errors), scored from the case's
    window on."""
    sc = case.scenario.with_changes(controller=variant.controller, params=variant.params, seed=seed)
    return CampaignUnit(index, case.name, variant.label, seed, sc, case.plant_vehicle, score_from_s=case.window_from_s)


#: the study's unit (kept name): ``Unit(case, variant, seed)``.
Unit = study_unit


def fly_unit(unit: CampaignUnit) -> tuple[dict[str, Any], Trace]:
    """Fly one unit in this process: (its campaign result row, its trace)."""
    row, trace = campaign_fly_unit(unit, trace=True)
    assert trace is not None or row["status"] == "error", row
    return row, trace if trace is not None else Trace()


def _study_row(row: dict[str, Any]) -> dict[str, Any]:
    """A campaign row as the study's results.csv writes it: case, controller, seed, status, ..."""
    skip = {"unit", "group", "controller", "seed_index", "seed"}
    return {"case": row["group"], "controller": row["controller"], "seed": row["seed_index"], **{k: v for k, v in row.items() if k not in skip}}


# -- the study ----------------------------------------------------------------------------------------
@dataclass
class StudyResult:
    rows: list[dict[str, Any]]
    #: the worst flight (largest max position error, crashes first) per (case, controller).
    worst: dict[tuple[str, str], tuple[dict[str, Any], Trace]]


def _badness(row: dict[str, Any]) -> tuple[int, float]:
    v = row.get("max_pos_err_m")
    return (1 if row.get("crashed") else 0, float(v) if isinstance(v, (int, float)) and math.isfinite(v) else math.inf)


def run_study(
    cases: Sequence[Case],
    variants: Sequence[Variant],
    seeds: int,
    *,
    jobs: int = 1,
    cluster: ClusterOptions | None = None,
    quiet: bool = True,
) -> StudyResult:
    """Fly every case × variant × seed (seeds 0 .. ``seeds``-1) on the campaign engine (a local
    cluster of ``jobs`` workers, or ``cluster``); the result does not depend on the workers."""
    units = [study_unit(c, v, s, i) for i, (c, v, s) in enumerate((c, v, s) for c in cases for v in variants for s in range(seeds))]
    rows: list[dict[str, Any] | None] = [None] * len(units)
    progress = Progress(len(units), label="compare", quiet=quiet)

    def take(unit: CampaignUnit, row: dict[str, Any]) -> None:
        rows[unit.index] = _study_row(row)
        progress.update(row)

    try:
        with Engine(cluster or ClusterOptions(workers=jobs), tag="compare") as engine:
            engine.run(units, take)
            done = [r for r in rows if r is not None]
            worst_of: dict[tuple[str, str], int] = {}
            for i, r in enumerate(rows):
                if r is None:
                    continue
                key = (r["case"], r["controller"])
                if key not in worst_of or _badness(r) > _badness(rows[worst_of[key]] or {}):
                    worst_of[key] = i
            picked = list(worst_of.items())
            traces = retrace(engine, [units[i] for _, i in picked])
    finally:
        progress.close()
    worst = {key: (rows[i] or {}, tr if tr is not None else Trace()) for (key, i), tr in zip(picked, traces)}
    return StudyResult(done, worst)


_ci95 = ci95


def summarize_study(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per case × controller: crash rate and the mean/95 % CI of every table metric."""
    return summarize(rows, group_key="case", metrics=TABLE_METRICS)


def markdown_table(summary: Sequence[dict[str, Any]], variants: Sequence[Variant]) -> str:
    """One row per case × controller: crashes, then the table metrics (mean ± 95 % CI half-width)."""
    return campaign_table(summary, group_key="case", metrics=TABLE_METRICS, order=[v.label for v in variants])


# -- files and figures --------------------------------------------------------------------------------
def write_outputs(result: StudyResult, cases: Sequence[Case], variants: Sequence[Variant], out: Path, *, figures: bool = True) -> dict[str, Path]:
    out.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    keys: list[str] = []
    for r in result.rows:
        for k in r:
            if k not in keys:
                keys.append(k)
    paths["results"] = out / "results.csv"
    with paths["results"].open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in result.rows:
            w.writerow({k: _csv_value(r.get(k)) for k in keys})
    summary = summarize_study(result.rows)
    paths["summary"] = out / "summary.json"
    paths["summary"].write_text(json.dumps({"variants": [v.__dict__ for v in variants], "cases": [
        {"name": c.name, "description": c.description} for c in cases], "groups": summary}, indent=2, default=str) + "\n", encoding="utf-8")
    paths["table"] = out / "table.md"
    paths["table"].write_text(markdown_table(summary, variants), encoding="utf-8")
    sdir = out / "scenarios"
    sdir.mkdir(exist_ok=True)
    for c in cases:
        c.scenario.save(sdir / f"{c.name}.toml")
    if figures:
        paths["figures"] = write_figures(result, cases, variants, out / "figures")
    return paths


def _csv_value(v: Any) -> Any:
    if isinstance(v, (list, tuple)):
        return json.dumps(list(v))
    return "" if v is None else v


def write_figures(result: StudyResult, cases: Sequence[Case], variants: Sequence[Variant], fig_dir: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig_dir.mkdir(parents=True, exist_ok=True)
    labels = [v.label for v in variants]
    for key, label in (("max_tilt_deg", "max tilt (°)"), ("max_pos_err_m", "max position error (m)"), ("iae_pos_m_s", "IAE position (m·s)")):
        ncol = min(5, len(cases))
        nrow = (len(cases) + ncol - 1) // ncol
        fig, axes = plt.subplots(nrow, ncol, figsize=(2.6 * ncol, 3.2 * nrow), squeeze=False)
        flat = [ax for row_axes in axes for ax in row_axes]
        for ax in flat[len(cases):]:
            ax.set_visible(False)
        for ax, c in zip(flat, cases):
            data = [[float(r[key]) for r in result.rows if r["case"] == c.name and r["controller"] == lab
                     and isinstance(r.get(key), (int, float)) and math.isfinite(r[key])] for lab in labels]  # fmt: skip
            ax.boxplot(data, tick_labels=labels, showfliers=True)
            ax.set_title(c.name, fontsize=9)
            ax.tick_params(axis="x", labelrotation=60, labelsize=7)
            ax.tick_params(axis="y", labelsize=7)
            if max((max(d) for d in data if d), default=0.0) > 20.0 * max(min((min(d) for d in data if d), default=1.0), 1e-9):
                ax.set_yscale("log")  # a crashed controller next to ones that held: both visible
        fig.suptitle(f"{label} per case and controller (each box: the seeds)", fontsize=10)
        fig.tight_layout()
        fig.savefig(fig_dir / f"box_{key}.png", dpi=110)
        plt.close(fig)
    for c in cases:
        fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 5.3), sharex=True)
        # Widest first, narrower and dashed on top: controllers that fly alike stay visible.
        styles: list[dict[str, Any]] = [{"lw": 2.6, "alpha": 0.6}, {"lw": 1.3, "ls": (0, (4, 2))}, {"lw": 1.0}, {"lw": 1.0, "ls": (0, (1, 1))}]
        for k, lab in enumerate(labels):
            w = result.worst.get((c.name, lab))
            if w is None:
                continue
            row, tr = w
            style = styles[k % len(styles)]
            t, err, tilt, t_crash = until_crash(row, tr)  # a crashed flight ends at its crash (×)
            (line,) = a1.plot(t, err, label=f"{lab} (seed {row['seed']}{', crashed' if t_crash is not None else ''})", **style)
            a2.plot(t, tilt, color=line.get_color(), **style)
            if t_crash is not None and t:
                a1.plot([t[-1]], [err[-1]], "x", color=line.get_color(), ms=8, mew=2)
                a2.plot([t[-1]], [tilt[-1]], "x", color=line.get_color(), ms=8, mew=2)
        for t_f in c.fault_starts_s:
            for ax in (a1, a2):
                ax.axvline(t_f, color="k", ls=":", lw=0.8)
        a1.set_ylabel("position error (m)")
        a1.set_yscale("symlog", linthresh=0.1)
        a1.set_ylim(bottom=0.0)  # a distance: nothing below zero
        a2.set_ylabel("tilt (°)")
        a2.set_xlabel("t (s)")
        a1.set_title(f"{c.name}: worst flight per controller — {c.description}", fontsize=9)
        a1.legend(fontsize=7)
        fig.text(0.5, 0.005, "Widest line first, narrower and dashed ones on top: a line that does not show lies under another.",
                 ha="center", va="bottom", fontsize=7, color="0.3")  # fmt: skip
        fig.tight_layout(rect=(0, 0.03, 1, 1))
        fig.savefig(fig_dir / f"worst_{c.name}.png", dpi=110)
        plt.close(fig)
    return fig_dir


# -- command line -------------------------------------------------------------------------------------
def add_arguments(p: argparse.ArgumentParser) -> None:
    names = [c.name for c in study_cases()]
    p.add_argument("--cases", default="all", help=f"comma-separated cases, or all (default): {', '.join(names)}")
    p.add_argument("--controllers", default="all",
                   help="comma-separated controllers, or all (default): " + ", ".join(f"{v.label} ({v.description})" for v in VARIANTS)
                   + "; or any law by name or reference (sign_smc, an installed plug-in, path/to/law.py:NAME; `smcpilot laws`)")
    p.add_argument("--seeds", type=int, default=5, help="seeds per case and controller (default 5): noise and gust draws")
    p.add_argument("--duration", type=float, default=20.0, metavar="S", help="simulated seconds per flight (default 20; the event at 10 s)")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                   help="flights in parallel: worker processes of the local Dask cluster (default: the cores)")
    p.add_argument("--cluster", metavar="tcp://HOST:PORT", help="fly on this running Dask scheduler instead (docs/campaigns.md)")
    p.add_argument("--out", type=Path, default=Path("out/compare"), help="output directory (default out/compare)")
    p.add_argument("--no-plots", action="store_true", help="skip the figures")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.add_argument("--loss-limit", action="store_true",
                   help="instead of the cases: bisect, per controller, the largest loss of motor 1's thrust survived at hover and"
                   " mid-step by every seed, beside the physical limit of a trim (lab/loss_limit.py); writes loss_limits.md")  # fmt: skip


def _pick(spec: str, items: Sequence[Any], name: Callable[[Any], str], what: str) -> list[Any]:
    if spec == "all":
        return list(items)
    known = {name(i): i for i in items}
    out = []
    for s in (x.strip() for x in spec.split(",") if x.strip()):
        if s not in known:
            raise ConfigError(f"unknown {what} {s!r}; choose from: {', '.join(known)}")
        out.append(known[s])
    if not out:
        raise ConfigError(f"no {what} given")
    return out


def _variants(spec: str) -> list[Variant]:
    """The study's variants by label, and any other law by name or reference (a plug-in, a file)."""
    from fc.control import registry
    from smcpilot.lawref import law_reference_problem, normalise_reference

    known = {v.label for v in VARIANTS}
    names = [x.strip() for x in spec.split(",") if x.strip()] if spec != "all" else []
    out: list[Variant] = []
    for name in names or ["all"]:
        if name == "all" or name in known:
            out.extend(_pick(name, VARIANTS, lambda v: v.label, "controller"))
        elif not law_reference_problem(name):
            ref = normalise_reference(name)
            law = registry.resolve(ref)
            out.append(Variant(law.name, ref, (), law.description))
        else:
            raise ConfigError(f"unknown controller {name!r}; choose from: {', '.join(known)}, or a law (`smcpilot laws`)")
    labels = [v.label for v in out]
    if len(set(labels)) != len(labels):
        raise ConfigError(f"a controller is named twice in --controllers: {spec}")
    return out


def _loss_limit_main(args: argparse.Namespace, variants: Sequence[Variant]) -> int:
    import json

    from lab.loss_limit import bisect_loss_limits, limits_table, trim_efficiency_min

    tol = 0.025
    cluster = ClusterOptions(workers=None if args.cluster else args.jobs, address=args.cluster)
    echo = None if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    if echo is not None:
        echo(f"compare --loss-limit: {len(variants)} controllers x 2 conditions x {args.seeds} seeds per round, to {tol:.1%}")
    brackets = bisect_loss_limits(variants, seeds=args.seeds, tol=tol, duration_s=args.duration, cluster=cluster, progress=echo)
    table = limits_table(brackets, DEFAULT_VEHICLE, args.seeds, tol)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "loss_limits.md").write_text(table, encoding="utf-8")
    data = {
        "seeds": args.seeds, "tolerance": tol,
        "physical_limit": {"heading_held": 1.0 - trim_efficiency_min(DEFAULT_VEHICLE), "heading_free": 1.0 - trim_efficiency_min(DEFAULT_VEHICLE, yaw_held=False)},
        "survived": [{"controller": b.variant.label, "condition": b.condition, "survived": b.lo, "not_survived": b.hi, "why": b.why} for b in brackets],
    }  # fmt: skip
    (args.out / "loss_limits.json").write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    print(table, end="")
    print(f"written: {args.out / 'loss_limits.md'}  {args.out / 'loss_limits.json'}")
    return 0


def main(args: argparse.Namespace) -> int:
    if args.seeds < 1 or args.jobs < 1:
        raise ConfigError("--seeds and --jobs must be >= 1")
    if not (math.isfinite(args.duration) and args.duration > 12.0):
        raise ConfigError(f"--duration must be a finite number of seconds > 12 (the event is at 10 s), got {args.duration}")
    variants = _variants(args.controllers)
    if args.loss_limit:
        return _loss_limit_main(args, variants)
    cases = _pick(args.cases, study_cases(args.duration), lambda c: c.name, "case")
    total = len(cases) * len(variants) * args.seeds
    cluster = ClusterOptions(workers=None if args.cluster else args.jobs, address=args.cluster)
    if not args.quiet:
        print(f"compare: {total} flights ({len(cases)} cases × {len(variants)} controllers × {args.seeds} seeds),"
              f" {'on ' + args.cluster if args.cluster else f'{args.jobs} at a time'}", file=sys.stderr)  # fmt: skip
    result = run_study(cases, variants, args.seeds, cluster=cluster, quiet=args.quiet)
    paths = write_outputs(result, cases, variants, args.out, figures=not args.no_plots)
    print(paths["table"].read_text(encoding="utf-8"), end="")
    print(f"results: {paths['results']}  summary: {paths['summary']}  table: {paths['table']}"
          + (f"  figures: {paths['figures']}/" if "figures" in paths else ""))  # fmt: skip
    return 0
