"""``smcpilot tune TUNE.toml --out DIR``: gain tuning with Optuna, trials flown on the campaign engine.

A tuning file is a campaign file (:mod:`lab.campaign.spec`: base scenario, controllers, seeds,
grids and distributions: the scenario set every trial flies) plus::

    trials = 40                   # trials to finish (complete or failed), resumed ones included
    parallel = 2                  # trials in flight at once (default: enough to keep every worker busy)
    sampler = "tpe"               # tpe (default) or random; seeded with the campaign seed
    baseline = true               # trial 0 flies the scenario's own gains (the study starts from them)

    [objective]
    metric = "iae_pos_m_s"        # any metric of results.csv (docs/metrics.md)
    statistic = "mean"            # mean or max over the trial's flights
    failure_penalty = 100.0       # added per flight not ok: crashed, diverged, timed out or error

    [[gain]]                      # the FC parameters tuned, with their ranges
    name = "PSC_POS_KP"
    low = 0.3
    high = 6.0
    log = true                    # sample on a log scale

Ask-and-tell in this process: each trial's flights are submitted to the cluster as ordinary
campaign units (the gains override every controller's), and the trial is told its objective once
all have come back, so trials run in parallel on the same workers. The study lives in
``DIR/study.journal`` (Optuna's journal file): ``--resume`` continues it after a crash or Ctrl-C,
marking trials a killed or crashed process left RUNNING as failed. With ``parallel`` = 1 a study is reproducible (the
sampler is seeded); in parallel, which trial the sampler sees first depends on finishing order.

Outputs: ``results.csv`` (every flight, with its trial and gains), ``trials.csv``, ``best.parm``
(the best gains as ``NAME VALUE`` lines the FC loads: ``python -m fc --param-file``), ``best.toml`` (a
``[fc] params`` fragment a scenario accepts), ``history.png`` (the optimisation history).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lab.campaign.spec import CampaignError, CampaignSpec, did_you_mean, parse_campaign
from smcpilot.tomlfile import read_toml

_TUNE_KEYS = {"trials", "parallel", "sampler", "baseline", "objective", "gain"}
_OBJ_KEYS = {"metric", "statistic", "failure_penalty"}
SAMPLERS = ("tpe", "random")


@dataclass(frozen=True)
class Gain:
    """One tuned FC parameter and its range."""

    name: str
    low: float
    high: float
    log: bool = False


@dataclass(frozen=True)
class Objective:
    metric: str = "iae_pos_m_s"
    statistic: str = "mean"
    failure_penalty: float = 100.0

    def value(self, rows: Sequence[Mapping[str, Any]]) -> tuple[float, int]:
        """(objective, flights not ok) of one trial's rows: the statistic of the metric over the
        flights that have it, plus the penalty per flight not ok (crashed, diverged, timed out, error)."""
        failures = sum(r.get("status") != "ok" for r in rows)
        vals = [float(r[self.metric]) for r in rows if r.get("status") == "ok" and isinstance(r.get(self.metric), (int, float))
                and not isinstance(r.get(self.metric), bool) and math.isfinite(r[self.metric])]  # fmt: skip
        base = (max(vals) if self.statistic == "max" else sum(vals) / len(vals)) if vals else 0.0
        return base + self.failure_penalty * failures, failures


@dataclass(frozen=True)
class TuneSpec:
    campaign: CampaignSpec
    gains: tuple[Gain, ...]
    objective: Objective
    trials: int = 20
    parallel: int | None = None
    sampler: str = "tpe"
    baseline: bool = True

    @property
    def name(self) -> str:
        return self.campaign.name


def _num(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise CampaignError(f"{where} must be a finite number, got {v!r}")
    return float(v)


def parse_tune(doc: Mapping[str, Any], *, source: str = "tune", base_dir: Path | None = None) -> TuneSpec:
    """A :class:`TuneSpec` of a parsed tuning document (errors name ``source`` and the key)."""
    from fc.params import param_table
    from lab.campaign.results import metric_columns

    campaign = parse_campaign({k: v for k, v in doc.items() if k not in _TUNE_KEYS}, source=source, base_dir=base_dir)
    trials = doc.get("trials", 20)
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
        raise CampaignError(f"{source}: trials must be a whole number >= 1, got {trials!r}")
    parallel = doc.get("parallel")
    if parallel is not None and (isinstance(parallel, bool) or not isinstance(parallel, int) or parallel < 1):
        raise CampaignError(f"{source}: parallel must be a whole number >= 1, got {parallel!r}")
    sampler = doc.get("sampler", "tpe")
    if sampler not in SAMPLERS:
        raise CampaignError(f"{source}: sampler must be one of {', '.join(SAMPLERS)}, got {sampler!r}")
    baseline = doc.get("baseline", True)
    if not isinstance(baseline, bool):
        raise CampaignError(f"{source}: baseline must be true or false, got {baseline!r}")
    obj = doc.get("objective", {})
    if not isinstance(obj, dict):
        raise CampaignError(f"{source}: [objective] must be a table")
    unknown = sorted(set(obj) - _OBJ_KEYS)
    if unknown:
        raise CampaignError(f"{source}: objective: unknown key {unknown[0]!r}{did_you_mean(unknown[0], sorted(_OBJ_KEYS))}")
    metrics = [m for m in metric_columns() if m not in ("samples",)]
    metric = obj.get("metric", "iae_pos_m_s")
    if metric not in metrics:
        raise CampaignError(f"{source}: objective.metric: unknown metric {metric!r}{did_you_mean(str(metric), metrics)}")
    statistic = obj.get("statistic", "mean")
    if statistic not in ("mean", "max"):
        raise CampaignError(f"{source}: objective.statistic must be mean or max, got {statistic!r}")
    penalty = _num(obj.get("failure_penalty", 100.0), f"{source}: objective.failure_penalty")
    if penalty < 0:
        raise CampaignError(f"{source}: objective.failure_penalty must be >= 0, got {penalty:g}")
    tables = doc.get("gain")
    if not isinstance(tables, list) or not tables:
        raise CampaignError(f"{source}: no [[gain]] tables: name the FC parameters to tune and their ranges")
    gains = []
    for i, t in enumerate(tables, start=1):
        where = f"{source}: gain[{i}]"
        if not isinstance(t, dict):
            raise CampaignError(f"{where} must be a table")
        unknown = sorted(set(t) - {"name", "low", "high", "log"})
        if unknown:
            raise CampaignError(f"{where}: unknown key {unknown[0]!r}{did_you_mean(unknown[0], ['name', 'low', 'high', 'log'])}")
        name = t.get("name")
        index = param_table().index
        if name not in index:
            raise CampaignError(f"{where}: unknown FC parameter {name!r}" + (did_you_mean(name, sorted(index)) if isinstance(name, str) else ""))
        for k in ("low", "high"):
            if k not in t:
                raise CampaignError(f"{where} ({name}): {k} is missing")
        low, high = _num(t["low"], f"{where} ({name}): low"), _num(t["high"], f"{where} ({name}): high")
        if not low < high:
            raise CampaignError(f"{where} ({name}): empty range: low ({low:g}) must be below high ({high:g})")
        p = param_table().specs[index[name]]
        if low < p.lo or high > p.hi:
            raise CampaignError(f"{where} ({name}): the range [{low:g}, {high:g}] leaves the parameter's valid range [{p.lo:g}, {p.hi:g}]")
        log = t.get("log", False)
        if not isinstance(log, bool):
            raise CampaignError(f"{where} ({name}): log must be true or false")
        if log and low <= 0:
            raise CampaignError(f"{where} ({name}): log = true needs low > 0, got {low:g}")
        gains.append(Gain(name, low, high, log))
    if len({g.name for g in gains}) != len(gains):
        raise CampaignError(f"{source}: a gain is named twice")
    varied = {v.ref.key for v in campaign.variations if v.ref.section == "params"}
    if varied & {g.name for g in gains}:
        raise CampaignError(f"{source}: {sorted(varied & {g.name for g in gains})[0]} is both tuned and varied")
    return TuneSpec(campaign, tuple(gains), Objective(metric, statistic, penalty), trials, parallel, sampler, baseline)


def load_tune(path: str | Path) -> TuneSpec:
    p = Path(path)
    return parse_tune(read_toml(p, CampaignError, "tuning file"), source=str(p), base_dir=p.parent.resolve())


def baseline_gains(spec: TuneSpec) -> dict[str, float]:
    """The gains the base scenario flies (its first controller's), clipped into the ranges."""
    from fc.params import config_for
    from fc.params import spec as param_spec

    v = spec.campaign.variants[0]
    base = spec.campaign.base
    config = config_for(base.with_changes(controller=v.controller, params=(*base.params, *v.params)))
    return {g.name: min(g.high, max(g.low, float(param_spec(g.name).get(config)))) for g in spec.gains}


def _open_study(spec: TuneSpec, out: Path, resume: bool) -> Any:
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend
    from optuna.trial import TrialState

    journal = out / "study.journal"
    if journal.exists() and not resume:
        raise CampaignError(f"{out} already holds a study: add --resume to continue it, or use another --out")
    out.mkdir(parents=True, exist_ok=True)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = JournalStorage(JournalFileBackend(str(journal)))
    sampler = optuna.samplers.TPESampler(seed=spec.campaign.seed) if spec.sampler == "tpe" else optuna.samplers.RandomSampler(seed=spec.campaign.seed)
    study = optuna.create_study(study_name=spec.name, storage=storage, sampler=sampler, direction="minimize", load_if_exists=True)
    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):  # left RUNNING by a crash
        study.tell(t.number, state=TrialState.FAIL)
    if not study.trials and spec.baseline:
        study.enqueue_trial(baseline_gains(spec))
    return study


def _distributions(spec: TuneSpec) -> dict[str, Any]:
    import optuna

    return {g.name: optuna.distributions.FloatDistribution(g.low, g.high, log=g.log) for g in spec.gains}


@dataclass
class TuneResult:
    study: Any
    best_value: float
    best_gains: dict[str, float]
    baseline_value: float | None
    paths: dict[str, Path]


def run_tune(spec: TuneSpec, out: Path, cluster: Any, *, sitl: bool = False, resume: bool = False, quiet: bool = False,
             echo: Any = None) -> TuneResult:  # fmt: skip
    """Run (or continue) the study until ``spec.trials`` trials have finished."""
    from optuna.trial import TrialState

    from lab.campaign.engine import Engine
    from lab.campaign.results import ResultsWriter, columns
    from lab.campaign.run import Progress
    from lab.campaign.units import expand

    say = echo or (lambda s: None)
    probe = expand(spec.campaign, sitl=sitl)  # every check on the scenario set before anything starts
    per_trial = len(probe)
    if (out / "study.journal").exists() and not resume:
        raise CampaignError(f"{out} already holds a study: add --resume to continue it, or use another --out")
    dists = _distributions(spec)
    gain_names = [g.name for g in spec.gains]
    cols = columns(["trial", *gain_names, *(c for c, _ in probe[0].values)])
    engine = Engine(cluster, tag=f"{spec.name}-tune")
    with engine:  # an unreachable scheduler fails here, before the study is created
        if not cluster.local:
            engine.wait_for_workers(1)
        study = _open_study(spec, out, resume)
        finished = [t for t in study.trials if t.state.is_finished()]
        parallel = spec.parallel or max(1, math.ceil(engine.n_workers / per_trial))
        say(f"tune {spec.name}: {spec.trials} trials of {per_trial} flights ({spec.campaign.n_groups} groups × {len(spec.campaign.variants)}"
            f" controllers × {spec.campaign.seeds} seeds), {parallel} at a time, on the {engine.where}"
            + (f"; {len(finished)} trials already done" if finished else "")
            + (f"\ndashboard: {engine.dashboard}" if engine.dashboard else ""))  # fmt: skip
        progress = Progress(spec.trials * per_trial, len(finished) * per_trial, label=f"{spec.name} flights", quiet=quiet)
        in_flight: dict[int, tuple[Any, dict[str, float], list[dict[str, Any]]]] = {}
        n_done = len(finished)
        n_asked = n_done
        try:
            with ResultsWriter(out / "results.csv", cols) as writer:
                while n_done < spec.trials:
                    while len(in_flight) < parallel and n_asked < spec.trials:
                        trial = study.ask(dists)
                        gains = {k: float(trial.params[k]) for k in gain_names}
                        units = expand(spec.campaign, sitl=sitl, extra_params=tuple(gains.items()), first_index=trial.number * per_trial)
                        in_flight[trial.number] = (trial, gains, [])
                        engine.submit(units)
                        n_asked += 1
                    for unit, row in engine.poll(1.0):
                        number = unit.index // per_trial
                        trial, gains, rows = in_flight[number]
                        row = {**row, "trial": number, **gains}
                        rows.append(row)
                        writer.write(row)
                        progress.update(row)
                        if len(rows) == per_trial:
                            value, failures = spec.objective.value(rows)
                            trial.set_user_attr("failures", failures)
                            study.tell(trial, value)
                            del in_flight[number]
                            n_done += 1
                            best = study.best_value
                            progress.note(f"trial {number}: {spec.objective.metric} objective {value:.4g} ({failures} flights crashed or in error);"
                                          f" best {best:.4g} (trial {study.best_trial.number})")  # fmt: skip
        finally:
            progress.close()
            for trial, _, _ in in_flight.values():  # interrupted: not a result
                study.tell(trial, state=TrialState.FAIL)
    return _outputs(spec, study, out)


def _outputs(spec: TuneSpec, study: Any, out: Path) -> TuneResult:
    from optuna.trial import TrialState

    from smcpilot.scenario import dumps_toml

    done = [t for t in study.trials if t.state == TrialState.COMPLETE]
    if not done:
        raise CampaignError(f"{spec.name}: no trial completed")
    best = study.best_trial
    gains = {g.name: float(best.params[g.name]) for g in spec.gains}
    paths: dict[str, Path] = {}
    v = spec.campaign.variants[0]
    lines = [f"# smcpilot tune {spec.name}: the best gains (trial {best.number}, objective {best.value:.6g} = {spec.objective.statistic}"
             f" {spec.objective.metric} + {spec.objective.failure_penalty:g} per flight crashed or in error), controller {v.controller}",
             "# the FC loads it: python -m fc --param-file FILE, or smcpilot sitl --param-file FILE"]  # fmt: skip
    lines += [f"{k} {val!r}" for k, val in gains.items()]
    paths["parm"] = out / "best.parm"
    paths["parm"].write_text("\n".join(lines) + "\n", encoding="utf-8")
    paths["toml"] = out / "best.toml"
    paths["toml"].write_text(f"# smcpilot tune {spec.name}: the best gains (trial {best.number}); paste into a scenario file\n"
                             + dumps_toml({"fc": {"params": gains}}), encoding="utf-8")  # fmt: skip
    paths["trials"] = out / "trials.csv"
    with paths["trials"].open("w", encoding="utf-8", newline="") as f:
        w = csv.writer(f)
        w.writerow(["trial", "state", "objective", "flights_not_ok", *gains])
        for t in study.trials:
            w.writerow([t.number, t.state.name, "" if t.value is None else t.value, t.user_attrs.get("failures", ""),
                        *(t.params.get(k, "") for k in gains)])  # fmt: skip
    baseline = next((t.value for t in study.trials if t.number == 0 and t.state == TrialState.COMPLETE), None) if spec.baseline else None
    paths["history"] = write_history(study, out / "history.png", title=f"{spec.name}: {spec.objective.statistic} {spec.objective.metric}"
                                     f" + {spec.objective.failure_penalty:g} per flight crashed or in error", baseline=spec.baseline)  # fmt: skip
    (out / "best.json").write_text(json.dumps({"trial": best.number, "objective": best.value, "gains": gains, "baseline_objective": baseline,
                                               "trials": len(study.trials)}, indent=2) + "\n", encoding="utf-8")  # fmt: skip
    return TuneResult(study, float(best.value), gains, baseline, paths)


def write_history(study: Any, path: Path, *, title: str, baseline: bool = False) -> Path:
    """The optimisation history: each trial's objective, the best so far, failed trials marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from optuna.trial import TrialState

    trials = sorted(study.trials, key=lambda t: t.number)
    ok = [t for t in trials if t.state == TrialState.COMPLETE]
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    xs, ys = [t.number for t in ok], [t.value for t in ok]
    ax.plot(xs, ys, "o", ms=4, alpha=0.7, label="trial objective")
    if baseline and ok and ok[0].number == 0:
        ax.plot([0], [ok[0].value], "s", ms=8, mfc="none", color="k", label="trial 0: the scenario's own gains")
    best, run = math.inf, []
    for y in ys:
        best = min(best, y)
        run.append(best)
    ax.step(xs, run, where="post", color="C3", lw=1.5, label="best so far")
    failed = [t.number for t in trials if t.state == TrialState.FAIL]
    if failed:
        ax.plot(failed, [max(ys) if ys else 0.0] * len(failed), "x", color="k", label="failed trial (interrupted)")
    if ys and min(ys) > 0 and max(ys) > 20 * min(ys):
        ax.set_yscale("log")
    ax.set_xlabel("trial")
    ax.set_ylabel("objective (lower is better)")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# -- command line --------------------------------------------------------------------------------------
def add_arguments(p: argparse.ArgumentParser) -> None:
    from lab.campaign.cli import add_cluster_arguments

    p.add_argument("tune", type=Path, metavar="TUNE.toml", help="the tuning file (examples/campaigns/tune-*.toml)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="the study directory (journal, results, best gains, figure)")
    p.add_argument("--resume", action="store_true", help="continue the study in DIR (trials a killed process left RUNNING count as failed)")
    p.add_argument("--trials", type=int, metavar="N", help="finish this many trials instead of the file's")
    p.add_argument("--sitl", action="store_true", help="fly each flight as the real FC and simulator processes over UDP")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    add_cluster_arguments(p)


def main(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from lab.campaign.cli import cluster_options

    try:
        import optuna  # noqa: F401
    except ImportError:
        raise CampaignError("smcpilot tune needs Optuna: pip install 'smcpilot[campaign]' (or pip install optuna)") from None
    spec = load_tune(args.tune)
    if args.trials is not None:
        if args.trials < 1:
            raise CampaignError(f"--trials must be >= 1, got {args.trials}")
        spec = replace(spec, trials=args.trials)
    cluster = cluster_options(args)
    t0 = time.perf_counter()
    result = run_tune(spec, args.out, cluster, sitl=args.sitl, resume=args.resume, quiet=args.quiet,
                      echo=lambda s: print(s, file=sys.stderr, flush=True))  # fmt: skip
    gains = ", ".join(f"{k} = {v:.4g}" for k, v in result.best_gains.items())
    base = f" (baseline, the scenario's gains: {result.baseline_value:.4g})" if result.baseline_value is not None else ""
    print(f"tune {spec.name}: best objective {result.best_value:.4g}{base} with {gains}; {len(result.study.trials)} trials,"
          f" {time.perf_counter() - t0:.1f} s")  # fmt: skip
    print(f"best gains: {result.paths['parm']} (--param-file)  {result.paths['toml']} (scenario fragment)")
    print(f"trials: {result.paths['trials']}  flights: {args.out / 'results.csv'}  history: {result.paths['history']}")
    return 0
