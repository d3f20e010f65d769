"""A landing scenario declares the estimator it flies on (issue 9): mocap by default, the bank
(its arbiter) or one of its filters; a bad name stops at load with the key named; the direct
stack is built on the anchored bank and takes off on it."""
import dataclasses as dc

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.onboard.estimation import BankOdometry, scenario_odometry
from alight.diagrams.running.landing import build_landing, run_landing
from alight.diagrams.scenario import load_scenario
from alight.models import model_path
from alight.systems.params import ConfigError


def _scenario_file(tmp_path, extra: str):
    path = tmp_path / "scenario.yaml"
    path.write_text(model_path("scenario_field.yaml").read_text() + extra)
    return path


def test_the_scenario_flies_mocap_unless_it_declares_the_bank(tmp_path):
    assert load_scenario("field").estimator == "mocap"
    assert scenario_odometry("mocap") is None
    scenario = load_scenario(str(_scenario_file(tmp_path, "estimator: rtk\n")))
    odometry = scenario_odometry(scenario.estimator, scenario.estimator_bank)
    assert isinstance(odometry, BankOdometry) and odometry.request == "rtk" and odometry.anchored


def test_an_unknown_estimator_is_refused_at_load_naming_the_file_and_the_key(tmp_path):
    path = _scenario_file(tmp_path, "estimator: kalman\n")
    with pytest.raises(ConfigError, match="key 'estimator' = 'kalman'") as error:
        load_scenario(str(path))
    assert str(path) in str(error.value) and "'bank'" in str(error.value) \
        and "'optic_flow'" in str(error.value)
    with pytest.raises(ConfigError, match="no_such_bank.yaml: parameter file not found"):
        load_scenario(str(_scenario_file(tmp_path, "estimator: bank\n"
                                                   "estimator_bank: no_such_bank.yaml\n")))


def test_the_direct_stack_is_built_on_the_anchored_bank(tmp_path):
    scenario = load_scenario(str(_scenario_file(tmp_path, "estimator: bank\n")))
    builder = DiagramBuilder()
    odometry = scenario_odometry(scenario.estimator, scenario.estimator_bank)
    _, onboard = build_landing(builder, scenario, odometry=odometry)
    diagram = builder.Build()
    assert diagram.HasSubsystemNamed("estimator_bank")
    assert not diagram.HasSubsystemNamed("mocap")
    assert onboard.loop.state_estimate_port == odometry.bank.anchored


def test_alight_land_takes_off_on_the_declared_bank(tmp_path):
    """The first 6 s of the field landing with `estimator: bank`: the mission climbs on the
    bank's estimate (in the GNSS filter's frame, 1.8 m from the truth by the GNSS bias)."""
    scenario = dc.replace(load_scenario(str(_scenario_file(tmp_path, "estimator: bank\n"))),
                          max_duration=6.0)
    run = run_landing(scenario, seed=0, run_dir=tmp_path / "run")
    assert {"bank_estimate", "bank_status"} <= set(run.streams)
    assert run.metadata["scenario"]["estimator"] == "bank"
    truth = run["ground_truth"]
    estimate = run["bank_estimate"]
    assert truth["p_WB_2"].iloc[-1] > 1.5                 # climbing towards 5.2 m
    assert estimate["valid"].iloc[-1] == 1.0
    z_true = np.interp(estimate["time"], truth["time"], truth["p_WB_2"])
    late = estimate["time"] > 2.0
    assert np.abs(estimate["p_EB_2"] - z_true)[late].max() < 0.15   # rangefinder height
