"""The onboard side of a waypoint flight on the linear MPC (`alight hil --mission fly`): the
waypoint mission, odometry and `add_mpc_control`, and their logging."""
import dataclasses as dc

import numpy as np

from alight.diagrams.onboard.mpc_loop import MpcLoop, add_mpc_control, add_mpc_logging
from alight.diagrams.running.run_log import RunLoggers
from alight.diagrams.running.simulation import DisarmedAfter, evaluate
from alight.systems.control.linear_model import LinearModelParams
from alight.systems.control.linear_mpc import LinearMpcParams
from alight.systems.managers.control_manager import gave_up
from alight.systems.managers.failsafe_switch import FailsafeSwitchParams
from alight.systems.mission.waypoints import Phase, WaypointMission, WaypointMissionParams


def parse_waypoints(text: str) -> np.ndarray:
    """'0,0,5; 10,0,5' -> array of x,y,z rows; a clear error for anything else."""
    try:
        rows = [[float(v) for v in item.split(",")] for item in text.split(";") if item.strip()]
    except ValueError:
        raise ValueError(f"waypoints must look like '0,0,5; 10,0,5', got {text!r}") from None
    if not rows or any(len(r) != 3 for r in rows) or not np.all(np.isfinite(rows)):
        raise ValueError(f"waypoints must be finite x,y,z triples separated by ';', got {text!r}")
    return np.array(rows)


@dc.dataclass
class WaypointOnboard:
    """Handles to the onboard side of `alight fly` built by `add_waypoint_onboard`."""
    mission: WaypointMission
    loop: MpcLoop
    loggers: RunLoggers

    def finished(self, rest: float = 1.0):
        """Stop condition: `rest` s after the mission landed (or the failsafe took over) and the
        flight controller disarmed."""
        return DisarmedAfter(lambda context: evaluate(self.mission, "phase", context)[0]
                             == Phase.LANDED or gave_up(evaluate(self.loop.switch,
                                                                 "manager_status", context)),
                             self.loop.vehicle, rest)


def add_waypoint_onboard(builder, vehicle, waypoints: np.ndarray,
                         mission: WaypointMissionParams, odometry, mpc_params: LinearMpcParams,
                         model: LinearModelParams, fallback: FailsafeSwitchParams,
                         command_filter=None) -> WaypointOnboard:
    """The onboard side of a waypoint flight on `vehicle`'s boundary ports (simulated or
    MAVLink): the waypoint mission, `odometry` and the linear MPC with its `fallback` to the
    failsafe (`add_mpc_control`, with `command_filter`: fault injection), and their logging."""
    mission_system = builder.AddNamedSystem("mission", WaypointMission(waypoints, mission))
    loop = add_mpc_control(builder, vehicle, mission_system.GetOutputPort("reference"),
                           mission_system.GetOutputPort("arm"), mpc_params, model, odometry,
                           fallback, command_filter=command_filter)
    builder.Connect(loop.state_estimate_port, mission_system.GetInputPort("state_estimate"))
    loggers = add_mpc_logging(builder, loop, mission_system.GetOutputPort("reference"))
    return WaypointOnboard(mission_system, loop, loggers)


def mission_duration(waypoints: np.ndarray, max_duration: float) -> float:
    """A generous time budget: climb, legs at 2 m/s, landing, plus settling."""
    legs = np.linalg.norm(np.diff(waypoints, axis=0), axis=1).sum() if len(waypoints) > 1 else 0.0
    return min(max_duration, 15.0 + np.linalg.norm(waypoints[0]) / 2 + legs / 2.0
               + waypoints[:, 2].max() / 0.6 + 5.0 * len(waypoints))
