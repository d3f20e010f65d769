"""A 5 m step in the GNSS-like source at hover (M Sec. 3.5, Fig. 13): the bank (gating, arbiter,
frame switch) keeps the vehicle in place; one filter fusing everything flies it metres away."""
import dataclasses as dc

import numpy as np
import pytest

from alight.diagrams.onboard.estimation import load_bank_params
from alight.diagrams.running.flights import fly_bank
from alight.models import model_path
from alight.systems.params import load_params
from alight.systems.sensors.position_fix import PositionFixParams

pytestmark = pytest.mark.mission

JUMP_TIME, DURATION = 6.0, 12.0
SINGLE = """
period: 0.01
sources:
  - {name: gnss, kind: position_fix, timeout: 1.0, sensor: gnss.yaml}
  - {name: optic_flow, kind: velocity_fix, timeout: 0.3, sensor: optic_flow.yaml}
  - {name: rangefinder, kind: range, timeout: 0.3, sensor: rangefinder.yaml}
filters:
  - name: single
    frame_id: 20
    gate: false
    fuse: [gnss.position.xy, optic_flow.velocity_heading, rangefinder.height, fc.heading,
           fc.heading_rate]
"""


def _fly(config, params, run_dir):
    gnss = dc.replace(load_params(PositionFixParams, model_path("gnss.yaml")),
                      jump=[5.0, 0.0, 0.0], jump_time=JUMP_TIME)
    rtk_off = dc.replace(load_params(PositionFixParams, model_path("rtk.yaml")),
                         outages=[[0.0, 1e9]])
    return fly_bank(config, params, DURATION, run_dir, seed=2,
                    sensors={"gnss": gnss, "rtk": rtk_off})


def _moved(run) -> float:
    """Largest horizontal distance of the vehicle from where it was just before the jump."""
    truth = run["ground_truth"]
    p = truth[["p_WB_0", "p_WB_1"]].to_numpy()
    t = truth["time"].to_numpy()
    before = p[(t > JUMP_TIME - 1.0) & (t <= JUMP_TIME)].mean(axis=0)
    return float(np.linalg.norm(p[t > JUMP_TIME] - before, axis=1).max())


@pytest.fixture(scope="module")
def bank_run(vehicle_config, tmp_path_factory):
    return _fly(vehicle_config, load_bank_params(), tmp_path_factory.mktemp("jump") / "bank")


def test_a_5_m_gnss_jump_moves_the_vehicle_less_than_0_3_m_with_the_bank(bank_run):
    moved = _moved(bank_run)
    status = bank_run["bank_status"]
    after = status[status["time"] > JUMP_TIME]
    print(f"bank: vehicle moved {moved:.3f} m; gnss gate rejections "
          f"{after['gnss_gated'].max():.0f}, switches {after['switches'].max():.0f}")
    assert moved < 0.3
    assert after["gnss_gated"].max() > status[status["time"] <= JUMP_TIME]["gnss_gated"].max()
    assert after["gnss_reliable"].min() == 0.0   # the arbiter saw it fail the gate ...
    assert (after["active"] == 2).any()          # ... and flew on optic flow meanwhile


def test_the_same_jump_moves_a_single_filter_fusing_everything_by_metres(vehicle_config,
                                                                         tmp_path):
    run = _fly(vehicle_config, load_bank_params(data=SINGLE), tmp_path / "single")
    moved = _moved(run)
    print(f"single filter: vehicle moved {moved:.2f} m")
    assert moved > 2.0
