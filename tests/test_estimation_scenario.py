"""A landing scenario declares the estimator it flies on (issue 9): mocap by default, the bank
(its arbiter) or one of its filters; a bad name stops at load with the key named; the direct
stack is built on the anchored bank and takes off on it."""
import numpy as np
import pytest
import yaml
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.onboard.estimation import BankOdometry, scenario_odometry
from alight.diagrams.running.runner import build, run
from alight.diagrams.scenario import load_scenario
from alight.models import model_path
from alight.systems.params import ConfigError


def _scenario_file(tmp_path, **onboard):
    """The field scenario file with `onboard` entries changed."""
    data = yaml.safe_load(model_path("scenario_field.yaml").read_text())
    data["onboard"].update(onboard)
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_scenario_flies_mocap_unless_it_declares_the_bank(tmp_path):
    field = load_scenario("field")
    assert field.onboard.estimator == "mocap"
    assert scenario_odometry("mocap", field.onboard.estimator_bank,
                             field.onboard.linear_model) is None
    scenario = load_scenario(str(_scenario_file(tmp_path, estimator="rtk")))
    odometry = scenario_odometry(scenario.onboard.estimator, scenario.onboard.estimator_bank,
                                 scenario.onboard.linear_model)
    assert isinstance(odometry, BankOdometry) and odometry.request == "rtk" and odometry.anchored


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
