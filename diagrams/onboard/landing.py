"""The onboard landing stack (L Sec. 6-7) on any vehicle's boundary ports (the simulated or the
MAVLink vehicle): odometry, target perception, the mission state machine L Sec. 6.4 with its
reference generation L Sec. 6.3, the linear MPC (`add_landing_onboard`). diagrams/stacks.py builds
it from a scenario, on the simulated vehicle (`alight land`) or the MAVLink one (`alight hil`)."""
import dataclasses as dc

from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.onboard.mpc_loop import MpcLoop, add_mpc_control, add_mpc_logging
from alight.diagrams.onboard.perception import TargetPerceptionPorts, add_target_perception
from alight.diagrams.running.run_log import RunLoggers
from alight.diagrams.running.simulation import DisarmedAfter, evaluate
from alight.systems.boundary import TARGET_ESTIMATE
from alight.systems.control.linear_model import LinearModelParams
from alight.systems.control.linear_mpc import LinearMpcParams
from alight.systems.control.touchdown_level import TouchdownLevel, TouchdownLevelParams
from alight.systems.managers.control_manager import gave_up
from alight.systems.managers.failsafe_switch import FailsafeSwitchParams
from alight.systems.mission.landing import (MISSION_STATUS, LandingMission, LandingMissionParams,
                                            Mode)
from alight.systems.perception.target_estimator import TargetEstimatorParams
from alight.systems.sensors.camera_faults import CameraBlackout


@dc.dataclass
class LandingOnboard:
    """Handles to the onboard landing stack built by `add_landing_onboard`."""
    mission: LandingMission
    loop: MpcLoop
    perception: TargetPerceptionPorts
    loggers: RunLoggers

    def finished(self, settle_time: float) -> DisarmedAfter:
        """Stop condition: `settle_time` s after the mission landed (or the failsafe took over)
        and the flight controller disarmed."""
        return landed_and_disarmed(self.mission, self.loop.vehicle, settle_time,
                                   self.loop.switch)


def landed_and_disarmed(mission: LandingMission, vehicle, settle_time: float,
                        manager) -> DisarmedAfter:
    """Stop condition: `settle_time` s after `mission` landed, or `manager` (the control manager
    or the failsafe switch: a `manager_status` output) gave up the mission (failsafe, emergency
    landing), with `vehicle` disarmed."""
    return DisarmedAfter(lambda context: float(MISSION_STATUS.get(evaluate(
        mission, "mission_status", context), "mode")) == Mode.LANDED or gave_up(evaluate(
            manager, "manager_status", context)), vehicle, settle_time)


def add_down_camera_perception(builder: DiagramBuilder, vehicle, state_estimate,
                               params: TargetEstimatorParams,
                               camera_blackouts=()) -> TargetPerceptionPorts:
    """Target perception `params` on `vehicle`'s `down_image`, blanked in the `camera_blackouts`
    windows [[start, end], ...] s (a sensor fault, simulation only)."""
    image = vehicle.GetOutputPort("down_image")
    if camera_blackouts:
        blackout = builder.AddNamedSystem("camera_blackout", CameraBlackout(camera_blackouts))
        builder.Connect(image, blackout.get_input_port())
        image = blackout.get_output_port()
    return add_target_perception(builder, image, state_estimate, params)


def add_mission_logging(builder: DiagramBuilder, loggers: RunLoggers, mission: LandingMission,
                        target_estimate, period: float) -> None:
    """The mission's status and the target estimate, at the mission's `period`."""
    loggers.add(builder, "mission_status", mission.GetOutputPort("mission_status"),
                MISSION_STATUS, period=period)
    loggers.add(builder, "target_estimate", target_estimate, TARGET_ESTIMATE, period=period)


def add_touchdown_level(builder: DiagramBuilder, params: TouchdownLevelParams,
                        mission: LandingMission, period: float) -> TouchdownLevel:
    """The level touchdown `params` on `mission`'s status, deciding every `period` (the command
    switch's); its `fc_command`, `state_estimate` and `target_estimate` inputs are the caller's
    to connect."""
    level = builder.AddNamedSystem("touchdown_level", TouchdownLevel(params, period))
    builder.Connect(mission.GetOutputPort("mission_status"), level.GetInputPort("mission_status"))
    return level


def add_landing_onboard(builder: DiagramBuilder, vehicle, mission_params: LandingMissionParams,
                        mpc_params: LinearMpcParams, model: LinearModelParams, odometry,
                        perception: TargetEstimatorParams, fallback: FailsafeSwitchParams,
                        camera_blackouts=(), command_filter=None,
                        touchdown: TouchdownLevelParams = TouchdownLevelParams()
                        ) -> LandingOnboard:
    """The onboard landing stack on `vehicle`'s boundary ports (the simulated or the MAVLink
    vehicle): the mission state machine L Sec. 6.4 with its reference L Sec. 6.3, `odometry` and
    the linear MPC with its `fallback` to the failsafe (`add_mpc_control`), its command levelled
    for the `touchdown` (TouchdownLevel), target perception `perception` on `down_image` (with
    `camera_blackouts`) and the run logging; `command_filter` as in `add_mpc_control` (fault
    injection, before the levelling)."""
    mission = builder.AddNamedSystem("mission", LandingMission(mission_params))
    level = add_touchdown_level(builder, touchdown, mission, fallback.period)

    def levelled(builder, command):
        if command_filter is not None:
            command = command_filter(builder, command)
        builder.Connect(command, level.GetInputPort("fc_command"))
        return level.GetOutputPort("fc_command")

    loop = add_mpc_control(builder, vehicle, mission.GetOutputPort("reference"),
                           mission.GetOutputPort("arm"), odometry=odometry,
                           mpc_params=mpc_params, model=model, fallback=fallback,
                           command_filter=levelled)
    ports = add_down_camera_perception(builder, vehicle, loop.state_estimate_port, perception,
                                       camera_blackouts)
    builder.Connect(loop.state_estimate_port, level.GetInputPort("state_estimate"))
    builder.Connect(ports.target_estimate, level.GetInputPort("target_estimate"))
    builder.Connect(loop.state_estimate_port, mission.GetInputPort("state_estimate"))
    builder.Connect(ports.target_estimate, mission.GetInputPort("target_estimate"))
    builder.Connect(vehicle.GetOutputPort("range"), mission.GetInputPort("range"))
    loggers = add_mpc_logging(builder, loop, mission.GetOutputPort("reference"))
    add_mission_logging(builder, loggers, mission, ports.target_estimate, mission_params.period)
    return LandingOnboard(mission, loop, ports, loggers)
