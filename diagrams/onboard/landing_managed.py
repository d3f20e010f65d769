"""The landing mission (L Sec. 6.4) on the managed flight stack (M Sec. 7.2, issue 11):
odometry -> target perception -> the landing mission state machine, unchanged, whose mode and arm
request `LandingRequests` turns into the control manager's tracker requests and goals: take-off
with the landoff tracker (M Sec. 4.2), the waypoint with the MPC tracker (M Sec. 4.1), Follow
and Landing Phases 1/2 with the target tracker (the L Sec. 6.3 reference generator), flown by one
controller of the control manager (the landing paper's `linear_mpc` by default, or `mpc`,
`se3`); the mission's arm request [arm, thrust enable] is the control manager's `arm` input
(Landed disarms).

`alight land --set 'onboard.stack: landing_managed' [--controller NAME]` runs it (diagrams/stacks.py).
"""
import dataclasses as dc

from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.onboard.control_manager import (ControlManagerConfig, ManagedControllers,
                                                     add_control_manager, add_managed_logging,
                                                     connect_managed_vehicle)
from alight.diagrams.onboard.landing import (add_down_camera_perception, add_mission_logging,
                                             add_touchdown_level, landed_and_disarmed)
from alight.diagrams.onboard.perception import TargetPerceptionPorts
from alight.diagrams.running.run_log import RunLoggers
from alight.diagrams.running.simulation import DisarmedAfter
from alight.systems.control.linear_mpc import LinearMpcParams
from alight.systems.control.touchdown_level import TouchdownLevelParams
from alight.systems.mission.landing import LandingMission, LandingMissionParams
from alight.systems.mission.landing_requests import LandingRequests
from alight.systems.perception.target_estimator import TargetEstimatorParams
from alight.systems.params import ConfigError


# The trackers LandingRequests asks for: take-off, waypoint, target (its defaults).
LANDING_TRACKERS = ("landoff", "mpc_tracker", "target")


@dc.dataclass
class LandingManagedOnboard:
    """Handles to the stack built by `add_landing_managed`."""
    vehicle: object
    state_estimate: object
    mission: LandingMission
    requests: LandingRequests
    managed: ManagedControllers
    perception: TargetPerceptionPorts
    loggers: RunLoggers

    def finished(self, settle_time: float) -> DisarmedAfter:
        """Stop condition: `settle_time` s after the mission landed (or the manager gave it up:
        failsafe, emergency landing) and the vehicle disarmed."""
        return landed_and_disarmed(self.mission, self.vehicle, settle_time,
                                   self.managed.manager)


def landing_manager_config(controller: str,
                           config: ControlManagerConfig) -> ControlManagerConfig:
    """The control manager `config` flying `controller` from the start with the take-off tracker
    selected; raises ConfigError when `controller` is not one of the listed controllers or the
    trackers of `LandingRequests` are not listed."""
    if controller not in config.names or controller == config.failsafe_controller:
        allowed = [name for name in config.names if name != config.failsafe_controller]
        raise ConfigError(f"landing controller {controller!r} is not one of the control "
                          f"manager's controllers {allowed}")
    missing = [name for name in LANDING_TRACKERS if name not in config.tracker_names]
    if missing:
        raise ConfigError(f"control manager trackers {config.tracker_names}: the landing "
                          f"mission needs {missing} too")
    return dc.replace(config, initial_controller=controller,
                      initial_tracker=LANDING_TRACKERS[0])


def add_landing_managed(builder: DiagramBuilder, vehicle, mission_params: LandingMissionParams,
                        config: ControlManagerConfig, controller: str,
                        mpc_params: LinearMpcParams, odometry,
                        perception: TargetEstimatorParams,
                        camera_blackouts=(),
                        touchdown: TouchdownLevelParams = TouchdownLevelParams()
                        ) -> LandingManagedOnboard:
    """The landing mission on the managed stack `config` flown by `controller`, on `vehicle`'s
    boundary ports (simulated or MAVLink); `odometry` as in diagrams/onboard/mpc_loop.py
    `add_mpc_control`; the linear MPC controller takes `mpc_params` (the landing tuning); target
    perception `perception` on `down_image`; the manager's command levelled for the `touchdown`
    (diagrams/onboard/landing.py `add_touchdown_level`)."""
    config = landing_manager_config(controller, config)
    controllers_config = dc.replace(config.controller_params, linear_mpc=mpc_params)
    estimate = odometry(builder, vehicle)
    ports = add_down_camera_perception(builder, vehicle, estimate, perception, camera_blackouts)
    mission = builder.AddNamedSystem("mission", LandingMission(mission_params))
    builder.Connect(estimate, mission.GetInputPort("state_estimate"))
    builder.Connect(ports.target_estimate, mission.GetInputPort("target_estimate"))
    builder.Connect(vehicle.GetOutputPort("range"), mission.GetInputPort("range"))
    requests = builder.AddNamedSystem("landing_requests", LandingRequests(
        mission_params, config.tracker_names, *LANDING_TRACKERS))
    builder.Connect(mission.GetOutputPort("mission_status"),
                    requests.GetInputPort("mission_status"))
    builder.Connect(mission.GetOutputPort("arm"), requests.GetInputPort("arm"))
    builder.Connect(mission.GetOutputPort("reference"), requests.GetInputPort("reference"))
    goals = {kind: requests.GetOutputPort(f"{kind}_goal")
             for kind in ("trajectory", "landoff", "target")}
    managed = add_control_manager(builder, config, controllers_config, estimate, goals=goals,
                                  fc_attitude=vehicle.GetOutputPort("fc_attitude"),
                                  target_estimate=ports.target_estimate)
    level = add_touchdown_level(builder, touchdown, mission, config.period)
    builder.Connect(estimate, level.GetInputPort("state_estimate"))
    builder.Connect(ports.target_estimate, level.GetInputPort("target_estimate"))

    def levelled(builder, command):
        builder.Connect(command, level.GetInputPort("fc_command"))
        return level.GetOutputPort("fc_command")

    connect_managed_vehicle(builder, managed, vehicle, mission.GetOutputPort("arm"),
                            requests.GetOutputPort("tracker_request"), odometry, estimate,
                            levelled)
    # "goal": the mission's own L Sec. 6.3 reference, beside the issued one ("reference").
    loggers = add_managed_logging(builder, vehicle, managed, estimate,
                                  mission.GetOutputPort("reference"), config.period,
                                  level.GetOutputPort("fc_command"))
    add_mission_logging(builder, loggers, mission, ports.target_estimate, mission_params.period)
    return LandingManagedOnboard(vehicle, estimate, mission, requests, managed, ports, loggers)
