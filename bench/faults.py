"""Fault campaign (issue 21): each fault injected into seeded landings (the `alight land` stack:
scenario `field`, its default odometry: the VIO since issue 20, mocap in the table of
docs/benchmarks.md at 153f32d; geometric down camera) and waypoint flights (scenario
`waypoints`, the same linear MPC stack), every run judged from ground truth and contacts
(diagrams/analysis/faults.py): landed / failsafe landing / not landed (safe) / unsafe (NaN at an
actuator, hard impact, flyaway beyond 10 m of the mission's area).

Every fault is an override of the scenario (so each run folder's scenario.yaml pins it):
`faults.estimate` (estimate lost, jump, noise), `faults.command` (NaN / out-of-range linear MPC
commands), `vehicle.motor_fault`, `vehicle.link_losses` (the command link lost: the flight
controller keeps the last command that got through, its stale-command failsafe acts),
`camera_blackouts`. When: a landing's faults start 1 s into its
first Follow phase (over the moving car), the camera blackout in Landing Phase 2 0.2 s into it,
both found in the nominal run of the same seed (identical up to the fault); a waypoint flight's at
4.5 s (at 2 m, on its first leg at speed). A seed whose nominal landing never reaches the phase
has no run for that fault (counted as `n/a`); a run that raises is counted as `error` with its
message in the CSV. Each scenario is resolved once at the start (its files under models/ read
then), so that the runs fly the same parameters however long the campaign takes.

    python bench/faults.py [--runs 2] [--seed 0] [--jobs 2] [--kinds landing,waypoints]
                           [--faults NAME,...] [--out runs/faults]

Prints one row per fault and flight kind with the counts per outcome and the unsafe reasons,
and writes every run's row to OUT/faults.csv. The link loss is simulated at the vehicle's
`fc_command` input; over a real MAVLink link (`alight hil` against `alight sim-autopilot`,
tests/test_mavlink_hil.py) it is not part of this campaign.
"""
import argparse
import concurrent.futures as cf
import dataclasses as dc
import os
import re
import time
from pathlib import Path

import pandas as pd

from alight.diagrams.analysis.faults import OUTCOMES, UNSAFE, judge_fault_run
from alight.diagrams.analysis.landing import mission_transitions
from alight.diagrams.running.run_log import RunLog
from alight.diagrams.running.runner import run
from alight.diagrams.scenario import dump_scenario, load_scenario
from alight.systems.mission.landing import Mode

KINDS = {"landing": "field", "waypoints": "waypoints"}   # flight kind -> scenario
WAYPOINT_FAULT_TIME = 4.5       # s: at 2 m on the first leg
FOLLOW_DELAY = 1.0              # s into the first Follow phase
PHASE2_DELAY = 0.2              # s into Landing Phase 2
BLACKOUT = 3.0                  # s of camera blackout
# s simulated at most (each stack stops settle_time after its disarm): longer than the waypoint
# mission's budget and the landing scenario's 75 s, so that a failsafe descent without a usable
# estimate reaches its max_descent_time (60 s)
MAX_DURATION = 120.0
ERROR, NOT_APPLICABLE = "error", "n/a"     # a run that raised; a phase the nominal never reached
COLUMNS = ["fault", "kind", "seed", "outcome", "reason", "failsafe", "distance",
           "peak_leg_force", "touchdown_speed", "sim_s", "cpu_s", "run_dir", "overrides"]


@dc.dataclass(frozen=True)
class Fault:
    name: str
    overrides: object             # (time [s]) -> list of overrides
    anchor: Mode = Mode.FOLLOW    # landings: the phase it starts in
    kinds: tuple = tuple(KINDS)


def _estimate(**fields):
    return lambda t: ["faults.estimate: {" + ", ".join(
        f"{key}: {value}" for key, value in {**fields, **_times(fields, t)}.items()) + "}"]


def _times(fields, t):
    keys = {"loss": "loss_time", "jump": "jump_time", "noise_std": "noise_start"}
    return {keys[key]: round(t, 3) for key in fields if key in keys}


def _command(kind):
    return lambda t: [f"faults.command: {{kind: {kind}, start: {t:.3f}, duration: 1.0}}"]


def _blackout(t):
    return [f"camera_blackouts: [[{t:.3f}, {t + BLACKOUT:.3f}]]"]


FAULTS = [
    Fault("none", lambda t: []),
    *[Fault(f"estimate lost {d:g} s", _estimate(loss="true", loss_duration=d))
      for d in (0.5, 2.0, 10.0)],
    Fault("camera blackout in Follow", _blackout, kinds=("landing",)),
    Fault("camera blackout in Landing Phase 2", _blackout, Mode.LANDING_P2, ("landing",)),
    Fault("NaN commands (1 s)", _command("nan")),
    Fault("out-of-range commands (1 s)", _command("out_of_range")),
    Fault("estimator jump 5 m", _estimate(jump="[5.0, 0.0, 0.0]")),
    *[Fault(f"estimator noise {s:g} m", _estimate(noise_std=s)) for s in (0.1, 1.0, 2.0)],
    Fault("command link lost 2 s", lambda t: [f"vehicle.link_losses: [[{t:.3f}, {t + 2:.3f}]]"]),
    Fault("motor -30 % thrust", lambda t: [f"vehicle.motor_fault: {{loss: 0.3, rotor: 0, "
                                           f"time: {t:.3f}}}"]),
]


def fly(kind: str, base: str, fault: str, seed: int, overrides: list[str], out: Path) -> dict:
    """One run of the resolved scenario YAML `base` with `overrides`; its row (fault, kind,
    seed, the judged outcome, CPU time). A run that raises is an `error` row with the message
    (a campaign keeps its other rows)."""
    start = time.process_time()
    run_dir = out / f"{kind}-{_slug(fault)}-s{seed}"
    row = {"fault": fault, "kind": kind, "seed": seed, "run_dir": str(run_dir),
           "overrides": "; ".join(overrides)}
    try:
        scenario = load_scenario(data=base, overrides=[f"random_seed: {seed}", *overrides])
        log = run(scenario, run_dir=run_dir, command="faults", duration=MAX_DURATION)
        row.update(dc.asdict(judge_fault_run(log)), sim_s=log.metadata["duration"])
    except Exception as error:   # noqa: BLE001 - reported in the table, not lost
        row.update(outcome=ERROR, reason=f"{type(error).__name__}: {error}"[:200])
    return {**row, "cpu_s": time.process_time() - start}


def _slug(fault: str) -> str:
    return re.sub(r"[^A-Za-z0-9.]+", "_", fault).strip("_")


def judge_folders(out: Path) -> pd.DataFrame:
    """The rows of the finished run folders under `out` (a campaign still running or cut short:
    `--judge-only`), named KIND-FAULT-sSEED as `fly` names them."""
    names = {f"{kind}-{_slug(fault.name)}": (kind, fault.name) for fault in FAULTS
             for kind in KINDS}
    rows = []
    for folder in sorted(out.iterdir()):
        prefix, _, seed = folder.name.rpartition("-s")
        if prefix not in names or not (folder / "metadata.json").exists():
            continue
        log = RunLog(folder)
        if not log.metadata.get("complete"):
            continue
        kind, fault = names[prefix]
        rows.append({"fault": fault, "kind": kind, "seed": int(seed),
                     **dc.asdict(judge_fault_run(log)), "sim_s": log.metadata["duration"],
                     "run_dir": str(folder)})
    return pd.DataFrame(rows)


def fault_time(nominal: RunLog, fault: Fault, kind: str) -> float | None:
    """When `fault` starts in `kind`'s flight of this seed (None: the phase never came)."""
    if kind == "waypoints":
        return WAYPOINT_FAULT_TIME
    entered = [t for t, mode, _ in mission_transitions(nominal) if mode == fault.anchor]
    if not entered:
        return None
    return entered[0] + (FOLLOW_DELAY if fault.anchor == Mode.FOLLOW else PHASE2_DELAY)


def campaign(kinds, faults, seeds, jobs: int, out: Path) -> pd.DataFrame:
    """Nominal runs first (they time the landing faults), then every fault, `jobs` at a time."""
    rows, missing = [], []
    # Each scenario resolved once, its files read now: the runs read no file under models/.
    bases = {kind: dump_scenario(load_scenario(KINDS[kind])) for kind in kinds}
    with cf.ProcessPoolExecutor(jobs) as pool:
        nominal = {(kind, seed): pool.submit(fly, kind, bases[kind], "none", seed, [], out)
                   for kind in kinds for seed in seeds}
        futures = []
        for (kind, seed), future in nominal.items():
            row = future.result()
            rows.append(row)
            for fault in faults:
                if fault.name == "none" or kind not in fault.kinds:
                    continue
                t = fault_time(RunLog(row["run_dir"]), fault, kind) \
                    if row["outcome"] != ERROR else None
                if t is None:
                    missing.append({"fault": fault.name, "kind": kind, "seed": seed,
                                    "outcome": NOT_APPLICABLE})
                    continue
                futures.append(pool.submit(fly, kind, bases[kind], fault.name, seed,
                                           fault.overrides(t), out))
        for row in rows + missing:
            _append(out, row)
        for future in cf.as_completed(futures):
            rows.append(_append(out, future.result()))
    return pd.DataFrame(rows + missing)


def _append(out: Path, row: dict) -> dict:
    """One row into OUT/faults.csv as soon as its run is judged (a cut campaign keeps them)."""
    path = out / "faults.csv"
    pd.DataFrame([row]).reindex(columns=COLUMNS).to_csv(path, mode="a", index=False,
                                                        header=not path.exists())
    return row


def summary(table: pd.DataFrame, faults) -> pd.DataFrame:
    """Counts per outcome for each (fault, kind), in FAULTS order, with the unsafe reasons."""
    order = {fault.name: i for i, fault in enumerate(faults)}
    counts = table.groupby(["fault", "kind"])["outcome"].value_counts().unstack(fill_value=0)
    counts = counts.reindex(columns=[*OUTCOMES, ERROR, NOT_APPLICABLE], fill_value=0)
    unsafe = table[table["outcome"] == UNSAFE].groupby(["fault", "kind"])["reason"].agg(
        lambda reasons: "; ".join(sorted(set(reasons))))
    counts["unsafe reasons"] = unsafe.reindex(counts.index).fillna("")
    counts["max distance [m]"] = table.groupby(["fault", "kind"])["distance"].max().round(1)
    counts["max touchdown [m/s]"] = table.groupby(["fault", "kind"])[
        "touchdown_speed"].max().round(2)
    return counts.sort_index(key=lambda index: index.map(lambda name: order.get(name, name))
                             if index.name == "fault" else index)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=2, help="seeds per fault and flight kind")
    parser.add_argument("--seed", type=int, default=0, help="the first seed")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    parser.add_argument("--kinds", default=",".join(KINDS))
    parser.add_argument("--faults", default=None, help="comma-separated names (default: all)")
    parser.add_argument("--out", type=Path, default=Path("runs/faults"))
    parser.add_argument("--judge-only", action="store_true",
                        help="fly nothing: the table of the finished run folders under --out")
    args = parser.parse_args()
    kinds = args.kinds.split(",")
    unknown = [kind for kind in kinds if kind not in KINDS]
    names = {fault.name for fault in FAULTS}
    wanted = names if args.faults is None else {"none", *args.faults.split(",")}
    if unknown or wanted - names or args.runs < 1:
        parser.error(f"--kinds from {list(KINDS)}, --faults from {sorted(names)}, --runs >= 1")
    faults = [fault for fault in FAULTS if fault.name in wanted]
    if args.judge_only:
        table = judge_folders(args.out)
        print(summary(table, faults).to_string())
        print(f"{len(table)} finished runs under {args.out}")
        return
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "faults.csv").unlink(missing_ok=True)
    wall = time.time()
    table = campaign(kinds, faults, range(args.seed, args.seed + args.runs), args.jobs, args.out)
    with pd.option_context("display.width", 200, "display.max_columns", 20,
                           "display.max_colwidth", 60):
        print(summary(table, faults).to_string())
    flown = table.dropna(subset=["sim_s"])
    print(f"{len(flown)} runs ({args.runs} seeds from {args.seed}) in {time.time() - wall:.0f} s "
          f"wall, {flown['cpu_s'].sum():.0f} CPU s in the runs ({flown['sim_s'].sum():.0f} s "
          f"simulated); load average {os.getloadavg()[0]:.1f}; rows in {args.out / 'faults.csv'}")


if __name__ == "__main__":
    main()
