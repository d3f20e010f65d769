"""Running a diagram: seeding, optional live Meshcat, HTML recording, real-time pacing."""
from pathlib import Path

from pydrake.common import RandomGenerator
from pydrake.geometry import Meshcat, StartMeshcat
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import EventStatus

from alight.diagrams.visualization import start_recording, write_recording


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
    simulator.AdvanceTo(duration)
    if meshcat is not None and record is not None:
        path = write_recording(meshcat, record)
        print(f"Replay written to {path} (open it in a browser; no server needed)", flush=True)
    return simulator
