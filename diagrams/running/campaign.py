"""Monte Carlo landing campaigns (DESIGN.md "Campaigns"): many seeded landing missions per target
speed, on a local process pool or on a Dask distributed cluster (the same job function), with one
run folder per mission and a table of all runs (`runs.csv`, appended as runs finish, so an
interrupted campaign keeps its finished runs and a second call resumes), summarized per speed in
the form of L Table 1.
"""
import dataclasses as dc
import multiprocessing
import time
from pathlib import Path

import numpy as np
import pandas as pd

from alight.diagrams.analysis.landing import score_landing
from alight.diagrams.analysis.vio import evaluate_vio
from alight.diagrams.running.runner import run
from alight.diagrams.scenario import Scenario, load_scenario

COLUMNS = ["target_speed_setting", "seed", "success", "reason", "target_speed", "e_xy",
           "tracking_duration", "mission_time", "touchdown_speed", "peak_leg_force", "wall_time",
           "run_dir", "e_ahead", "vio_ate", "vio_drift", "vio_restarts"]


@dc.dataclass(frozen=True)
class CampaignJob:
    """One mission: a scenario (name or file) with its overrides ('key.sub: value' each) and
    seed, the target speed it is tabled under, and where to write its run folder."""
    scenario: str
    overrides: tuple[str, ...]
    seed: int
    target_speed: float
    run_dir: str


def scenario_for(job: CampaignJob) -> Scenario:
    """The job's scenario: its overrides and seed applied, validated."""
    return load_scenario(job.scenario, overrides=[*job.overrides, f"random_seed: {job.seed}"])


def run_job(job: CampaignJob) -> dict:
    """Flies and scores one mission (runs in a worker process); returns its table row."""
    start = time.perf_counter()
    scenario = scenario_for(job)
    run_log = run(scenario, run_dir=job.run_dir, command="campaign")
    score = score_landing(run_log, scenario.scoring.impact.vertical_speed,
                          scenario.scoring.impact.horizontal_speed)
    return {"target_speed_setting": job.target_speed, "seed": job.seed, **dc.asdict(score),
            **vio_figures(run_log, score.mission_time),
            "wall_time": time.perf_counter() - start, "run_dir": job.run_dir}


def vio_figures(run_log, until: float) -> dict:
    """The VIO's ATE [m] and final drift (fraction of the distance flown) from the start to
    `until` (the touchdown, or the run's end), and its window restarts over the whole run; empty
    when the mission flew another odometry (then the columns stay blank)."""
    if "vio_estimate" not in run_log.streams:
        return {}
    vio = evaluate_vio(run_log, until=until)
    return {"vio_ate": vio["ate_rmse"], "vio_drift": vio["final_drift"],
            "vio_restarts": vio["restarts"]}


def campaign_jobs(out_dir: Path, scenario: str, speeds, runs: int, seed: int = 0,
                  overrides=()) -> list[CampaignJob]:
    """`runs` seeds from `seed` per target speed (`target_motion.speed`), each with `overrides`;
    seed by seed (every speed of one seed, then the next), so that a campaign stopped part way has
    about as many runs at each speed."""
    return [CampaignJob(str(scenario), (*overrides, f"target_motion.speed: {float(v)}"),
                        seed + i, float(v),
                        str(Path(out_dir) / "runs" / f"v{float(v):.1f}_s{seed + i}"))
            for i in range(runs) for v in speeds]


def finished(out_dir: Path) -> pd.DataFrame:
    """The rows of runs.csv (empty if none)."""
    path = Path(out_dir) / "runs.csv"
    return pd.read_csv(path) if path.is_file() else pd.DataFrame(columns=COLUMNS)


def _append(out_dir: Path, row: dict) -> None:
    path = Path(out_dir) / "runs.csv"
    # a campaign resumed from an older runs.csv keeps that file's columns
    columns = list(pd.read_csv(path, nrows=0).columns) if path.is_file() else COLUMNS
    pd.DataFrame([row], columns=columns).to_csv(path, mode="a", header=not path.is_file(),
                                                index=False)


def run_campaign(out_dir: Path, jobs: list[CampaignJob], workers: int = 1,
                 scheduler: str | None = None, progress: bool = True) -> pd.DataFrame:
    """Runs the jobs not yet in out_dir/runs.csv (local pool, or the Dask scheduler at
    `scheduler`: an address or a `distributed.Client`); returns all rows, sorted."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    done = finished(out_dir)
    keys = set(zip(done["target_speed_setting"].round(3), done["seed"]))
    todo = [j for j in jobs if (round(j.target_speed, 3), j.seed) not in keys]
    bar = _progress(len(jobs), len(jobs) - len(todo), progress)
    start, landed = time.perf_counter(), 0
    for row in _execute(todo, workers, scheduler):
        _append(out_dir, row)
        landed += bool(row["success"])
        bar.update(1)
    bar.close()
    if progress and todo:
        print(throughput(len(todo), landed, time.perf_counter() - start), flush=True)
    rows = finished(out_dir)
    return rows.sort_values(["target_speed_setting", "seed"]).reset_index(drop=True)


def throughput(missions: int, landed: int, wall: float) -> str:
    """The campaign's pace: missions flown (and landed) per minute of wall time."""
    minutes = wall / 60
    return (f"{missions} landing missions in {minutes:.1f} min of wall time: "
            f"{missions / minutes:.1f} landings per minute ({landed} landed, "
            f"{landed / minutes:.1f} per minute)")


# pydrake keeps every diagram it has built alive: a Python LeafSystem's callbacks are bound methods
# that C++ holds, a cycle the garbage collector cannot see (RobotLocomotion/drake#22515); measured
# here, every system of a finished field mission survives `gc.collect()`, about 85 MB per mission.
# A local worker is therefore replaced (forked again from the campaign's process, which has
# imported everything) after this many missions (250 missions on one worker would hold about
# 21 GB).
MISSIONS_PER_WORKER = 8


def _execute(jobs, workers: int, scheduler):
    if not jobs:
        return
    if scheduler is not None:
        from distributed import Client
        from distributed import as_completed as dask_completed
        client = scheduler if isinstance(scheduler, Client) else Client(scheduler)
        for future in dask_completed(client.map(run_job, jobs, pure=False)):
            yield future.result()
        if client is not scheduler:
            client.close()
        return
    if workers <= 1:
        for job in jobs:
            yield run_job(job)
        return
    # The pool flies every submitted job even when one raises: table every finished one before
    # raising the first error (a second call then flies only the failed jobs).
    failed = []
    with multiprocessing.Pool(workers, maxtasksperchild=MISSIONS_PER_WORKER) as pool:
        for job, row, error in pool.imap_unordered(_try_job, jobs):
            if error is not None:
                failed.append((job, error))
                continue
            yield row
    if failed:
        job, error = failed[0]
        raise RuntimeError(f"{len(failed)} of {len(jobs)} campaign runs failed, the first "
                           f"{job.run_dir}: {error!r}") from error


def _try_job(job: CampaignJob) -> tuple[CampaignJob, dict | None, Exception | None]:
    """`run_job` in a pool worker: its row, or the error it raised (the pool goes on)."""
    try:
        return job, run_job(job), None
    except Exception as error:   # tabled by the caller, raised after the other jobs
        return job, None, error


def _progress(total: int, initial: int, enabled: bool):
    from tqdm import tqdm
    return tqdm(total=total, initial=initial, disable=not enabled, unit="run",
                desc="landings")


def summarize(rows: pd.DataFrame) -> pd.DataFrame:
    """Per target speed, as L Table 1 in bulk: runs, success rate, median and worst e_xy of the
    successful landings [cm], the median of their offset ahead of the platform's centre [cm]
    (a lead or lag of the reference), median tracking duration [s], mean measured target speed,
    and the median and worst peak force on one leg of every run that touched down [N] (the
    structural limit is the airframe's `max_leg_force`), and over the runs that flew on VIO its
    drift to the touchdown, median and worst [%]."""
    def one(group: pd.DataFrame) -> pd.Series:
        ok = group[group["success"].astype(bool)]
        forces = group["peak_leg_force"].dropna()
        drift = group["vio_drift"].dropna() if "vio_drift" in group else pd.Series(dtype=float)
        return pd.Series({
            "runs": len(group), "landed": len(ok), "success_rate": len(ok) / len(group),
            "target_speed": group["target_speed"].mean(),
            "e_xy_median_cm": 100 * ok["e_xy"].median() if len(ok) else np.nan,
            "e_xy_worst_cm": 100 * ok["e_xy"].max() if len(ok) else np.nan,
            "e_ahead_median_cm": 100 * ok["e_ahead"].median()
            if len(ok) and "e_ahead" in ok else np.nan,
            "tracking_median_s": ok["tracking_duration"].median() if len(ok) else np.nan,
            "leg_force_median_n": forces.median() if len(forces) else np.nan,
            "leg_force_worst_n": forces.max() if len(forces) else np.nan,
            "vio_drift_median_pct": 100 * drift.median() if len(drift) else np.nan,
            "vio_drift_worst_pct": 100 * drift.max() if len(drift) else np.nan})
    return rows.groupby("target_speed_setting").apply(one, include_groups=False)


def write_summary(out_dir: Path, rows: pd.DataFrame) -> pd.DataFrame:
    """summary.csv, summary.md (a Markdown table) and summary.png next to runs.csv."""
    out_dir = Path(out_dir)
    summary = summarize(rows)
    summary.to_csv(out_dir / "summary.csv")
    (out_dir / "summary.md").write_text(summary_markdown(summary))
    _plot(summary, rows, out_dir / "summary.png")
    return summary


def summary_markdown(summary: pd.DataFrame) -> str:
    lines = ["| target speed [m/s] | runs | landed | success | e_xy median [cm] | e_xy worst [cm] "
             "| ahead median [cm] | tracking median [s] | peak leg force median / worst [N] "
             "| VIO drift to touchdown median / worst [%] |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for speed, r in summary.iterrows():
        lines.append(f"| {speed:.1f} ({r.target_speed:.2f} measured) | {r.runs:.0f} | "
                     f"{r.landed:.0f} | {100 * r.success_rate:.0f} % | {r.e_xy_median_cm:.1f} | "
                     f"{r.e_xy_worst_cm:.1f} | {r.e_ahead_median_cm:+.1f} | "
                     f"{r.tracking_median_s:.2f} | "
                     f"{r.leg_force_median_n:.0f} / {r.leg_force_worst_n:.0f} | "
                     f"{r.vio_drift_median_pct:.2f} / {r.vio_drift_worst_pct:.2f} |")
    return "\n".join(lines) + "\n"


def _plot(summary: pd.DataFrame, rows: pd.DataFrame, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    a.bar(summary.index.astype(str), 100 * summary["success_rate"])
    a.set_xlabel("target speed [m/s]")
    a.set_ylabel("landed [%]")
    ok = rows[rows["success"].astype(bool)]
    b.scatter(ok["target_speed"], 100 * ok["e_xy"], s=12)
    b.set_xlabel("measured target speed [m/s]")
    b.set_ylabel("e_xy at touchdown [cm]")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
