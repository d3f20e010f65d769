"""`alight campaign`: its options and what it runs (`HELP` says what it does)."""
import argparse
import sys

from alight.diagrams.cli.options import LANDING_FLAGS, add_scenario_options, scenario_overrides

NAME = "campaign"
HELP = ("Monte Carlo landings per target speed (local processes or a Dask cluster), "
        "summarized like L Table 1")


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(NAME, help=HELP, description=HELP)
    add_scenario_options(parser, "field", [f for f in LANDING_FLAGS if f != "target_speed"])
    parser.add_argument("--target-speeds", default="1.3,2,3,4,5,5.7", metavar="V,V,...")
    parser.add_argument("--runs", type=int, default=20,
                        help="runs per speed (seeds --seed, --seed + 1, ...; default from 0)")
    parser.add_argument("--workers", type=int, default=1, help="local worker processes")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="run on this Dask distributed scheduler instead (tcp://host:8786)")
    parser.add_argument("--out", default="runs/campaign",
                        help="campaign folder (runs.csv, summary, run folders); rerun resumes")
    parser.set_defaults(run=run)
    return parser


def run(args) -> int:
    from pathlib import Path
    from alight.diagrams.running.campaign import (campaign_jobs, run_campaign, scenario_for,
                                                  write_summary)
    from alight.systems.params import ConfigError
    try:
        speeds = [float(v) for v in args.target_speeds.split(",") if v.strip()]
    except ValueError:
        print(f"alight campaign: --target-speeds must be numbers like 1.3,2,3, got "
              f"{args.target_speeds!r}", file=sys.stderr)
        return 2
    if not speeds or args.runs < 1 or any(not 0 <= v <= 20 for v in speeds):
        print("alight campaign: give at least one target speed in [0, 20] m/s and --runs >= 1",
              file=sys.stderr)
        return 2
    out = Path(args.out)
    seed, args.seed = args.seed or 0, None     # each job's seed is its own override
    jobs = campaign_jobs(out, args.scenario, speeds, args.runs, seed, scenario_overrides(args))
    try:
        scenario_for(jobs[0])          # a bad scenario or override stops here, not in a worker
    except ConfigError as e:
        print(f"alight campaign: {e}", file=sys.stderr)
        return 2
    rows = run_campaign(out, jobs, workers=args.workers, scheduler=args.scheduler)
    summary = write_summary(out, rows)
    print(summary.to_string(float_format=lambda v: f"{v:.2f}"))
    print(f"all runs: {out / 'runs.csv'}; summary: {out / 'summary.md'}, {out / 'summary.png'}")
    return 0
