"""The landing mission end to end in simulation (field scenario, its default sensing: geometric
down camera, VIO): a seeded landing succeeds and is judged by the physics; a car swerving under
the descent is caught by the rangefinder or failed by the physics; campaigns resume and give the
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
from alight.systems.mission.landing import Mode, Reason
from alight.systems.rotations import quaternion_heading
from conftest import SHORT_LANDING, assert_landed

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
    # Judged by contact: the legs touched the platform, nothing touched the ground after the
    # take-off, nothing but the legs touched anything; no leg overloaded (126 N measured).
    truth = run["ground_truth"]
    flying = truth["time"] > 5.0
    # On the platform from the touchdown to the end (2.03 s) but for a 0.06 s bounce: 1.97 s.
    assert truth["legs_platform_time"].iloc[-1] > scenario.scoring.settle_time - 0.1
    assert truth["legs_platform_force"].iloc[-1] == pytest.approx(2.5 * 9.81, rel=0.01)
    assert truth["legs_ground_force"][flying].max() == 0.0
    assert truth["legs_ground_time"][flying].nunique() == 1 and \
        truth["other_contact_time"].iloc[-1] == 0.0
    assert 100.0 < score.peak_leg_force < scenario.vehicle.airframe.max_leg_force
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


def _swerve(run, after_p2: float, tmp_path, *overrides: str):
    """The seed-0 landing again with the car pulled sharply aside (90 deg/s for 0.8 s)
    `after_p2` s after Landing Phase 2 began (a scheduled pull draws no noise, so the run is the
    same until then), with the scenario `overrides`; returns the run and its score."""
    p2 = next(t for t, mode, _ in mission_transitions(run) if mode == Mode.LANDING_P2)
    scenario = load_scenario("field", overrides=[f"target_motion.speed: {SPEED}",
                                                 f"target_motion.pull_times: [{p2 + after_p2}]",
                                                 *overrides])
    run = run_scenario(scenario, run_dir=tmp_path / "swerve")
    impact = scenario.scoring.impact
    return run, score_landing(run, impact.vertical_speed, impact.horizontal_speed)


@pytest.mark.mission
def test_target_swerving_in_the_blind_descent_is_scored_failed_by_the_physics(landing, tmp_path):
    """Pulled 0.5 s into Phase 2, the car swerves under the descent while the pattern is too
    close to see and the platform's edge still under the rangefinder: the mission reaches Landed,
    the physics fails the landing (194 N on a leg, e_xy 74 cm, measured)."""
    run, score = _swerve(landing[1], 0.5, tmp_path)
    assert run["mission_status"]["mode"].iloc[-1] == Mode.LANDED
    assert not score.success
    assert score.reason in ("slid off the platform", "touched the ground", "tipped over",
                            "not resting on the platform") or score.reason.startswith("impact")


@pytest.mark.mission
def test_a_descent_beside_the_swerving_car_goes_around_on_the_rangefinder_and_lands(landing,
                                                                                   tmp_path):
    """Pulled 0.1 s into Phase 2, the car leaves the descent's footprint: below the blind
    height the rangefinder reads the road, so the mission does not go on to disarm (L's rule
    would have, 1.3 m above the road) but goes back to Follow (MISSED_PLATFORM), climbs clear,
    catches the car again and lands on it. (Found only at the landed height, the go-around
    began 0.35 s later with the body below the platform's top beside its corner, and in one
    realization the airframe struck the car.) Flown on the paper's constant-velocity
    reference: with the car's acceleration fed forward (the default since c907d75) the vehicle
    is 8 cm nearer the platform's centre when the car is pulled, stays over its edge as the car
    leaves, and its legs graze the edge (130 N) as it goes around: the physics scores that
    "slid off the platform" although the mission goes around and lands on the car 6 s later."""
    run, score = _swerve(landing[1], 0.1, tmp_path, "mission.cutoff_acceleration: 0.0")
    events = mission_transitions(run)
    missed = [i for i, (_, _, reason) in enumerate(events) if reason == Reason.MISSED_PLATFORM]
    assert len(missed) == 1 and events[missed[0]][1] == Mode.FOLLOW
    assert events[missed[0] - 1][1] == Mode.LANDING_P2
    fc = run["fc_status"]
    airborne = (fc["time"] > 5.0) & (fc["time"] <= events[missed[0]][0] + 1.0)
    assert fc["armed"][airborne].min() == 1.0                   # not disarmed over the road
    assert events[-1][1:] == (Mode.LANDED, Reason.BELOW_LANDED_OFFSET)
    assert score.success, score.row()
    truth = run["ground_truth"]
    flying = truth["time"] > 5.0
    assert truth["legs_ground_force"][flying].max() == 0.0     # never touched the road


def _rows(frame):
    return frame.drop(columns=["wall_time", "run_dir"]).reset_index(drop=True)


@pytest.mark.mission
def test_the_car_swerving_away_under_the_blind_descent_is_a_ground_touchdown(tmp_path):
    """The short landing with the camera blind from Landing Phase 2 on (8.2 s), the car
    pulled aside then and the rangefinder out (no fresh range: L's rule on the estimate alone;
    with it the mission goes around, above): the mission lands where the car would have been,
    on the ground, and the contact says so."""
    scenario = load_scenario("field", overrides=[*SHORT_LANDING, f"target_motion.speed: {SPEED}",
                                                 "target_motion.pull_times: [8.2]",
                                                 "camera_blackouts: [[8.2, 20.0]]",
                                                 "vehicle.rangefinder.outages: [[0.0, 20.0]]"])
    run = run_scenario(scenario, run_dir=tmp_path / "away")
    assert run["mission_status"]["mode"].iloc[-1] == Mode.LANDED
    score = score_landing(run, scenario.scoring.impact.vertical_speed,
                          scenario.scoring.impact.horizontal_speed)
    assert not score.success and score.reason == "touched the ground", score.row()
    truth = run["ground_truth"]
    assert truth["legs_platform_time"].iloc[-1] == 0.0               # never on the platform
    flying = truth["time"] > 5.0
    assert truth["legs_ground_time"][flying].iloc[-1] > truth["legs_ground_time"][flying].iloc[0]
    assert score.e_xy > 0.75 + 0.22                                  # beyond its edge
    assert score.peak_leg_force > scenario.vehicle.airframe.max_leg_force  # 311 N at 4.3 m/s


@pytest.mark.mission
def test_campaign_resumes_and_a_dask_cluster_gives_the_same_runs(tmp_path):
    """Two short landings (seeds 0 and 1, both landed: e_xy 15.4 and 12.9 cm measured), run
    once then resumed on the local pool, and again on a Dask cluster: the same rows."""
    from distributed import Client, LocalCluster
    local = tmp_path / "local"
    jobs = campaign_jobs(local, "field", [SPEED], 2, overrides=SHORT_LANDING)
    first = run_campaign(local, jobs[:1], progress=False)       # "interrupted" after one run
    rows = run_campaign(local, jobs, progress=False)             # resumes: runs only the other
    assert len(first) == 1 and len(rows) == 2
    assert _rows(rows.iloc[:1]).equals(_rows(first))
    assert rows["success"].all() and set(rows["reason"]) == {"landed"}, rows["reason"]
    print(rows[["seed", "e_xy", "vio_ate", "vio_drift", "vio_restarts"]])
    # The VIO these missions flew on, judged to the touchdown: no restart, within 1 % of the
    # distance flown (issue 20's goal) and 4 cm ATE (measured: 0.14-0.16 %, 1.3-1.8 cm)
    assert (rows["vio_restarts"] == 0).all() and (rows["vio_drift"] < 0.01).all(), rows
    assert (rows["vio_ate"] < 0.04).all(), rows["vio_ate"]
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        remote = run_campaign(tmp_path / "dask", campaign_jobs(tmp_path / "dask", "field",
                                                               [SPEED], 2, overrides=SHORT_LANDING),
                              scheduler=client, progress=False)
    assert _rows(remote).equals(_rows(rows))
    summary = summarize(rows)
    assert summary.loc[SPEED, "runs"] == 2 and summary.loc[SPEED, "success_rate"] == 1.0
    limit = load_scenario("field").vehicle.airframe.max_leg_force
    assert summary.loc[SPEED, "leg_force_worst_n"] == rows["peak_leg_force"].max() < limit
    assert summary.loc[SPEED, "vio_drift_worst_pct"] == 100 * rows["vio_drift"].max()


def test_a_local_campaign_worker_is_replaced_after_its_missions(tmp_path, monkeypatch):
    """pydrake keeps every built diagram alive (about 85 MB per field mission, campaign.py): the
    local pool forks a new worker after `MISSIONS_PER_WORKER` missions, and a mission that
    raises is tabled after the others finished, not lost with its worker."""
    import os
    from alight.diagrams.running import campaign

    def fake_job(job):   # a worker's pid instead of a flight
        if job.seed == 3:
            raise ValueError("a broken mission")
        return {"target_speed_setting": job.target_speed, "seed": job.seed, "success": True,
                "reason": str(os.getpid())}

    monkeypatch.setattr(campaign, "run_job", fake_job)
    monkeypatch.setattr(campaign, "MISSIONS_PER_WORKER", 2)
    jobs = campaign_jobs(tmp_path, "field", [SPEED], 7)
    with pytest.raises(RuntimeError, match="1 of 7 campaign runs failed.*v2.0_s3.*broken"):
        run_campaign(tmp_path, jobs, workers=2, progress=False)
    rows = campaign.finished(tmp_path)
    assert sorted(rows["seed"]) == [0, 1, 2, 4, 5, 6]
    pids = rows["reason"].value_counts()
    assert len(pids) >= 3 and pids.max() <= 2, pids   # 7 missions, 2 per worker at most


def test_bad_scenario_values_are_refused_naming_the_key(tmp_path, capsys):
    data = yaml.safe_load(model_path("scenario_field.yaml").read_text())
    data["mission"]["descending_p2"] = -1.0
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    assert main(["land", "--scenario", str(bad)]) == 2
    assert "descending_p2" in capsys.readouterr().err
    assert main(["campaign", "--target-speeds", "fast", "--runs", "1"]) == 2


@pytest.mark.mission
def test_at_8_ms_the_vio_s_keyframe_corrections_do_not_throw_the_car_off(tmp_path):
    """`alight land --target-speed 8 --wind 15 --gusts 0.8 --seed 11` (VIO, geometric cameras):
    the VIO moves the vehicle's position by 5-20 cm at each keyframe at this speed; the target
    estimator moves the car with it (STATE_ESTIMATE `p_EO`), so the target EKF keeps the car's
    velocity and the vehicle lands within issue 23's 25 cm (measured 12.9 cm). Before, each
    correction read as the car's motion: the EKF's velocity went 1 m/s off, it re-initialized
    four times in the descent and the vehicle hit the car 0.95 m behind the platform's centre."""
    scenario = load_scenario("field", overrides=[
        "target_motion.speed: 8.0", "random_seed: 11", f"vehicle.wind.mean_speed: {15 / 3.6}",
        "vehicle.wind.gust_std: 0.8"])
    run = run_scenario(scenario, run_dir=tmp_path / "fast")
    impact = scenario.scoring.impact
    score = score_landing(run, impact.vertical_speed, impact.horizontal_speed)
    assert score.success, score.row()
    assert score.e_xy < 0.25, score.row()
    assert score.target_speed == pytest.approx(8.0, abs=0.6)


@pytest.mark.mission
def test_on_the_mbzirc_curve_the_car_s_acceleration_lands_the_vehicle_near_the_centre(tmp_path):
    """`alight land --scenario mbzirc` in 15 km/h wind (seed 0), the scenario's defaults: the
    reference carries the car's acceleration and the target EKF estimates it, so the touchdown on
    the curve is within 20 cm of the platform's centre (measured 14.4 cm; 37 cm with the paper's
    constant-velocity reference and EKF, the test below)."""
    scenario = load_scenario("mbzirc", overrides=["vehicle.wind.mean_speed: 4.1667",
                                                  "vehicle.wind.gust_std: 0.8"])
    run = run_scenario(scenario, run_dir=tmp_path / "mbzirc")
    score = assert_landed(run, scenario, scenario.target_motion.speed)
    assert score.e_xy < 0.20, score.row()


@pytest.mark.mission
def test_a_landing_on_the_mbzirc_figure_eight_s_curve_rests_on_the_turning_platform(tmp_path):
    """`alight land --scenario mbzirc` in 15 km/h wind (seed 0): the car is on the figure-eight's
    curve at the touchdown, and the vehicle, standing 37 cm off the platform's centre, turns with
    it. It is at rest relative to the platform where it stands (its position in the platform's
    frame does not move), although its velocity differs from the centre's by about
    w x r = 0.29 rad/s x 0.37 m = 0.11 m/s: the judge once failed 18 of 20 such landings as
    "not at rest on the platform". Flown with the paper's constant-velocity reference and target
    EKF, which stand the vehicle off the centre (with the car's acceleration it lands 15 cm off,
    where w x r is too small to tell the judges apart; docs/landing.md "A turning car")."""
    scenario = load_scenario("mbzirc", overrides=[
        "vehicle.wind.mean_speed: 4.1667", "vehicle.wind.gust_std: 0.8",
        "mission.cutoff_acceleration: 0.0", "onboard.perception.ekf.sigma_acc: [0.0, 0.0, 0.0]"])
    run = run_scenario(scenario, run_dir=tmp_path / "mbzirc")
    score = assert_landed(run, scenario, scenario.target_motion.speed)
    truth = run["ground_truth"]
    end = truth["time"] > truth["time"].iloc[-1] - 0.5
    heading = np.unwrap([quaternion_heading(*q) for q in
                         run.field("ground_truth", "q_WT").to_numpy()[end].tolist()])
    turn_rate = abs(np.polyfit(truth["time"][end], heading, 1)[0])
    offset = run.field("ground_truth", "p_WB").to_numpy()[end] \
        - run.field("ground_truth", "p_WT").to_numpy()[end]
    centre_speed = np.linalg.norm(run.field("ground_truth", "v_WB").to_numpy()[end]
                                  - run.field("ground_truth", "v_WT").to_numpy()[end], axis=1)
    r = np.linalg.norm(offset[:, :2], axis=1).mean()
    assert turn_rate > 0.2 and r > 0.2, score.row()   # on the curve, off the centre
    # what the old judge read as the vehicle's motion on the platform: the platform's own turn
    assert centre_speed.mean() == pytest.approx(turn_rate * r, rel=0.2)
