"""Time per estimator-bank update (M Sec. 3.5) with 1, 4 and 8 filters, against the 10 ms bank
period, on simulated GNSS / optic-flow / rangefinder messages of a vehicle flying a circle.

    python bench/estimator_bank.py [--seconds 20]

Each bank runs alone in a Simulator (sources + bank, no vehicle); the figure is the wall time
of the bank's update events only (timed inside the process), per update.
"""
import argparse
import dataclasses as dc
import time

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from alight.diagrams.onboard.estimation import add_sampled_sensor, load_bank_params
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
        start = time.perf_counter()
        super()._update(context, state)
        self.seconds += time.perf_counter() - start
        self.updates += 1


def bank_with(num_filters: int):
    params = load_bank_params()
    gnss = next(f for f in params.filters if f.name == "gnss")
    params = dc.replace(params, sources=[s for s in params.sources if s.name != "rtk"],
                        filters=[dc.replace(gnss, name=f"f{i}", frame_id=i)
                                 for i in range(num_filters)],
                        arbiter=dc.replace(params.arbiter, initial="f0"))
    return params


def measure(num_filters: int, seconds: float) -> float:
    builder = DiagramBuilder()
    bank = builder.AddSystem(TimedBank(bank_with(num_filters)))
    truth = builder.AddSystem(Circle())
    builder.Connect(truth.GetOutputPort("fc_attitude"), bank.GetInputPort("fc_attitude"))
    for name, sensor, latency in (
            ("gnss", PositionFix(PositionFixParams()), 0.1),
            ("optic_flow", OpticFlow(OpticFlowParams()), 0.04),
            ("rangefinder", Rangefinder(RangefinderParams()), 0.02)):
        port = add_sampled_sensor(builder, name, sensor, latency,
                                  truth.GetOutputPort("ground_truth"))
        builder.Connect(port, bank.GetInputPort(name))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    diagram.SetRandomContext(simulator.get_mutable_context(), RandomGenerator(0))
    simulator.AdvanceTo(seconds)
    return bank.seconds / bank.updates


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated time per bank")
    args = parser.parse_args()
    period = load_bank_params().period
    print(f"bank update time, {args.seconds:.0f} s simulated at {1 / period:.0f} Hz")
    print("filters  mean per update [ms]  x 1 filter  share of the 10 ms period", flush=True)
    base = None
    for n in (1, 4, 8):
        per_update = measure(n, args.seconds)
        base = base or per_update
        print(f"{n:7d}  {per_update * 1e3:20.3f}  {per_update / base:10.2f}  "
              f"{per_update / period:25.3f}", flush=True)


if __name__ == "__main__":
    main()
