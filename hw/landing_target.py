"""LANDING_TARGET out (`alight hil`): the target EKF's estimate for PX4's precision landing and the
ground stations, as hw/external_vision.py encodes it (MAV_FRAME_LOCAL_NED, position_valid, the
target in the local frame the ODOMETRY gives PX4). The message has no covariance field: PX4's
landing target estimator uses its own measurement noise (LTEST_MEAS_UNC); the EKF's covariance
stays in the onboard run folder's `target_estimate`."""
import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.hw.external_vision import landing_target_message
from alight.hw.link import MavlinkLink
from alight.hw.mavlink_vehicle import autopilot_time
from alight.systems.boundary import STATE_ESTIMATE, TARGET_ESTIMATE


class LandingTargetSender(LeafSystem):
    """Input `target_estimate` TARGET_ESTIMATE, `state_estimate` STATE_ESTIMATE (both in E)
    Every `period`: a new valid target estimate (with a valid vehicle estimate for the angular
    form) goes to the autopilot as LANDING_TARGET, stamped on its clock. `sent` counts them."""

    def __init__(self, link: MavlinkLink, period: float):
        super().__init__()
        self._link = link
        self._target = self.DeclareVectorInputPort("target_estimate", TARGET_ESTIMATE.size)
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        # A publish event (output to the world): it sees the estimate after this instant's
        # updates, as the run loggers do.
        self.DeclarePeriodicPublishEvent(period, 0.0, self._publish)
        self._last_stamp = -np.inf  # what was sent: not simulation state
        self.sent = 0

    def _publish(self, context):
        target = self._target.Eval(context)
        estimate = self._estimate.Eval(context)
        stamp = TARGET_ESTIMATE.get(target, "stamp")
        t_fc = autopilot_time(self._link, stamp)
        if not (TARGET_ESTIMATE.get(target, "valid") > 0.5 and np.all(np.isfinite(target))
                and STATE_ESTIMATE.get(estimate, "valid") > 0.5
                and np.all(np.isfinite(estimate)) and math.isfinite(t_fc)
                and stamp > self._last_stamp):
            return
        self._link.send(landing_target_message(self._link.mav, target, estimate,
                                               int(round(max(t_fc, 0.0) * 1e6))))
        self.sent += 1
        self._last_stamp = stamp
