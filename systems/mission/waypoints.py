"""A waypoint mission: take off, visit waypoints in order, land where the last one is, disarm.

Outputs a REFERENCE (position, zero velocity; landing: a position descending at `land_speed`) and an
arm request. A waypoint counts as reached within `acceptance_radius` and below `acceptance_speed`.
"""
import dataclasses as dc
import enum

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import REFERENCE, STATE_ESTIMATE
from alight.systems.params import bounded


@dc.dataclass
class WaypointMissionParams:
    period: float = bounded(0.05, 0.005, 1.0, "s")          # 20 Hz (DESIGN.md: mission rate)
    takeoff_height: float = bounded(2.0, 0.5, 100.0, "m")   # first climb, above the start
    acceptance_radius: float = bounded(0.3, 0.05, 10.0, "m")
    acceptance_speed: float = bounded(0.5, 0.05, 10.0, "m/s")
    land_speed: float = bounded(0.6, 0.1, 3.0, "m/s")
    landed_height: float = bounded(0.1, 0.0, 2.0, "m")      # above the start height: disarm
    start_delay: float = bounded(1.0, 0.0, 60.0, "s")       # wait for the estimate, then arm
    arm_time: float = bounded(0.5, 0.0, 10.0, "s")          # rotors idle before take-off
    heading: float = bounded(0.0, -360.0, 360.0, "deg")


class Phase(enum.IntEnum):
    WAIT = 0
    ARMING = 1     # arm request on, thrust held at zero (the flight controller arms at low thrust)
    TAKEOFF = 2
    WAYPOINT = 3
    LAND = 4
    LANDED = 5


class WaypointMission(LeafSystem):
    """Input  `state_estimate` STATE_ESTIMATE
    Outputs `reference` REFERENCE, `arm` (2: arm request, thrust enable), `phase` (Phase, index)
    """

    def __init__(self, waypoints: np.ndarray, params: WaypointMissionParams):
        super().__init__()
        self._waypoints = np.atleast_2d(np.asarray(waypoints, float))
        if self._waypoints.shape[1] != 3 or not np.all(np.isfinite(self._waypoints)):
            raise ValueError(f"waypoints must be finite x,y,z triples, got {waypoints!r}")
        self._p = params
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        # [phase, waypoint index, reference p (3), start p (3), phase start time]
        self._xd = self.DeclareDiscreteState(np.zeros(9))
        self.DeclarePeriodicDiscreteUpdateEvent(params.period, 0.0, self._update)
        self.DeclareVectorOutputPort("reference", REFERENCE.size, self._calc_reference,
                                     prerequisites_of_calc={self.xd_ticket()})
        self.DeclareVectorOutputPort(
            "arm", 2, lambda c, o: o.SetFromVector([
                float(Phase.ARMING <= self._phase(c) <= Phase.LAND),
                float(Phase.TAKEOFF <= self._phase(c) <= Phase.LAND)]),
            prerequisites_of_calc={self.xd_ticket()})
        self.DeclareVectorOutputPort(
            "phase", 2, lambda c, o: o.SetFromVector(c.get_discrete_state(self._xd).get_value()[:2]),
            prerequisites_of_calc={self.xd_ticket()})

    def _phase(self, context) -> Phase:
        return Phase(int(context.get_discrete_state(self._xd).get_value()[0]))

    def _calc_reference(self, context, output):
        x = context.get_discrete_state(self._xd).get_value()
        velocity = np.zeros(3)
        if self._phase(context) == Phase.LAND:
            velocity[2] = -self._p.land_speed
        output.SetFromVector(REFERENCE.pack(
            stamp=context.get_time(), p=x[2:5], v=velocity, a=np.zeros(3), j=np.zeros(3),
            heading=np.radians(self._p.heading), heading_rate=0.0))

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._xd).get_value().copy()
        estimate = self._estimate.Eval(context)
        p = STATE_ESTIMATE.get(estimate, "p_EB")
        v = STATE_ESTIMATE.get(estimate, "v_EB")
        phase, index = Phase(int(x[0])), int(x[1])
        reached = lambda target: (np.linalg.norm(p - target) < self._p.acceptance_radius
                                  and np.linalg.norm(v) < self._p.acceptance_speed)
        if phase == Phase.WAIT:
            x[2:5] = x[5:8] = p
            if context.get_time() >= self._p.start_delay and STATE_ESTIMATE.get(estimate,
                                                                                "valid") > 0.5:
                phase, x[8] = Phase.ARMING, context.get_time()
        elif phase == Phase.ARMING:
            x[2:5] = x[5:8] = p
            if context.get_time() >= x[8] + self._p.arm_time:
                phase = Phase.TAKEOFF
                x[2:5] = p + [0.0, 0.0, self._p.takeoff_height]
        elif phase == Phase.TAKEOFF and reached(x[2:5]):
            phase, index = Phase.WAYPOINT, 0
            x[2:5] = self._waypoints[0]
        elif phase == Phase.WAYPOINT and reached(x[2:5]):
            if index + 1 < len(self._waypoints):
                index += 1
                x[2:5] = self._waypoints[index]
            else:
                phase = Phase.LAND
        elif phase == Phase.LAND:
            x[4] = max(x[4] - self._p.land_speed * self._p.period, x[7] - 1.0)
            if p[2] < x[7] + self._p.landed_height and abs(v[2]) < 0.2:
                phase = Phase.LANDED
        x[0], x[1] = phase, index
        discrete_state.set_value(self._xd, x)
