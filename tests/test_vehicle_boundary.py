"""The simulated vehicle exports exactly the vehicle-boundary ports of DESIGN.md."""
import numpy as np
import pytest
from pydrake.systems.framework import PortDataType

from alight.diagrams.world.sim_vehicle import make_sim_vehicle
from alight.systems import boundary


def test_sim_vehicle_ports_match_design(vehicle_config):
    dut = make_sim_vehicle(vehicle_config)
    inputs = {dut.get_input_port(i).get_name(): dut.get_input_port(i)
              for i in range(dut.num_input_ports())}
    outputs = {dut.get_output_port(i).get_name(): dut.get_output_port(i)
               for i in range(dut.num_output_ports())}
    assert set(inputs) == {"fc_command", "odometry"}
    assert set(outputs) == {"imu", "fc_attitude", "fc_status", "rgbd", "down_image", "range",
                            "ground_truth"}
    for name, layout in {**boundary.INPUTS}.items():
        assert inputs[name].get_data_type() == PortDataType.kVectorValued
        assert inputs[name].size() == layout.size
    for name, layout in {**boundary.VECTOR_OUTPUTS, **boundary.SIM_ONLY_OUTPUTS}.items():
        assert outputs[name].get_data_type() == PortDataType.kVectorValued
        assert outputs[name].size() == layout.size
    context = dut.CreateDefaultContext()
    dut.GetInputPort("fc_command").FixValue(context, np.zeros(boundary.FC_COMMAND.size))
    for name, value_type in boundary.ABSTRACT_OUTPUTS.items():
        assert outputs[name].get_data_type() == PortDataType.kAbstractValued
        assert isinstance(outputs[name].Eval(context), value_type)


def test_reserved_cameras_say_they_have_no_frame(vehicle_config):
    dut = make_sim_vehicle(vehicle_config)
    context = dut.CreateDefaultContext()
    assert not dut.GetOutputPort("down_image").Eval(context).valid
    assert not dut.GetOutputPort("rgbd").Eval(context).valid


def test_layout_pack_and_names_round_trip():
    command = boundary.FC_COMMAND.pack(stamp=1.0, mode=1, q_WD=[1, 0, 0, 0], w_D=[0.1, 0.2, 0.3],
                                       thrust=0.5, arm=1)
    assert boundary.FC_COMMAND.get(command, "thrust") == 0.5
    np.testing.assert_allclose(boundary.FC_COMMAND.get(command, "w_D"), [0.1, 0.2, 0.3])
    assert len(boundary.FC_COMMAND.names()) == boundary.FC_COMMAND.size
    assert boundary.FC_COMMAND.names()[2:6] == ["q_WD_0", "q_WD_1", "q_WD_2", "q_WD_3"]


def test_a_vector_from_some_fields_takes_the_layouts_defaults_for_the_rest():
    estimate = boundary.STATE_ESTIMATE.vector(p_EB=[1, 2, 3])
    np.testing.assert_array_equal(boundary.STATE_ESTIMATE.get(estimate, "p_EB"), [1, 2, 3])
    np.testing.assert_array_equal(boundary.STATE_ESTIMATE.get(estimate, "q_EB"), [1, 0, 0, 0])
    assert boundary.estimate_is_valid(estimate)
    assert boundary.STATE_ESTIMATE.get(estimate, "frame_counter") == 0.0
    assert not np.any(boundary.FC_COMMAND.vector(thrust=0.5)[:2])
    with pytest.raises(ValueError, match="q_WD"):
        boundary.FC_COMMAND.pack(stamp=1.0, mode=1, w_D=0.0, thrust=0.5, arm=1)
