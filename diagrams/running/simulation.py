"""Running a diagram: seeding, optional live Meshcat, HTML recording, real-time pacing."""
from pathlib import Path

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.geometry import Meshcat, StartMeshcat
from pydrake.systems.analysis import Simulator

from alight.diagrams.world.visualization import start_recording, write_recording
from alight.systems.boundary import FC_STATUS


def make_meshcat(live: bool, record: str | Path | None) -> Meshcat | None:
    """A Meshcat for a live view (prints its URL) and/or a recording, or None for neither."""
    if not live and record is None:
        return None
    meshcat = StartMeshcat() if live else Meshcat()
    if live:
        print(f"Meshcat: open {meshcat.web_url()} in a browser", flush=True)
    return meshcat


# How often `simulate` asks its stop condition [s]: the mission's rate (DESIGN.md: 20 Hz). A
# Simulator monitor would ask at every step (about 1,000 Python calls per simulated second).
STOP_CHECK_PERIOD = 0.05


def simulate(diagram, duration: float, seed: int, meshcat: Meshcat | None = None,
             record: str | Path | None = None, realtime_rate: float = 0.0,
             stop_when=None, prepare=None) -> Simulator:
    """Seeds every random source from `seed`, lets `prepare(context)` change the seeded context
    (e.g. a body's mass), runs to `duration` (or until `stop_when(context)` is true, asked every
    STOP_CHECK_PERIOD s) and writes the replay if asked."""
    simulator = start_simulation(diagram, seed, meshcat, record, realtime_rate, prepare)
    advance_until(simulator, duration, stop_when)
    finish_recording(meshcat, record)
    return simulator


def advance_until(simulator: Simulator, duration: float, stop_when=None,
                  check_period: float = STOP_CHECK_PERIOD) -> None:
    """Advances `simulator` to `duration`, or to the first multiple of `check_period` at which
    `stop_when(root_context)` is true. Between checks the simulation runs uninterrupted in
    Drake (the same steps and events as one AdvanceTo)."""
    if stop_when is None:
        simulator.AdvanceTo(duration)
        return
    context = simulator.get_context()
    k = int(np.floor(context.get_time() / check_period + 1e-9))
    while context.get_time() < duration:
        k += 1
        simulator.AdvanceTo(min(k * check_period, duration))
        if stop_when(context):
            return


def start_simulation(diagram, seed: int, meshcat: Meshcat | None = None,
                     record: str | Path | None = None, realtime_rate: float = 0.0,
                     prepare=None) -> Simulator:
    """`simulate` up to the first AdvanceTo: an initialized, seeded Simulator (recording when
    `meshcat` and `record` are given), for callers that advance it themselves (`advance_until`
    with a stop condition)."""
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.SetRandomContext(context, RandomGenerator(seed))
    if prepare is not None:
        prepare(context)
    simulator.set_target_realtime_rate(realtime_rate)
    if meshcat is not None and record is not None:
        start_recording(meshcat)
    simulator.Initialize()
    return simulator


def finish_recording(meshcat: Meshcat | None, record: str | Path | None) -> None:
    """Writes the replay `start_simulation` recorded (nothing without both)."""
    if meshcat is not None and record is not None:
        path = write_recording(meshcat, record)
        print(f"Replay written to {path} (open it in a browser; no server needed)", flush=True)


def evaluate(system, port: str, root_context):
    """The value of `system`'s output `port` in a diagram's root context."""
    return system.GetOutputPort(port).Eval(system.GetMyContextFromRoot(root_context))


class DisarmedAfter:
    """Stop condition for `simulate` and `run_realtime`: true `rest` s after the mission first says
    it has landed (`mission_landed(root_context)`) with the vehicle's flight controller disarmed."""

    def __init__(self, mission_landed, vehicle, rest: float):
        self._mission_landed, self._vehicle, self._rest = mission_landed, vehicle, rest
        self.at: float | None = None  # when it first held

    def holds(self, context) -> bool:
        return bool(self._mission_landed(context)) and bool(
            FC_STATUS.get(evaluate(self._vehicle, "fc_status", context), "armed") < 0.5)

    def __call__(self, context) -> bool:
        if self.at is None and self.holds(context):
            self.at = context.get_time()
        return self.at is not None and context.get_time() >= self.at + self._rest
