"""A scenario declares the estimator it flies on (issue 9): VIO by default (issue 20: realistic
by default, mocap an explicit option), the bank (its arbiter) or one of its filters; a bad name stops at load with the key named; the direct
stack is built on the anchored bank and takes off on it."""
import numpy as np
import pytest
import yaml
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.onboard.estimation import BankOdometry, scenario_odometry
from alight.diagrams.onboard.vio import VioRun
from alight.diagrams.running.mission import Mission
from alight.diagrams.running.runner import build, run
from alight.diagrams.scenario import Onboard, load_scenario, vehicle_config
from alight.diagrams.stacks import scenario_estimator
from alight.models import model_path
from alight.systems.params import ConfigError


def _scenario_file(tmp_path, **onboard):
    """The field scenario file with `onboard` entries changed."""
    data = yaml.safe_load(model_path("scenario_field.yaml").read_text())
    data["onboard"].update(onboard)
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_every_scenario_that_flies_on_odometry_flies_vio_unless_told_otherwise(tmp_path):
    for name in ("field", "mbzirc", "waypoints"):
        scenario = load_scenario(name)
        assert scenario.onboard.estimator == "vio", name
        odometry = scenario_estimator(scenario)
        assert isinstance(odometry, VioRun)  # its frame E starts at the take-off point
        assert odometry.params.initial_position[:2] == scenario.vehicle.initial_position
        assert vehicle_config(scenario).rgbd_camera.source == "geometric"
    assert Onboard().estimator == "vio"
    mocap = load_scenario("field", overrides=["onboard.estimator: mocap"])
    assert scenario_odometry("mocap", mocap.onboard.estimator_bank,
                             mocap.onboard.linear_model) is None
    assert vehicle_config(mocap).rgbd_camera.source == "none"  # no VIO camera to render
    scenario = load_scenario(str(_scenario_file(tmp_path, estimator="rtk")))
    odometry = scenario_odometry(scenario.onboard.estimator, scenario.onboard.estimator_bank,
                                 scenario.onboard.linear_model)
    assert isinstance(odometry, BankOdometry) and odometry.request == "rtk" and odometry.anchored


def test_the_mission_api_flies_vio_unless_told_otherwise(tmp_path):
    """`Mission.simulated` builds the VIO on the forward RGB-D camera by default; mocap only when
    asked for; a name it does not know is refused."""
    with Mission.simulated(run_dir=tmp_path / "vio") as mission:
        assert mission.diagram.HasSubsystemNamed("vio")
        assert not mission.diagram.HasSubsystemNamed("mocap")
        assert mission.metadata["vehicle_config"].rgbd_camera.source == "geometric"
    with Mission.simulated(run_dir=tmp_path / "mocap", estimator="mocap") as mission:
        assert not mission.diagram.HasSubsystemNamed("vio")
    with pytest.raises(ValueError, match="'gps' is not 'vio' or 'mocap'"):
        Mission.simulated(run_dir=tmp_path / "bad", estimator="gps")


def test_an_unknown_estimator_is_refused_at_load_naming_the_file_and_the_key(tmp_path):
    path = _scenario_file(tmp_path, estimator="kalman")
    with pytest.raises(ConfigError, match="key 'onboard.estimator' = 'kalman'") as error:
        load_scenario(str(path))
    assert str(path) in str(error.value) and "'bank'" in str(error.value) \
        and "'optic_flow'" in str(error.value)
    with pytest.raises(ConfigError, match="no_such_bank.yaml: parameter file not found"):
        load_scenario(str(_scenario_file(tmp_path, estimator="bank",
                                         estimator_bank="no_such_bank.yaml")))


def test_the_direct_stack_is_built_on_the_anchored_bank(tmp_path):
    scenario = load_scenario(str(_scenario_file(tmp_path, estimator="bank")))
    builder = DiagramBuilder()
    odometry = scenario_odometry(scenario.onboard.estimator, scenario.onboard.estimator_bank,
                                 scenario.onboard.linear_model)
    onboard = build(builder, scenario, odometry=odometry)
    diagram = builder.Build()
    assert diagram.HasSubsystemNamed("estimator_bank")
    assert not diagram.HasSubsystemNamed("mocap")
    assert onboard.parts.loop.state_estimate_port == odometry.bank.anchored


@pytest.mark.mission
def test_alight_land_takes_off_on_the_declared_bank(tmp_path):
    """The first 6 s of the field landing with `estimator: bank`: the mission climbs on the
    bank's estimate (in the GNSS filter's frame, 1.8 m from the truth by the GNSS bias)."""
    scenario = load_scenario(str(_scenario_file(tmp_path, estimator="bank")),
                             overrides=["simulator.max_duration: 6.0"])
    run_log = run(scenario, run_dir=tmp_path / "run")
    assert {"bank_estimate", "bank_status"} <= set(run_log.streams)
    assert run_log.metadata["estimator"] == "bank"
    truth = run_log["ground_truth"]
    estimate = run_log["bank_estimate"]
    assert truth["p_WB_2"].iloc[-1] > 1.5                 # climbing towards 5.2 m
    assert estimate["valid"].iloc[-1] == 1.0
    z_true = np.interp(estimate["time"], truth["time"], truth["p_WB_2"])
    late = estimate["time"] > 2.0
    assert np.abs(estimate["p_EB_2"] - z_true)[late].max() < 0.15   # rangefinder height
