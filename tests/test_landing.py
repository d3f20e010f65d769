"""The landing mission end to end in simulation (field scenario, geometric down camera, mocap
odometry): a seeded landing succeeds and is judged by the physics; campaigns resume and give the
same runs on a Dask cluster as on the local pool."""

import numpy as np
import pytest
import yaml

from alight.diagrams.running.campaign import campaign_jobs, run_campaign, summarize
from alight.diagrams.cli import main
from alight.diagrams.analysis.landing import mission_transitions
from alight.diagrams.running.runner import run as run_scenario
from alight.diagrams.scenario import load_scenario
from alight.diagrams.analysis.landing import score_landing
from alight.diagrams.running.run_log import RunLog
from alight.models import model_path
from alight.systems.mission.landing import Mode
from conftest import assert_landed

SPEED = 2.0  # m/s


@pytest.fixture(scope="module")
def landing(tmp_path_factory):
    """`alight land --target-speed 2 --seed 0` (exit status 0: landed)."""
    run_dir = tmp_path_factory.mktemp("land") / "run"
    status = main(["land", "--target-speed", str(SPEED), "--seed", "0", "--run-dir",
                   str(run_dir)])
    return status, RunLog(run_dir)


@pytest.mark.mission
def test_seeded_landing_at_2_ms_succeeds_judged_by_the_physics(landing):
    status, run = landing
    assert status == 0
    scenario = load_scenario("field")
    score = assert_landed(run, scenario, SPEED)
    assert score.touchdown_speed < scenario.scoring.impact.vertical_speed
    assert (run.path / "mission.png").stat().st_size > 20_000   # like L Fig. 10
    assert (run.path / "paths.png").stat().st_size > 10_000     # like L Fig. 12


@pytest.mark.mission
def test_landed_disarms_and_the_vehicle_rests_on_the_moving_platform(landing):
    _, run = landing
    status = run["mission_status"]
    assert status["mode"].iloc[-1] == Mode.LANDED
    landed_at = status["time"][status["mode"] == Mode.LANDED].iloc[0]
    fc = run["fc_status"]
    assert fc["armed"][fc["time"] > landed_at + 0.5].max() == 0.0
    truth = run["ground_truth"]
    end = truth.iloc[-1]
    v_rel = np.array([end[f"v_WB_{i}"] - end[f"v_WT_{i}"] for i in range(3)])
    assert np.linalg.norm([end["v_WT_0"], end["v_WT_1"]]) > 0.3  # the car is still driving
    assert np.linalg.norm(v_rel) < 0.3                            # and carries the vehicle


@pytest.mark.mission
def test_target_swerving_in_landing_phase_2_is_scored_failed_by_the_physics(landing, tmp_path):
    """The seed-0 landing again, with the car pulled sharply aside (90 deg/s for 0.8 s) just after
    Landing Phase 2 began (a scheduled pull draws no noise, so the run is the same until then): the
    mission, blind that close, still reaches Landed; the physics fails the landing."""
    _, run = landing
    p2 = next(t for t, mode, _ in mission_transitions(run) if mode == Mode.LANDING_P2)
    scenario = load_scenario("field", overrides=[f"target_motion.speed: {SPEED}",
                                                 f"target_motion.pull_times: [{p2 + 0.1}]"])
    run = run_scenario(scenario, run_dir=tmp_path / "swerve")
    modes = run["mission_status"]["mode"]
    assert modes.iloc[-1] == Mode.LANDED
    impact = scenario.scoring.impact
    score = score_landing(run, impact.vertical_speed, impact.horizontal_speed)
    assert not score.success
    assert score.reason in ("slid off the platform", "touched the ground", "tipped over",
                            "not resting on the platform") or score.reason.startswith("impact")


def _short_scenario(tmp_path):
    """The field scenario cut at 8 s (climbing): cheap campaign runs."""
    data = yaml.safe_load(model_path("scenario_field.yaml").read_text())
    data["simulator"]["max_duration"] = 8.0
    path = tmp_path / "short.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def _rows(frame):
    return frame.drop(columns=["wall_time", "run_dir"]).reset_index(drop=True)


@pytest.mark.mission
def test_campaign_resumes_and_a_dask_cluster_gives_the_same_runs(tmp_path):
    from distributed import Client, LocalCluster
    scenario = _short_scenario(tmp_path)
    local = tmp_path / "local"
    jobs = campaign_jobs(local, scenario, [SPEED], 2)
    first = run_campaign(local, jobs[:1], progress=False)       # "interrupted" after one run
    rows = run_campaign(local, jobs, progress=False)             # resumes: runs only the other
    assert len(first) == 1 and len(rows) == 2
    assert _rows(rows.iloc[:1]).equals(_rows(first))
    assert not rows["success"].any() and set(rows["reason"]) == {"no detection"}
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        remote = run_campaign(tmp_path / "dask", campaign_jobs(tmp_path / "dask", scenario,
                                                               [SPEED], 2),
                              scheduler=client, progress=False)
    assert _rows(remote).equals(_rows(rows))
    summary = summarize(rows)
    assert summary.loc[SPEED, "runs"] == 2 and summary.loc[SPEED, "success_rate"] == 0.0


def test_bad_scenario_values_are_refused_naming_the_key(tmp_path, capsys):
    data = yaml.safe_load(model_path("scenario_field.yaml").read_text())
    data["mission"]["descending_p2"] = -1.0
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    assert main(["land", "--scenario", str(bad)]) == 2
    assert "descending_p2" in capsys.readouterr().err
    assert main(["campaign", "--target-speeds", "fast", "--runs", "1"]) == 2
