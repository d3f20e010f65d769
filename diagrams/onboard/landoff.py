"""Take-off and landing on the landoff tracker (M Sec. 4.2) in closed loop: mocap odometry, the
landoff tracker (always active) wired straight to one flight-stack controller (SE(3) or MPC force
feedback), and an arm gate that disarms once the tracker reports `landed`. diagrams/running/flights.py
`fly_landoff` flies a schedule of goals on the simulated vehicle and writes a run folder; the tests
and bench/landoff.py (the tethered take-off of docs/benchmarks.md) use it.
"""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem
from pydrake.systems.primitives import AffineSystem, ConstantVectorSource

from alight.diagrams.onboard.controllers import ControllersConfig, make_controller
from alight.diagrams.onboard.mocap import add_mocap
from alight.systems.boundary import REFERENCE, VectorLayout
from alight.systems.control.arm_gate import ArmGate
from alight.systems.sensors.mocap import MocapParams
from alight.systems.tracking.landoff_tracker import LandoffTrackerParams, make_landoff_tracker

LANDED = VectorLayout("landed", [("landed", 1)])


class GoalSchedule(LeafSystem):
    """Output `goal` (abstract): `goals[i]` from `times[i]` [s] on; None before the first."""

    def __init__(self, schedule: list[tuple[float, object]]):
        super().__init__()
        self._times = np.array([t for t, _ in schedule], float)
        self._goals = [goal for _, goal in schedule]
        if np.any(np.diff(self._times) < 0):
            raise ValueError(f"goal schedule times must not decrease: {self._times}")
        self.DeclareAbstractOutputPort("goal", lambda: AbstractValue.Make(None), self._calc,
                                       {self.time_ticket()})

    def _calc(self, context, output):
        i = int(np.searchsorted(self._times, context.get_time(), side="right")) - 1
        output.set_value(self._goals[i] if i >= 0 else None)


def add_landoff_loop(builder, vehicle, controllers_config: ControllersConfig,
                     tracker_params: LandoffTrackerParams, schedule, mocap: MocapParams,
                     controller: str = "se3"):
    """Mocap odometry `mocap` of `vehicle`, the landoff tracker following `schedule`, the
    controller and the arm gate (disarmed once landed) on the vehicle's command. Returns
    (estimate port, tracker, controller, the issued command port)."""
    estimate = add_mocap(builder, vehicle.GetOutputPort("ground_truth"), mocap)
    tracker = builder.AddNamedSystem("landoff_tracker", make_landoff_tracker(
        controllers_config.vehicle, tracker_params))
    goals = builder.AddNamedSystem("goals", GoalSchedule(schedule))
    feedback = builder.AddNamedSystem(f"controller_{controller}",
                                      make_controller(controller, controllers_config))
    gate = builder.AddNamedSystem("arm_gate", ArmGate())
    arm = builder.AddNamedSystem("arm_unless_landed", AffineSystem(   # [1, 1] - [landed] x 2
        np.zeros((0, 0)), np.zeros((0, 1)), np.zeros(0), np.zeros((2, 0)), -np.ones((2, 1)),
        np.ones(2)))
    active = builder.AddNamedSystem("active", ConstantVectorSource([1.0]))
    no_reference = builder.AddNamedSystem("no_last_reference", ConstantVectorSource(
        np.full(REFERENCE.size, np.nan)))
    command = gate.GetOutputPort("fc_command")
    builder.Connect(estimate, tracker.GetInputPort("state_estimate"))
    builder.Connect(goals.GetOutputPort("goal"), tracker.GetInputPort("goal"))
    builder.Connect(active.get_output_port(), tracker.GetInputPort("active"))
    builder.Connect(no_reference.get_output_port(), tracker.GetInputPort("last_reference"))
    builder.Connect(command, tracker.GetInputPort("last_command"))
    builder.Connect(estimate, feedback.GetInputPort("state_estimate"))
    builder.Connect(tracker.GetOutputPort("reference"), feedback.GetInputPort("reference"))
    if feedback.HasInputPort("tracker_status"):
        builder.Connect(tracker.GetOutputPort("tracker_status"),
                        feedback.GetInputPort("tracker_status"))
    builder.Connect(active.get_output_port(), feedback.GetInputPort("active"))
    builder.Connect(command, feedback.GetInputPort("last_command"))
    builder.Connect(vehicle.GetOutputPort("fc_attitude"), feedback.GetInputPort("fc_attitude"))
    builder.Connect(feedback.GetOutputPort("fc_command"), gate.GetInputPort("fc_command"))
    builder.Connect(tracker.GetOutputPort("landed"), arm.get_input_port())
    builder.Connect(arm.get_output_port(), gate.GetInputPort("arm"))
    builder.Connect(command, vehicle.GetInputPort("fc_command"))
    return estimate, tracker, feedback, command
