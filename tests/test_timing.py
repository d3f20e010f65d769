"""Compute times live outside the Drake context (systems/timing.py): the same seeded system gives
the same state bit for bit, while its `compute_timer` records every tick; a run folder writes them
apart, as the `timing` stream."""
import numpy as np
import pandas as pd
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from alight.diagrams.running.flights import fly_reference
from alight.systems.boundary import CONTROLLER_STATUS, REFERENCE, STATE_ESTIMATE, TRACKER_STATUS
from alight.systems.control.failsafe import FailsafeController, FailsafeParams
from alight.systems.control.force_controller import VehicleModel, level_command
from alight.systems.perception.target_estimator import PERCEPTION_STATUS
from alight.systems.timing import ComputeTimer, compute_timers, timing_frame
from alight.systems.vio.odometry import VIO_ODOMETRY


def _descend(dut: FailsafeController, seconds: float):
    """A fresh context of `dut`, active from a flying command, advanced `seconds`."""
    context = dut.CreateDefaultContext()
    dut.GetInputPort("state_estimate").FixValue(context, STATE_ESTIMATE.vector(
        p_EB=[0, 0, 3], v_EB=[0, 0, -0.5], heading=0.3))
    dut.GetInputPort("reference").FixValue(context, np.zeros(REFERENCE.size))
    dut.GetInputPort("active").FixValue(context, [1.0])
    dut.GetInputPort("last_command").FixValue(context, level_command(0.0, 0.3, 0.6, 1.0))
    Simulator(dut, context).AdvanceTo(seconds)
    return context


def test_two_simulations_have_the_same_state_and_the_timer_records_both():
    dut = FailsafeController(VehicleModel(), FailsafeParams(), period=0.01)
    first, second = _descend(dut, 0.5), _descend(dut, 0.5)
    assert first.num_discrete_state_groups() >= 4
    for i in range(first.num_discrete_state_groups()):
        np.testing.assert_array_equal(first.get_discrete_state(i).get_value(),
                                      second.get_discrete_state(i).get_value())
    stamps = dut.compute_timer.stamps()
    ticks = len(stamps) // 2
    assert ticks == 50 and len(stamps) == 2 * ticks     # every 10 ms tick in [0, 0.5), twice
    np.testing.assert_allclose(stamps[:ticks], 0.01 * np.arange(ticks), atol=1e-12)
    np.testing.assert_array_equal(stamps[:ticks], stamps[ticks:])
    assert np.all(dut.compute_timer.seconds() > 0.0)


def test_no_layout_carries_a_wall_clock_time():
    for layout in (CONTROLLER_STATUS, TRACKER_STATUS, PERCEPTION_STATUS, VIO_ODOMETRY):
        assert not any("time" in name for name in layout.names()), layout.names()


def test_a_diagram_lists_its_timers_by_path_and_makes_the_timing_stream():
    inner = DiagramBuilder()
    failsafe = inner.AddNamedSystem("failsafe", FailsafeController(
        VehicleModel(), FailsafeParams()))
    builder = DiagramBuilder()
    builder.AddNamedSystem("onboard", inner.Build())
    builder.AddNamedSystem("source", ConstantVectorSource([0.0]))
    timers = compute_timers(builder.Build())
    assert timers == {"onboard/failsafe": failsafe.compute_timer}
    vio = ComputeTimer()
    vio.record(0.10, "frontend", 0.002)
    vio.record(0.10, "backend", 0.030)
    failsafe.compute_timer.record(0.05, "tick", 0.001)
    failsafe.compute_timer.record(0.15, "tick", 0.001)
    frame = timing_frame({**timers, "vio": vio})
    assert list(frame.columns) == ["time", "component", "part", "seconds"]
    assert frame["time"].tolist() == [0.05, 0.10, 0.10, 0.15]
    assert frame["component"].tolist() == ["onboard/failsafe", "vio", "vio", "onboard/failsafe"]
    assert frame["part"].tolist() == ["tick", "frontend", "backend", "tick"]
    np.testing.assert_array_equal(vio.seconds("backend"), [0.030])
    assert timing_frame({}).empty


def test_a_rerun_reproduces_every_stream_but_timing(vehicle_config, tmp_path):
    def hover(t):
        return np.array([0.0, 0.0, 1.0]), np.zeros(3)
    first, second = (fly_reference(vehicle_config, hover, 2.0, tmp_path / name, seed=3)
                     for name in ("first", "second"))
    assert "timing" in first.streams and first.streams == second.streams
    for stream in first.streams:
        if stream != "timing":
            pd.testing.assert_frame_equal(first[stream], second[stream], check_exact=True)
    timing = first["timing"]
    assert list(timing.columns) == ["time", "component", "part", "seconds"]
    assert set(zip(timing["component"], timing["part"])) == {("linear_mpc", "tick")}
    np.testing.assert_allclose(timing["time"], 0.05 * np.arange(40), atol=1e-9)  # 20 Hz, 2 s
    assert np.all(timing["seconds"] > 0.0) and len(first.compute_seconds("linear_mpc")) == 40
    pd.testing.assert_frame_equal(timing.drop(columns="seconds"),
                                  second["timing"].drop(columns="seconds"), check_exact=True)
