"""The onboard odometry source over the local channel: the simulated world's mocap estimate
(DESIGN.md: `mocap`, true pose plus noise and latency, computed by `alight sim-autopilot`) read
from the frame channel (hw/frame_channel.py), as a mocap system streams poses to the companion
computer beside the flight controller's link. It is the `odometry` of `add_mpc_control` for
`alight hil --mission fly|land`: the MAVLink vehicle has no ground truth to build mocap from.
"""
import dataclasses as dc
import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.hw.frame_channel import EstimateSample, FrameSubscriber
from alight.hw.link import MavlinkLink
from alight.systems.boundary import STATE_ESTIMATE
from alight.systems.params import bounded


@dc.dataclass
class ChannelOdometryParams:
    period: float = bounded(0.005, 0.001, 0.1, "s")   # how often the channel is read
    timeout: float = bounded(0.2, 0.01, 5.0, "s")     # older than this: the estimate is invalid
    source: str = "mocap"                            # the channel item's name


class ChannelOdometry(LeafSystem):
    """Output `state_estimate` STATE_ESTIMATE: the newest valid estimate named `source` on the
    channel, its stamp mapped from the autopilot's clock to ours (TIMESYNC). `valid` is 0 before
    the first sample and whenever the newest is older than `timeout` (a stopped source)."""

    def __init__(self, subscriber: FrameSubscriber, link: MavlinkLink,
                 params: ChannelOdometryParams):
        super().__init__()
        self._subscriber, self._link, self._params = subscriber, link, params
        initial = STATE_ESTIMATE.vector(valid=0.0)  # invalid until the first sample
        self._xd = self.DeclareDiscreteState(initial)
        self.DeclarePeriodicDiscreteUpdateEvent(params.period, 0.0, self._update)
        self.DeclareStateOutputPort("state_estimate", self._xd)

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._xd).get_value().copy()
        sample = self._subscriber.latest(self._params.source)
        if isinstance(sample, EstimateSample) and sample.valid:
            stamp = self._link.to_local(sample.stamp)
            if math.isfinite(stamp) and stamp > STATE_ESTIMATE.get(x, "stamp"):
                x = np.array(sample.value, dtype=float)
                x[STATE_ESTIMATE.slice("stamp")] = stamp
        if context.get_time() - STATE_ESTIMATE.get(x, "stamp") > self._params.timeout:
            x[STATE_ESTIMATE.slice("valid")] = 0.0
        discrete_state.set_value(self._xd, x)


def channel_odometry(subscriber: FrameSubscriber, link: MavlinkLink,
                     params: ChannelOdometryParams):
    """The `odometry` hook of `add_mpc_control` reading the channel's mocap."""
    def odometry(builder, vehicle):
        source = builder.AddNamedSystem("channel_odometry", ChannelOdometry(
            subscriber, link, params))
        return source.get_output_port()
    return odometry
