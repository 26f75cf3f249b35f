"""``smcpilot campaign run CAMPAIGN.toml --out DIR`` and ``smcpilot campaign replay DIR UNIT``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lab.campaign.engine import ClusterOptions
from lab.campaign.spec import CampaignError, load_campaign


def add_cluster_arguments(p: argparse.ArgumentParser) -> None:
    """``--workers``, ``--cluster``, ``--scheduler-file`` (shared with ``smcpilot tune``)."""
    g = p.add_argument_group("where the flights run (default: a local Dask cluster, one worker process per core)")
    g.add_argument("--workers", type=int, metavar="N", help="worker processes of the local cluster (default: the cores)")
    g.add_argument("--cluster", metavar="tcp://HOST:PORT", help="use the running Dask scheduler at this address (`dask scheduler`)")
    g.add_argument("--scheduler-file", type=Path, metavar="FILE", help="use the Dask scheduler described by this file"
                   " (`dask scheduler --scheduler-file FILE`, dask-jobqueue)")  # fmt: skip
    g.add_argument("--connect-timeout", type=float, default=10.0, metavar="S", help="give up reaching the scheduler after S seconds (default 10)")


def cluster_options(args: argparse.Namespace) -> ClusterOptions:
    if args.workers is not None and (args.cluster or args.scheduler_file):
        raise CampaignError("--workers sizes a local cluster: not with --cluster or --scheduler-file (start the workers there)")
    if not args.connect_timeout > 0:
        raise CampaignError(f"--connect-timeout must be > 0 s, got {args.connect_timeout}")
    return ClusterOptions(workers=args.workers, address=args.cluster, scheduler_file=args.scheduler_file, connect_timeout_s=args.connect_timeout)


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    r = sub.add_parser("run", help="fly every unit of a campaign file; results.csv, summary, figures, worst runs",
                       description="Fly the campaign (base scenario × controllers × seeds × variations; format in"
                       " docs/campaigns.md) on a Dask cluster and write DIR/results.csv (one row per flight, appended as"
                       " each finishes), summary.json, table.md, worst.md and figures/. Exit codes: 0 flown (even if"
                       " vehicles crashed or flights ended in an error: each row's status says so), 2 a broken file, option or"
                       " unreachable scheduler, 130 interrupted (--resume flies the rest).")  # fmt: skip
    r.add_argument("campaign", type=Path, metavar="CAMPAIGN.toml", help="the campaign file (examples/campaigns/)")
    r.add_argument("--out", type=Path, required=True, metavar="DIR", help="the results directory")
    r.add_argument("--resume", action="store_true", help="fly only the units DIR/results.csv does not hold yet (after Ctrl-C or a killed run)")
    r.add_argument("--sitl", action="store_true", help="fly each unit as the real FC and simulator processes over UDP (lockstep, free ports)")
    r.add_argument("--worst", type=int, default=5, metavar="N", help="list (and plot) the N worst runs (default 5)")
    r.add_argument("--no-plots", action="store_true", help="skip the figures")
    r.add_argument("--quiet", action="store_true", help="no progress line")
    add_cluster_arguments(r)
    r.set_defaults(campaign_action=run_main)
    rp = sub.add_parser("replay", help="fly one unit of a campaign again, exactly, and write its .tlog",
                        description="Rebuild unit UNIT of the campaign in DIR (from DIR/campaign.json), fly it in this process"
                        " (or as SITL if the campaign was), and write DIR/replay/unit-UNIT/ (.tlog, scenario, plots); says"
                        " whether the result equals its row in results.csv.")  # fmt: skip
    rp.add_argument("dir", type=Path, metavar="DIR", help="a results directory of `smcpilot campaign run`")
    rp.add_argument("unit", type=int, metavar="UNIT", help="the unit number (the results' unit column)")
    rp.add_argument("--no-plots", action="store_true", help="skip the figures of the log")
    rp.set_defaults(campaign_action=replay_main)


def main(args: argparse.Namespace) -> int:
    return int(args.campaign_action(args))


def run_main(args: argparse.Namespace) -> int:
    from lab.campaign.run import run_campaign

    if args.worst < 0:
        raise CampaignError(f"--worst must be >= 0, got {args.worst}")
    spec = load_campaign(args.campaign)
    cluster = cluster_options(args)
    try:
        result = run_campaign(spec, args.out, cluster, sitl=args.sitl, resume=args.resume, worst_n=args.worst, figures=not args.no_plots,
                              quiet=args.quiet, echo=lambda s: print(s, file=sys.stderr, flush=True))  # fmt: skip
    except KeyboardInterrupt:
        if (args.out / "results.csv").exists():
            print(f"smcpilot campaign: the finished flights are in {args.out / 'results.csv'}; the same command with --resume flies the rest",
                  file=sys.stderr)  # fmt: skip
        raise
    print(result.paths["table"].read_text(encoding="utf-8"), end="")
    bad = result.paths["worst"].read_text(encoding="utf-8").split("\n", 2)[-1]
    if bad.strip():
        print("\nworst runs (replay each with its command):\n" + bad, end="")
    print(f"\nresults: {result.paths['results']}  summary: {result.paths['summary']}  table: {result.paths['table']}"
          + (f"  figures: {result.paths['figures']}/" if "figures" in result.paths else ""))  # fmt: skip
    return 0


def replay_main(args: argparse.Namespace) -> int:
    from ground.logs import load_log, plot_log, print_summary, summarize
    from lab.campaign.run import replay_unit, same_result

    row, tlog, recorded = replay_unit(args.dir, args.unit)
    print(f"replay: unit {args.unit} ({row['controller']}, {row['group']}, seed index {row['seed_index']}): {row['status']}"
          + (f" — {row['message']}" if row.get("message") else ""))  # fmt: skip
    # one log, or a swarm unit's one per vehicle (NAME-vN.tlog, figures in vN/)
    logs = [tlog] if tlog.exists() else sorted(tlog.parent.glob(f"{tlog.stem}-v*.tlog"))
    for path in logs:
        if path.stat().st_size > 0:
            log = load_log(path)
            print()
            if len(logs) > 1:
                print(f"{path.stem}:")
            print_summary(summarize(log), sys.stdout)
            if not args.no_plots:
                where = path.parent if len(logs) == 1 else path.parent / path.stem.rsplit("-", 1)[-1]
                paths = plot_log(log, where)
                print(f"plots: {len(paths)} PNG files in {where}/")
    print(f"log: {', '.join(map(str, logs)) or tlog}")
    if recorded is None:
        print("results.csv has no row for this unit yet (not flown): nothing to compare with")
    elif same_result(row, recorded):
        print("the replay gives the unit's results.csv row exactly (every metric, status and message)")
    else:
        diff = sorted(k for k in set(row) | set(recorded) if k != "wall_s" and not same_result({k: row.get(k)}, {k: recorded.get(k)}))
        print(f"the replay differs from results.csv in: {', '.join(diff)}")
        return 1
    return 0
