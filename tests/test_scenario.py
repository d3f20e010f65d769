"""One typed scenario per run (issue 17): loaded once with its files resolved, overridden from the
command line by `--set` and the convenience flags, pinned in the run folder, and flown again from
there stream for stream."""
import dataclasses as dc

import numpy as np
import pandas as pd
import pytest

from alight.diagrams.cli import main, make_parser
from alight.diagrams.cli.options import args_scenario
from alight.diagrams.running.run_log import RunLog
from alight.diagrams.scenario import (Scenario, WaypointPlan, dump_scenario, load_scenario,
                                      vehicle_config)
from alight.diagrams.world.sim_vehicle import check_rate_grid, load_sim_vehicle_config
from alight.systems.control.scripted_pilot import PilotProfile
from alight.systems.mission.landing import LandingMissionParams
from alight.systems.params import ConfigError


def test_every_shipped_scenario_loads_with_its_files_resolved():
    for name, mission in (("field", LandingMissionParams), ("mbzirc", LandingMissionParams),
                          ("field_hil", LandingMissionParams), ("waypoints", WaypointPlan),
                          ("hover", PilotProfile)):
        scenario = load_scenario(name)
        assert isinstance(scenario, Scenario) and isinstance(scenario.mission, mission)
        assert "yaml" not in dump_scenario(scenario)    # values only, never a file name
    field = load_scenario("field")
    assert field.onboard.linear_mpc.weight_position == [10.0, 10.0, 8.0] and len(field.vehicle.airframe.rotors) == 6
    target = vehicle_config(field).target
    assert target.profile == "field_test" and target.field_test.mean_speed == 3.0
    # The car starts speed x approach_time before the waypoint, along its heading (+y).
    np.testing.assert_allclose(target.initial_position, [0.0, -60.0], atol=1e-9)


def test_overrides_reach_the_scenario_on_every_command():
    cases = {
        "land": (["land", "--target-speed", "4", "--wind", "18", "--camera", "rendered",
                  "--stack", "managed", "--controller", "se3", "--seed", "7",
                  "--set", "simulator.max_duration: 30"],
                 lambda s: (s.target_motion.speed, s.vehicle.wind.mean_speed,
                            s.vehicle.down_camera.source, s.onboard.vio_camera.source,
                            s.onboard.stack, s.onboard.controller, s.random_seed,
                            s.simulator.max_duration),
                 (4.0, 5.0, "rendered", "rendered", "landing_managed", "se3", 7, 30.0)),
        "campaign": (["campaign", "--gusts", "0.8", "--set", "onboard.estimator: vio"],
                     lambda s: (s.vehicle.wind.gust_std, s.onboard.estimator), (0.8, "vio")),
        "fly": (["fly", "--waypoints", "0,0,2", "--set", "vehicle.imu.period: 0.004"],
                lambda s: s.vehicle.imu.period, 0.004),
        "track": (["track", "--wind", "3.6", "--set", "vehicle.ground_friction: 0.5"],
                  lambda s: (s.vehicle.wind.mean_speed, s.vehicle.ground_friction), (1.0, 0.5)),
        "hover": (["hover", "--set", "vehicle.initial_heading: 90"],
                  lambda s: s.vehicle.initial_heading, 90.0),
    }
    for command, (argv, read, expected) in cases.items():
        assert read(args_scenario(make_parser().parse_args(argv))) == pytest.approx(expected), \
            command


@pytest.mark.parametrize("argv", [
    ["land", "--set", "target_motion.sped: 2"],
    ["campaign", "--runs", "1", "--set", "target_motion.sped: 2"],
    ["fly", "--waypoints", "0,0,2", "--set", "target_motion.sped: 2"],
    ["track", "--set", "target_motion.sped: 2"],
    ["hil", "--connect", "udp:127.0.0.1:9", "--mission", "land", "--set",
     "target_motion.sped: 2"],
])
def test_a_bad_override_is_refused_naming_the_key(argv, capsys):
    assert main(argv) == 2
    assert "target_motion.sped" in capsys.readouterr().err


def test_a_bad_override_value_names_the_key_and_range():
    with pytest.raises(ConfigError, match=r"target_motion\.speed.*is not a number"):
        load_scenario("field", overrides=["target_motion.speed: fast"])
    with pytest.raises(ConfigError, match=r"vehicle\.wind\.gust_std.*outside the allowed range"):
        load_scenario("field", overrides=["vehicle.wind.gust_std: -1"])
    with pytest.raises(ConfigError, match=r"'waypoints' stack.*WaypointPlan"):
        load_scenario("field", overrides=["onboard.stack: waypoints"])


def _streams(run: RunLog) -> dict[str, pd.DataFrame]:
    return {name: run[name] for name in run.streams if name != "timing"}


@pytest.mark.mission
def test_a_run_folder_flies_again_from_its_scenario_yaml_stream_for_stream(tmp_path):
    """The first 8 s of the field landing (take-off: every system runs), then the same run from
    the run folder's scenario.yaml alone: every logged stream identical, bit for bit (`timing`,
    the wall-clock compute times, is the one stream that may differ)."""
    first, again = tmp_path / "first", tmp_path / "again"
    assert main(["land", "--seed", "3", "--target-speed", "2.5", "--set",
                 "simulator.max_duration: 8", "--run-dir", str(first)]) == 1   # not landed
    assert main(["land", "--scenario", str(first / "scenario.yaml"), "--run-dir",
                 str(again)]) == 1
    a, b = _streams(RunLog(first)), _streams(RunLog(again))
    assert set(a) == set(b) and {"ground_truth", "imu", "mission_status"} <= set(a)
    for name in a:
        pd.testing.assert_frame_equal(a[name], b[name], check_exact=True, obj=name)
    assert load_scenario(first / "scenario.yaml").random_seed == 3
    assert "timing" in RunLog(again).streams


def test_a_vio_period_other_than_the_imu_period_is_refused_naming_both_keys():
    """The VIO integrates each IMU sample over its own period: a different IMU rate would count
    samples twice or leave gaps."""
    assert load_scenario("field", overrides=["onboard.estimator: vio"]).onboard.vio.period \
        == load_scenario("field").vehicle.imu.period
    with pytest.raises(ConfigError, match=r"onboard\.vio\.period.*vehicle\.imu\.period"):
        load_scenario("field", overrides=["onboard.estimator: vio", "vehicle.imu.period: 0.002"])


@pytest.mark.parametrize("key, value", [("imu.period", 0.005), ("flight_controller.period", 0.003),
                                        ("contact_period", 0.001)])
def test_a_vehicle_rate_off_the_plant_step_is_refused_naming_the_key(key, value):
    """Every sampled part of the vehicle reads the plant state of its own instant only when its
    period is a multiple of the plant's step (2 ms)."""
    config = load_sim_vehicle_config()
    check_rate_grid(config)  # the shipped rates lie on the grid
    if key == "contact_period":
        config = dc.replace(config, contact_period=value)
    else:
        part, field = key.split(".")
        config = dc.replace(config, **{part: dc.replace(getattr(config, part), **{field: value})})
    with pytest.raises(ConfigError, match=rf"'{key}' = {value} s is not a multiple"):
        check_rate_grid(config)


def test_the_vio_flies_the_forward_camera_it_is_given():
    """`fly_vio(camera=...)` (bench/vio.py --sources, alight vio-eval --rgbd-camera): the
    scenario carries that camera as the VIO's, and the simulated vehicle gets it (the scenario's
    default VIO camera replaced it before, so `--sources rendered` flew the geometric one)."""
    from alight.diagrams.onboard.vio import load_rgbd_camera_params
    from alight.diagrams.running.flights import vehicle_scenario
    from alight.diagrams.scenario import vehicle_config
    rendered = dc.replace(load_rgbd_camera_params(), source="rendered")
    config = dc.replace(load_sim_vehicle_config(), rgbd_camera=rendered)
    plan = WaypointPlan([[0.0, 0.0, 2.0]])
    assert vehicle_config(vehicle_scenario(config, "waypoints", plan, vio_camera=rendered)
                          ).rgbd_camera.source == "rendered"
    assert vehicle_config(vehicle_scenario(config, "waypoints", plan)).rgbd_camera.source \
        == "geometric"   # without it: the scenario's own (models/rgbd_camera_landing.yaml)
