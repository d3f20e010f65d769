"""The rangefinder and the optic flow measure against the scene's geometry (issue 20; DESIGN.md
"Simulation fidelity"): the ground and the moving target's platform and body (its SDF's boxes)."""
import numpy as np
import pytest
from pydrake.math import RollPitchYaw

from alight.systems.boundary import GROUND_TRUTH
from alight.systems.estimation.measurements import RANGE, VELOCITY_FIX
from alight.systems.sensors.optic_flow import OpticFlow, OpticFlowParams
from alight.systems.sensors.rangefinder import Rangefinder, RangefinderParams
from alight.systems.sensors.scene_ray import target_boxes

HEADING = 0.5                       # rad, the car's heading
P_WT = np.array([4.0, -3.0, 1.0])   # platform top 1 m above the ground (target.yaml)
V_WT = np.array([2.0 * np.cos(HEADING), 2.0 * np.sin(HEADING), 0.0])


def truth(p_T, tilt_deg: float = 0.0, v_WB=(0.0, 0.0, 0.0), present: float = 1.0,
          height: float = 3.0):
    """The body `height` above the ground at p_T (x, y in the car's frame T), rolled by
    `tilt_deg`; the car at P_WT, heading HEADING, driving at 2 m/s."""
    c, s = np.cos(HEADING), np.sin(HEADING)
    p_WB = P_WT + np.array([c * p_T[0] - s * p_T[1], s * p_T[0] + c * p_T[1], 0.0])
    p_WB[2] = height
    q_WB = RollPitchYaw(np.radians(tilt_deg), 0.0, 0.2).ToQuaternion().wxyz()
    return GROUND_TRUTH.pack(
        p_WB=p_WB, q_WB=q_WB, v_WB=v_WB, w_WB_B=0.0, v_WA=0.0, motor_command=0.0,
        rotor_thrust=0.0, p_WT=P_WT, q_WT=[np.cos(HEADING / 2), 0, 0, np.sin(HEADING / 2)],
        v_WT=V_WT, target_present=present)


def measure_range(params: RangefinderParams, ground_truth) -> np.ndarray:
    return Rangefinder(params).measure(0.0, ground_truth, np.zeros(1), None)


def test_target_geometry_comes_from_the_sdf():
    sizes = sorted(tuple(np.round(2 * half, 3)) for _, _, half in target_boxes(
        "target_vehicle.sdf"))
    assert sizes == [(1.5, 1.5, 0.04), (3.4, 1.7, 0.6)]   # the platform plate and the car body


@pytest.mark.parametrize("p_T, tilt, expected", [
    ((0.3, -0.2), 0.0, 2.0),            # over the platform: its top, 1 m up
    ((1.4, 0.0), 0.0, 3.0 - 0.94),      # over the car's bonnet (body top 6 cm under T)
    ((0.0, 2.5), 0.0, 3.0),             # beside the car: the ground
    ((0.0, 2.5), 30.0, 3.0 / np.cos(np.radians(30.0))),   # tilted, beside it
])
def test_rangefinder_measures_the_first_surface_under_the_body(p_T, tilt, expected):
    measurement = measure_range(RangefinderParams(noise_std=0.0), truth(p_T, tilt))
    assert RANGE.get(measurement, "valid") == 1.0
    assert RANGE.get(measurement, "range") == pytest.approx(expected, abs=1e-9)


def test_rangefinder_measures_the_platform_top_when_over_the_car_and_the_ground_otherwise():
    over = truth((0.0, 0.0))
    assert RANGE.get(measure_range(RangefinderParams(noise_std=0.0), over), "range") == \
        pytest.approx(2.0)
    # the same pose with no car in the scene, or a sensor that ignores it: the ground
    for ground_truth, params in ((truth((0.0, 0.0), present=0.0), RangefinderParams()),
                                 (over, RangefinderParams(target_model=""))):
        params.noise_std = 0.0
        assert RANGE.get(measure_range(params, ground_truth), "range") == pytest.approx(3.0)


def test_optic_flow_over_the_moving_car_measures_the_velocity_relative_to_it():
    flow = OpticFlow(OpticFlowParams(noise_std=0.0, min_height=0.5))
    # flying along with the car over its platform: no flow; beside it: the ground speed
    with_car = flow.measure(0.0, truth((0.0, 0.0), v_WB=V_WT), np.zeros(2), None)
    np.testing.assert_allclose(VELOCITY_FIX.get(with_car, "v_H"), 0.0, atol=1e-12)
    beside = flow.measure(0.0, truth((0.0, 2.5), v_WB=V_WT), np.zeros(2), None)
    assert np.linalg.norm(VELOCITY_FIX.get(beside, "v_H")) == pytest.approx(2.0)
    # 0.4 m above the platform (1.4 m above the ground): closer than min_height to the surface
    low = flow.measure(0.0, truth((0.0, 0.0), v_WB=V_WT, height=1.4), np.zeros(2), None)
    assert VELOCITY_FIX.get(low, "valid") == 0.0
