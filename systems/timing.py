"""Compute time of the systems, kept outside the Drake context.

A run folder is reproducible: the same scenario and seed give the same logged streams, bit for bit.
Wall-clock times are not, so no system writes them into its state or its outputs. A system that
measures its own computation owns a `ComputeTimer` as its attribute `compute_timer`: a plain
Python object that records, per measured call, the simulation time, the part of the system
measured and the wall-clock seconds. `compute_timers(diagram)` collects them from a built diagram
and `timing_frame` makes the run folder's `timing` stream of them (docs/run_folder.md), the one
stream a replay may differ in.
"""
import array
import contextlib
import time

import numpy as np
import pandas as pd
from pydrake.systems.framework import Diagram


class ComputeTimer:
    """Wall-clock seconds of the measured calls of one system, each with the simulation time it
    belongs to and the part measured ("tick"; the VIO's "frontend", "backend" and "propagation").

    Like a system's solver workspace it serves one simulation at a time: the records of every
    simulation the system ran accumulate (in compact growing arrays) until `clear()`, which the
    run folder writer calls at every flush once it has written them (diagrams/running/run_log.py).
    """

    def __init__(self):
        self.parts: list[str] = []
        self._stamp = array.array("d")
        self._part = array.array("H")     # index into `parts`
        self._seconds = array.array("d")

    @contextlib.contextmanager
    def measure(self, stamp: float, part: str = "tick"):
        """Records the wall-clock seconds of the `with` body (raising or not) at simulation
        time `stamp` [s]."""
        start = time.perf_counter()
        try:
            yield
        finally:
            self.record(stamp, part, time.perf_counter() - start)

    def clock(self) -> float:
        """The clock `measure` reads [s], for a system that times a part by hand."""
        return time.perf_counter()

    def record(self, stamp: float, part: str, seconds: float) -> None:
        if part not in self.parts:
            self.parts.append(part)
        self._stamp.append(stamp)
        self._part.append(self.parts.index(part))
        self._seconds.append(seconds)

    def __len__(self) -> int:
        return len(self._seconds)

    def seconds(self, part: str | None = None) -> np.ndarray:
        """The recorded durations [s] in call order, of `part` only when given."""
        return np.asarray(self._seconds)[self._select(part)]

    def stamps(self, part: str | None = None) -> np.ndarray:
        """The simulation times [s] of the recorded calls, of `part` only when given."""
        return np.asarray(self._stamp)[self._select(part)]

    def _select(self, part: str | None) -> np.ndarray:
        if part is None:
            return np.ones(len(self), bool)
        if part not in self.parts:
            return np.zeros(len(self), bool)
        return np.asarray(self._part, dtype=int) == self.parts.index(part)

    def frame(self, component: str) -> pd.DataFrame:
        """The records as rows of the `timing` stream: time [s], component, part, seconds."""
        return pd.DataFrame({
            "time": np.asarray(self._stamp), "component": np.full(len(self), component, object),
            "part": np.asarray(self.parts, object)[np.asarray(self._part, dtype=int)],
            "seconds": np.asarray(self._seconds)})

    def clear(self) -> None:
        self.__init__()


def compute_timers(diagram: Diagram, prefix: str = "") -> dict[str, ComputeTimer]:
    """The `compute_timer` of every system in `diagram` (sub-diagrams included), by the
    system's path below it, e.g. "control_manager/controller_mpc"."""
    timers = {}
    for system in diagram.GetSystems():
        name = prefix + system.get_name()
        timer = getattr(system, "compute_timer", None)
        if isinstance(timer, ComputeTimer):
            timers[name] = timer
        if isinstance(system, Diagram):
            timers.update(compute_timers(system, name + "/"))
    return timers


def timing_frame(timers: dict[str, ComputeTimer]) -> pd.DataFrame:
    """The `timing` stream of `timers` (by component name): one row per measured call, in order
    of simulation time (ties in component order)."""
    frames = [timer.frame(name) for name, timer in timers.items() if len(timer)]
    if not frames:
        return ComputeTimer().frame("")
    return pd.concat(frames, ignore_index=True).sort_values("time", kind="stable",
                                                            ignore_index=True)
