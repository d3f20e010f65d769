"""The onboard stack in real time (issue 19): records the sensor streams of a landing, then
replays them through the onboard diagram alone and prints what each component costs.

1. Record (once per scenario, duration and sensing; reused when present): the scenario's
   simulated vehicle flies its landing with its own onboard stack (closed loop; `--duration` s or
   until the stack's stop condition, landed and settled), and every
   boundary output the stack reads is recorded as it changes: `imu`, `fc_attitude`,
   `fc_status`, `range`, the forward RGB-D frames (`rgbd`) and the down-camera frames
   (`down_image`),
   plus `ground_truth` for scoring only. The recording lives outside the repository, under
   `$ALIGHT_CACHE` (default `~/.cache/alight`) `/onboard/<scenario hash>/`: frames one pickle
   each (a rendered 30 s landing is a few GB), the small streams in one file.
2. Replay: the same onboard stack (diagrams/stacks.py `add_onboard`) on a `RecordedVehicle`, a
   LeafSystem that exports the vehicle boundary's ports (as the MAVLink vehicle does) and plays
   the recorded streams into them, each value from the simulation time it appeared at; no plant,
   no world, no ground truth. The replay is open loop: the stack's `fc_command` goes nowhere and
   the vehicle flies as recorded (the recorded attitude and status, the recorded images), so the
   mission, the estimators and the MPC see the landing that was flown and do its work.

Per component (every onboard system's `compute_timer`, systems/timing.py, by part) it prints
calls per second of flight, CPU seconds per second of flight, mean / p99 / max time per call
and the typical interval between calls (the component's period: the median of the stamps'
differences), then the rest of the diagram (Drake's dispatch, the systems without a timer: the
mission, the failsafe, logging; the VIO's IMU propagation is its `vio.propagation` row), the
replay's own cost (reading frames), and ends with

    onboard total: X CPU s per s of flight

the whole onboard diagram's CPU time (this thread's, `time.thread_time`) over the replayed
flight, the replay's own reading cost taken out. By default the timers measure CPU time too
(`--clock cpu`: the timing module's clock is this thread's CPU clock in this process), so that
other jobs on a shared machine do not inflate them; `--clock wall` keeps the wall clock they
log in a run folder.

Sensing (`--sensing`): `rendered` (default, the realistic stack: the rendered 1280x1024 down
camera for the detector and target EKF, the rendered RGB-D camera for the VIO) or `geometric`
(both cameras' geometric sources: keypoints, no images; cheap). The odometry is the VIO in
both (`onboard.estimator: vio`).

    python bench/onboard.py [--sensing rendered|geometric] [--duration 30] [--scenario field]
                            [--target-speed V] [--seed S] [--set 'KEY: VALUE' ...]
                            [--clock cpu|wall] [--rerecord] [--recording DIR]
"""
import argparse
import hashlib
import os
import pickle
import shutil
import time
import types
from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import BasicVector, DiagramBuilder, LeafSystem

from alight.diagrams.cli.options import add_scenario_options, args_scenario
from alight.diagrams.running.runner import build
from alight.diagrams.running.simulation import simulate
from alight.diagrams.scenario import dump_scenario, load_scenario
from alight.diagrams.stacks import add_onboard
from alight.systems import timing
from alight.systems.boundary import (FC_ATTITUDE, FC_COMMAND, FC_STATUS, GROUND_TRUTH, RANGE,
                                     STATE_ESTIMATE, TARGET_ESTIMATE, CameraFrame, ImuSamples)
from alight.systems.timing import compute_timers

FORMAT = 2          # of the recording folder; part of its hash (2: with `range`)
SENSING = {"rendered": ["vehicle.down_camera.source: rendered",
                        "onboard.vio_camera.source: rendered"],
           "geometric": ["vehicle.down_camera.source: geometric",
                         "onboard.vio_camera.source: geometric"]}
VECTORS = {"fc_attitude": FC_ATTITUDE, "fc_status": FC_STATUS, "range": RANGE}
FRAMES = ("rgbd", "down_image")
TRUTH_PERIOD = 0.01  # s, ground truth (scoring only)


# --- recording ----------------------------------------------------------------------------------
def _key(value):
    """What identifies a new value of an abstract stream: a frame's stamp, the IMU buffer's
    newest sequence number."""
    if isinstance(value, CameraFrame):
        return value.stamp if np.isfinite(value.stamp) else None
    if isinstance(value, ImuSamples):
        return int(value.seq[-1]) if len(value) else None
    raise TypeError(f"no key for {type(value).__name__}")


class StreamRecorder(LeafSystem):
    """Inputs `imu`, `rgbd`, `down_image` (abstract) and `fc_attitude`, `fc_status`, `range`
    (vectors),
    each recorded at every simulator step where its value changed, with the simulation time it
    appeared at: a per-step publish at the end of a step sees what the updates at the step's
    start made, so a change is stamped with the step's start (the previous step's end); frames are written to `folder/<stream>/<index>.pkl` as they come (`index`:
    the frame's time). Input `ground_truth` is sampled every TRUTH_PERIOD."""

    def __init__(self, folder: Path):
        super().__init__()
        self._folder = folder
        self._abstract = {"imu": self.DeclareAbstractInputPort(
            "imu", AbstractValue.Make(ImuSamples.empty()))}
        for name in FRAMES:
            self._abstract[name] = self.DeclareAbstractInputPort(
                name, AbstractValue.Make(CameraFrame()))
            (folder / name).mkdir(parents=True, exist_ok=True)
        self._vectors = {name: self.DeclareVectorInputPort(name, layout.size)
                         for name, layout in VECTORS.items()}
        self._truth = self.DeclareVectorInputPort("ground_truth", GROUND_TRUTH.size)
        self.times = {name: [] for name in [*self._abstract, *self._vectors]}
        self.values = {name: [] for name in ["imu", *self._vectors]}
        self.truth = ([], [])
        self._last = {}
        self._step_start = 0.0    # when the updates this publish sees took place
        self.DeclarePerStepPublishEvent(self._record)
        self.DeclarePeriodicPublishEvent(TRUTH_PERIOD, 0.0, self._record_truth)

    def _record(self, context):
        t, self._step_start = self._step_start, context.get_time()
        for name, port in self._abstract.items():
            value = port.Eval(context)
            key = _key(value)
            if key is None or key == self._last.get(name):
                continue
            self._last[name] = key
            if name in FRAMES:
                with open(self._folder / name / f"{len(self.times[name])}.pkl", "wb") as f:
                    pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
            else:
                self.values[name].append(value)
            self.times[name].append(t)
        for name, port in self._vectors.items():
            value = port.Eval(context)
            last = self._last.get(name)
            if last is None or not np.array_equal(value, last):
                self._last[name] = value.copy()
                self.values[name].append(value.copy())
                self.times[name].append(t)

    def _record_truth(self, context):
        self.truth[0].append(context.get_time())
        self.truth[1].append(self._truth.Eval(context).copy())

    def save(self, duration: float) -> None:
        streams = {"duration": duration,
                   "times": {name: np.asarray(t) for name, t in self.times.items()},
                   "imu": self.values["imu"],
                   **{name: np.asarray(self.values[name]) for name in VECTORS},
                   "ground_truth": (np.asarray(self.truth[0]), np.asarray(self.truth[1]))}
        with open(self._folder / "streams.pkl", "wb") as f:
            pickle.dump(streams, f, protocol=pickle.HIGHEST_PROTOCOL)


def record(scenario, duration: float, folder: Path):
    """Flies `scenario` for `duration` s (its stack closed loop on the simulated vehicle) and
    records the vehicle's boundary outputs into `folder`; returns the flown stack."""
    builder = DiagramBuilder()
    stack = build(builder, scenario)
    vehicle = builder.GetSubsystemByName("vehicle")
    recorder = builder.AddNamedSystem("stream_recorder", StreamRecorder(folder))
    for name in ["imu", *FRAMES, *VECTORS, "ground_truth"]:
        builder.Connect(vehicle.GetOutputPort(name), recorder.GetInputPort(name))
    diagram = builder.Build()
    simulator = simulate(diagram, duration, scenario.random_seed, stop_when=stack.finished)
    recorder.save(simulator.get_context().get_time())
    (folder / "scenario.yaml").write_text(dump_scenario(scenario))
    (folder / "complete").write_text("1\n")
    return stack


# --- replay -------------------------------------------------------------------------------------
class Recording:
    """A recording folder read back: streams in memory, frames loaded on demand."""

    def __init__(self, folder: Path):
        self.folder = folder
        with open(folder / "streams.pkl", "rb") as f:
            streams = pickle.load(f)
        self.duration = float(streams["duration"])
        self.times = streams["times"]
        self.imu = streams["imu"]
        for name, layout in VECTORS.items():
            if name not in streams:   # a recording from before the stream existed: never valid
                streams[name] = layout.vector(valid=0.0)[None, :]
                self.times[name] = np.zeros(1)
        self.vectors = {name: streams[name] for name in VECTORS}
        self.ground_truth = streams["ground_truth"]

    def frame(self, name: str, index: int) -> CameraFrame:
        with open(self.folder / name / f"{index}.pkl", "rb") as f:
            return pickle.load(f)


def _index(times: np.ndarray, t: float) -> int:
    """The recorded value in force at `t`: the last that appeared strictly before `t` (a value
    that appears at a discrete update at t is seen by the other updates at t only after them, as
    in the simulation), the first one before that, -1 when there is none."""
    return int(np.searchsorted(times, t, side="left")) - 1


class RecordedVehicle(LeafSystem):
    """The vehicle boundary of a recording (DESIGN.md; the MAVLink vehicle's ports, no ground
    truth): outputs `imu`, `fc_attitude`, `fc_status`, `range`, `rgbd`, `down_image`, each the
    recorded
    value in force at the context time; input `fc_command` (open loop: nothing acts on it).
    `reader_seconds` is the CPU time spent loading frames (the replay's, not the stack's)."""

    def __init__(self, recording: Recording):
        super().__init__()
        self._rec = recording
        self._cache = {name: (-1, CameraFrame()) for name in FRAMES}
        self.reader_seconds = 0.0
        self.DeclareVectorInputPort("fc_command", FC_COMMAND.size)
        time_only = {self.time_ticket()}   # the outputs depend on time, not on the command
        self.DeclareAbstractOutputPort("imu", lambda: AbstractValue.Make(ImuSamples.empty()),
                                       self._imu, prerequisites_of_calc=time_only)
        for name, layout in VECTORS.items():
            self.DeclareVectorOutputPort(name, layout.size,
                                         lambda context, output, name=name:
                                         self._vector(name, context, output),
                                         prerequisites_of_calc=time_only)
        for name in FRAMES:
            self.DeclareAbstractOutputPort(name, lambda: AbstractValue.Make(CameraFrame()),
                                           lambda context, output, name=name:
                                           self._frame(name, context, output),
                                           prerequisites_of_calc=time_only)

    def _imu(self, context, output):
        k = _index(self._rec.times["imu"], context.get_time())
        output.set_value(self._rec.imu[k] if k >= 0 else ImuSamples.empty())

    def _vector(self, name, context, output: BasicVector):
        k = max(_index(self._rec.times[name], context.get_time()), 0)
        output.SetFromVector(self._rec.vectors[name][k])

    def _frame(self, name, context, output):
        k = _index(self._rec.times[name], context.get_time())
        index, frame = self._cache[name]
        if k != index:
            start = time.thread_time()
            frame = self._rec.frame(name, k) if k >= 0 else CameraFrame()
            self.reader_seconds += time.thread_time() - start
            self._cache[name] = (k, frame)
        output.set_value(frame)


def replay(scenario, recording: Recording):
    """The scenario's onboard stack on the recording; returns (timers, CPU s of the whole
    replay, the reader's CPU s, the stack)."""
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", RecordedVehicle(recording))
    stack = add_onboard(builder, scenario, vehicle)
    diagram = builder.Build()
    timers = compute_timers(diagram)
    simulator = Simulator(diagram)
    simulator.Initialize()
    start = time.thread_time()
    simulator.AdvanceTo(recording.duration)
    cpu = time.thread_time() - start
    return timers, cpu, vehicle.reader_seconds, stack, simulator


# --- the report ---------------------------------------------------------------------------------
def component_rows(timers: dict, flight: float) -> list[tuple]:
    """(component/part, calls per s, CPU s per s, mean, p99, max [ms], period [ms]) per timed
    part of every component."""
    rows = []
    for name, timer in timers.items():
        for part in timer.parts:
            seconds, stamps = timer.seconds(part), timer.stamps(part)
            period = float(np.median(np.diff(stamps))) if len(stamps) > 1 else np.nan
            label = name if part == "tick" else f"{name}.{part}"
            rows.append((label, len(seconds) / flight, seconds.sum() / flight,
                         1e3 * seconds.mean(), 1e3 * np.percentile(seconds, 99),
                         1e3 * seconds.max(), 1e3 * period))
    return rows


def print_report(rows, flight: float, cpu: float, reader: float, clock: str) -> float:
    print(f"{'component':42s} {'calls/s':>8s} {'CPU s/s':>8s} {'mean ms':>8s} {'p99 ms':>8s} "
          f"{'max ms':>8s} {'period ms':>9s} {'max/period':>10s}")
    for label, rate, load, mean, p99, peak, period in rows:
        print(f"{label:42s} {rate:8.1f} {load:8.3f} {mean:8.2f} {p99:8.2f} {peak:8.2f} "
              f"{period:9.1f} {peak / period:10.2f}")
    timed = sum(row[2] for row in rows) * flight
    onboard = cpu - reader
    print(f"{'timed components (' + clock + ' clock)':42s} {'':8s} {timed / flight:8.3f}")
    print(f"{'rest of the diagram (untimed systems, Drake)':42s} {'':8s} "
          f"{(onboard - timed) / flight:8.3f}")
    print(f"{'replay reader (not onboard, excluded)':42s} {'':8s} {reader / flight:8.3f}")
    return onboard / flight


def accuracy(stack, recording: Recording) -> str:
    """The replay's VIO position error against the recorded ground truth (RMS and final) and
    the share of the target estimates that were valid: the replay did the stack's work."""
    t_truth, truth = recording.ground_truth
    p_truth = truth[:, GROUND_TRUTH.slice("p_WB")]
    vio = stack.loggers.vector_sinks["vio_estimate"][0].take()
    rows = vio[vio[:, 1 + STATE_ESTIMATE.slice("valid").start] > 0.5]
    p = rows[:, 1:][:, STATE_ESTIMATE.slice("p_EB")]
    error = np.linalg.norm(p - np.stack([np.interp(rows[:, 0], t_truth, p_truth[:, k])
                                         for k in range(3)], 1), axis=1)
    target = stack.loggers.vector_sinks["target_estimate"][0].take()
    valid = target[:, 1 + TARGET_ESTIMATE.slice("valid").start] > 0.5
    return (f"VIO position error against ground truth: RMS {np.sqrt(np.mean(error ** 2)):.3f} m, "
            f"final {error[-1]:.3f} m ({len(rows)} valid estimates); target estimate valid "
            f"{100 * valid.mean():.0f} % of {len(valid)} samples")


def cache_folder(scenario, duration: float) -> Path:
    root = Path(os.environ.get("ALIGHT_CACHE", Path.home() / ".cache" / "alight"))
    digest = hashlib.sha256(f"{FORMAT}\n{duration}\n{dump_scenario(scenario)}".encode())
    return root / "onboard" / digest.hexdigest()[:16]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scenario_options(parser, "field", flags=("target_speed", "wind", "gusts"))
    parser.add_argument("--sensing", choices=tuple(SENSING), default="rendered")
    parser.add_argument("--duration", type=float, default=30.0,
                        help="s of the landing recorded and replayed (default 30)")
    parser.add_argument("--clock", choices=("cpu", "wall"), default="cpu",
                        help="what the components' timers measure (default this thread's CPU)")
    parser.add_argument("--rerecord", action="store_true", help="record even if cached")
    parser.add_argument("--recording", type=Path, metavar="DIR",
                        help="replay this recording folder with the scenario it was recorded "
                             "with (its scenario.yaml), whatever the other options say: the "
                             "same streams before and after a change of the stack or models/")
    args = parser.parse_args()
    if args.duration <= 0:
        parser.error("--duration must be positive")
    if args.recording is not None:
        if not (args.recording / "complete").exists():
            parser.error(f"--recording {args.recording}: not a complete recording folder")
        folder, scenario = args.recording, load_scenario(args.recording / "scenario.yaml")
    else:
        scenario = args_scenario(args, ["onboard.estimator: vio", *SENSING[args.sensing]])
        folder = cache_folder(scenario, args.duration)
    if args.recording is None and (args.rerecord or not (folder / "complete").exists()):
        shutil.rmtree(folder, ignore_errors=True)
        print(f"recording {args.duration:g} s of {scenario.name} ({args.sensing}) into {folder}",
              flush=True)
        start = time.perf_counter()
        record(scenario, args.duration, folder)
        print(f"recorded in {time.perf_counter() - start:.0f} s wall", flush=True)
    recording = Recording(folder)
    if args.clock == "cpu":   # the timers of this process measure this thread's CPU time
        timing.time = types.SimpleNamespace(perf_counter=time.thread_time)
    timers, cpu, reader, stack, _ = replay(scenario, recording)
    flight = recording.duration
    sensing = (scenario.vehicle.down_camera.source, scenario.onboard.vio_camera.source)
    print(f"replayed {flight:.1f} s of flight (down camera {sensing[0]}, RGB-D {sensing[1]}, "
          f"VIO odometry, open loop) from {folder}; load average {os.getloadavg()[0]:.2f}")
    total = print_report(component_rows(timers, flight), flight, cpu, reader, args.clock)
    print(accuracy(stack, recording))
    print(f"onboard total: {total:.3f} CPU s per s of flight")


if __name__ == "__main__":
    main()
