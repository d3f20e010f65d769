"""Running a diagram: seeding, optional live Meshcat, HTML recording, real-time pacing."""
from pathlib import Path

from pydrake.common import RandomGenerator
from pydrake.geometry import Meshcat, StartMeshcat
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import EventStatus

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


def simulate(diagram, duration: float, seed: int, meshcat: Meshcat | None = None,
             record: str | Path | None = None, realtime_rate: float = 0.0,
             stop_when=None, prepare=None) -> Simulator:
    """Seeds every random source from `seed`, lets `prepare(context)` change the seeded context
    (e.g. a body's mass), runs to `duration` (or until `stop_when(context)` is true) and writes
    the replay if asked."""
    simulator = start_simulation(diagram, seed, meshcat, record, realtime_rate, stop_when,
                                 prepare)
    simulator.AdvanceTo(duration)
    finish_recording(meshcat, record)
    return simulator


def start_simulation(diagram, seed: int, meshcat: Meshcat | None = None,
                     record: str | Path | None = None, realtime_rate: float = 0.0,
                     stop_when=None, prepare=None) -> Simulator:
    """`simulate` up to the first AdvanceTo: an initialized, seeded Simulator (recording when
    `meshcat` and `record` are given), for callers that advance it themselves."""
    simulator = Simulator(diagram)
    if stop_when is not None:
        simulator.set_monitor(lambda context: EventStatus.ReachedTermination(
            diagram, "done") if stop_when(context) else EventStatus.Succeeded())
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
