"""Time per estimator-bank update (M Sec. 3.5) with 1, 4 and 8 filters, against the 10 ms bank
period, on simulated GNSS / optic-flow / rangefinder messages of a vehicle flying a circle.

    python bench/estimator_bank.py [--seconds 20]

Each bank runs alone in a Simulator (sources + bank, no vehicle); the figure is the CPU time
(this thread's, `time.thread_time`: other jobs on a shared machine do not inflate it) of the
bank's update events only, per update, with the ratio to the one-filter bank measured in the
same process; and the bank's cost in the simulation (the whole simulation's CPU minus that of the
sources alone), which adds Drake's dispatch and its copy of the bank's abstract state.
"""
import argparse
import dataclasses as dc
import os
import time

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from alight.diagrams.onboard.estimation import load_bank_params
from alight.systems.sensors.sampled import add_sampled_sensor
from alight.systems.boundary import FC_ATTITUDE, GROUND_TRUTH
from alight.systems.estimation.bank import EstimatorBank
from alight.systems.sensors.optic_flow import OpticFlow, OpticFlowParams
from alight.systems.sensors.position_fix import PositionFix, PositionFixParams
from alight.systems.sensors.rangefinder import Rangefinder, RangefinderParams
from alight.systems.rotations import heading_quaternion


class Circle(LeafSystem):
    """ground_truth and fc_attitude of a level vehicle on a 5 m circle at 2 m/s, 3 m high."""

    def __init__(self):
        super().__init__()
        self.DeclareVectorOutputPort("ground_truth", GROUND_TRUTH.size, self._truth)
        self.DeclareVectorOutputPort("fc_attitude", FC_ATTITUDE.size, self._attitude)

    def _truth(self, context, output):
        t = context.get_time()
        w = 2.0 / 5.0
        output.SetFromVector(GROUND_TRUTH.pack(
            p_WB=[5 * np.cos(w * t), 5 * np.sin(w * t), 3.0], q_WB=heading_quaternion(w * t),
            v_WB=[-2 * np.sin(w * t), 2 * np.cos(w * t), 0.0], w_WB_B=[0, 0, w], v_WA=0.0,
            motor_command=0.0, rotor_thrust=0.0))

    def _attitude(self, context, output):
        t = context.get_time()
        output.SetFromVector(FC_ATTITUDE.pack(stamp=t, q_WB=heading_quaternion(0.4 * t),
                                              w_B=[0, 0, 0.4]))


class TimedBank(EstimatorBank):
    def __init__(self, params):
        super().__init__(params)
        self.seconds, self.updates = 0.0, 0

    def _update(self, context, state):
        start = time.thread_time()
        super()._update(context, state)
        self.seconds += time.thread_time() - start
        self.updates += 1


def bank_with(num_filters: int):
    params = load_bank_params()
    gnss = next(f for f in params.filters if f.name == "gnss")
    params = dc.replace(params, sources=[s for s in params.sources if s.name != "rtk"],
                        filters=[dc.replace(gnss, name=f"f{i}", frame_id=i)
                                 for i in range(num_filters)],
                        arbiter=dc.replace(params.arbiter, initial="f0"))
    return params


def simulate(num_filters: int | None, seconds: float, bank_class=None) -> tuple:
    """The sources (and with `num_filters`, the bank of that many filters) simulated for
    `seconds`: (the bank, or None; this thread's CPU s of the whole simulation)."""
    builder = DiagramBuilder()
    bank = None if num_filters is None else builder.AddSystem(
        (bank_class or TimedBank)(bank_with(num_filters)))
    truth = builder.AddSystem(Circle())
    if bank is not None:
        builder.Connect(truth.GetOutputPort("fc_attitude"), bank.GetInputPort("fc_attitude"))
    for name, sensor, latency in (
            ("gnss", PositionFix(PositionFixParams()), 0.1),
            ("optic_flow", OpticFlow(OpticFlowParams()), 0.04),
            ("rangefinder", Rangefinder(RangefinderParams()), 0.02)):
        port = add_sampled_sensor(builder, name, sensor, latency,
                                  truth.GetOutputPort("ground_truth"))
        if bank is not None:
            builder.Connect(port, bank.GetInputPort(name))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    diagram.SetRandomContext(simulator.get_mutable_context(), RandomGenerator(0))
    simulator.Initialize()
    start = time.thread_time()
    simulator.AdvanceTo(seconds)
    return bank, time.thread_time() - start


def measure(num_filters: int, seconds: float, sources_cpu: float) -> tuple[float, float]:
    """Per update: the bank's update event alone, and the bank in the simulation (the whole
    simulation's CPU minus that of the sources alone, `sources_cpu`: with Drake's dispatch and
    its copy of the bank's state)."""
    bank, cpu = simulate(num_filters, seconds)
    return bank.seconds / bank.updates, (cpu - sources_cpu) / bank.updates


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated time per bank")
    args = parser.parse_args()
    period = load_bank_params().period
    print(f"bank update CPU time, {args.seconds:.0f} s simulated at {1 / period:.0f} Hz "
          f"(load average {os.getloadavg()[0]:.2f})")
    print("filters  update [ms]  x 1 filter  share of 10 ms  in the simulation [ms]", flush=True)
    _, sources_cpu = simulate(None, args.seconds)
    base = None
    for n in (1, 4, 8):
        per_update, in_simulation = measure(n, args.seconds, sources_cpu)
        base = base or per_update
        print(f"{n:7d}  {per_update * 1e3:11.3f}  {per_update / base:10.2f}  "
              f"{per_update / period:14.3f}  {in_simulation * 1e3:22.3f}", flush=True)


if __name__ == "__main__":
    main()
