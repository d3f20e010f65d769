"""The landing mission (L Sec. 6.4) on the managed stack (M Sec. 7.2): the mission state machine's
mode and arm request turned into the control manager's requests and the trackers' goals.

| mode                | tracker (default) | goal                                          |
|---------------------|-------------------|-----------------------------------------------|
| Idle                | landoff           | none (disarmed)                               |
| Taking Off          | landoff           | take-off to `takeoff_height` at lift-off      |
| Waypoint            | mpc_tracker       | the waypoint at the mission's heading         |
| Follow              | target            | follow at the height held (L Sec. 6.3)        |
| Landing Phase 1 / 2 | target            | descend at `descending_p1` / `descending_p2`  |
| Returning           | mpc_tracker       | the mission's reference: over the take-off    |
| Landing Home        | landoff           | land                                          |
| Landed              | (unchanged)       | disarm                                        |

The tracker request's id is the mission's transition count plus one: every mode change is a new
request (the control manager ignores a request for the tracker already active). The mission's
`arm` output [arm, thrust enable] goes to the control manager as it is (rotors idle for
`arm_time`, then flying; Landed disarms); the take-off goal is given once thrust is enabled.
Outputs are functions of the inputs (the mission's state outputs): no state.
"""
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import REFERENCE
from alight.systems.mission.landing import MISSION_STATUS, LandingMissionParams, Mode, Reason
from alight.systems.tracking.goal import TrackerGoal
from alight.systems.tracking.landoff_tracker import LandoffGoal
from alight.systems.tracking.target_tracker import TargetGoal


class LandingRequests(LeafSystem):
    """Inputs  `mission_status` MISSION_STATUS; `arm` (2) [arm request, thrust enable];
            `reference` REFERENCE of the mission (alight.systems.mission.landing.LandingMission):
            its position is the Returning goal
    Outputs `tracker_request` (2) [id, index] for the control manager; `trajectory_goal`
            TrackerGoal, `landoff_goal` LandoffGoal or None, `target_goal` TargetGoal or None
            (abstract) for the trackers of those goal kinds
    `trackers`: the control manager's tracker list (requests name them by index).
    """

    def __init__(self, params: LandingMissionParams, trackers: list[str],
                 takeoff_tracker: str = "landoff", waypoint_tracker: str = "mpc_tracker",
                 target_tracker: str = "target"):
        super().__init__()
        chosen = {"takeoff_tracker": takeoff_tracker, "waypoint_tracker": waypoint_tracker,
                  "target_tracker": target_tracker}
        for key, name in chosen.items():
            if name not in trackers:
                raise ValueError(f"landing requests: {key} {name!r} is not one of the control "
                                 f"manager's trackers {list(trackers)}")
        index = {key: float(trackers.index(name)) for key, name in chosen.items()}
        self._tracker = {Mode.IDLE: index["takeoff_tracker"],
                         Mode.TAKING_OFF: index["takeoff_tracker"],
                         Mode.WAYPOINT: index["waypoint_tracker"],
                         Mode.FOLLOW: index["target_tracker"],
                         Mode.LANDING_P1: index["target_tracker"],
                         Mode.LANDING_P2: index["target_tracker"],
                         Mode.LANDED: index["target_tracker"],
                         Mode.RETURNING: index["waypoint_tracker"],
                         Mode.LANDING_HOME: index["takeoff_tracker"]}
        self._waypoint = TrackerGoal.point(params.waypoint, np.radians(params.heading))
        self._takeoff = LandoffGoal.takeoff(params.takeoff_height)
        self._landing = LandoffGoal.land()
        self._target = {Mode.FOLLOW: TargetGoal.follow(),
                        Mode.LANDING_P1: TargetGoal.descend(params.descending_p1),
                        Mode.LANDING_P2: TargetGoal.descend(params.descending_p2)}
        self._status = self.DeclareVectorInputPort("mission_status", MISSION_STATUS.size)
        self._arm = self.DeclareVectorInputPort("arm", 2)
        self._reference = self.DeclareVectorInputPort("reference", REFERENCE.size)
        self._heading = np.radians(params.heading)
        self.DeclareVectorOutputPort("tracker_request", 2, self._calc_tracker_request)
        self.DeclareAbstractOutputPort("trajectory_goal", lambda: AbstractValue.Make(None),
                                       self._calc_trajectory_goal)
        self.DeclareAbstractOutputPort("landoff_goal", lambda: AbstractValue.Make(None),
                                       self._calc_landoff_goal)
        self.DeclareAbstractOutputPort("target_goal", lambda: AbstractValue.Make(None),
                                       lambda c, o: o.set_value(self._target.get(self._mode(c))))

    def _mode(self, context) -> Mode:
        return Mode(int(MISSION_STATUS.get(self._status.Eval(context), "mode")))

    def _calc_tracker_request(self, context, output):
        status = self._status.Eval(context)
        mode = self._mode(context)
        home = mode == Mode.LANDED \
            and float(MISSION_STATUS.get(status, "reason")) == Reason.ON_THE_GROUND
        output.SetFromVector([MISSION_STATUS.get(status, "transitions") + 1.0,
                              self._tracker[Mode.LANDING_HOME] if home else self._tracker[mode]])

    def _calc_trajectory_goal(self, context, output):
        if self._mode(context) != Mode.RETURNING:
            return output.set_value(self._waypoint)
        home = REFERENCE.get(self._reference.Eval(context), "p")
        output.set_value(TrackerGoal.point(home, self._heading) if np.all(np.isfinite(home))
                         else self._waypoint)

    def _calc_landoff_goal(self, context, output):
        mode = self._mode(context)
        if mode in (Mode.LANDING_HOME, Mode.LANDED):
            return output.set_value(self._landing if mode == Mode.LANDING_HOME else None)
        lift_off = mode >= Mode.TAKING_OFF and self._arm.Eval(context)[1] > 0.5
        output.set_value(self._takeoff if lift_off else None)
