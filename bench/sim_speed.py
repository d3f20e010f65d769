"""Simulation speed: hover and whole landing missions, with a per-system table (issue 18).

For each case it prints the simulated time, this process's CPU time per simulated second (the
figure to compare on a shared machine: other jobs stretch the wall time, not the CPU time), the
real-time factor (simulated / wall time), the simulator's steps and the CPU time per step; and,
as the in-process reference, the same figures for the bare MultibodyPlant of the hexacopter (same
model, SAP contact and step, no rotors, controllers or sensors) and of the landing world (the
hexacopter, the ground and the car on its PD-driven joints), with the ratios.

Cases (`--cases`, default hover,land,vio; `--rendered` adds `rendered`):
- `hover`: the simulated vehicle flown by a scripted pilot (arm, climb to 2 m, hover), no logging;
- `land`: `alight land --target-speed 2 --seed 0 --estimator mocap` (field scenario, geometric
  camera, mocap: the issue's reference case), the
  whole mission as the runner flies it: build, simulate to the stop condition, write the run
  folder (build and writing are printed apart and amortized in the "whole" figure);
- `vio`: the same on VIO (the scenario's default odometry, the geometric RGB-D source);
- `rendered`: the same with the rendered down camera (`vehicle.down_camera.source: rendered`,
  mocap; slow);
- `managed`: the same mission on the managed stack (control manager, trackers, linear MPC through
  the manager; `onboard.stack: landing_managed`, mocap), only when named in `--cases`;
- each mission case also prints its diagram's leaf systems, Python and C++;
- `floor`: what a Python LeafSystem costs Drake's simulator at every plant step even when it
  computes nothing (the bare hexacopter plant beside 25 idle Python systems, one output port
  each, against 25 idle C++ ones): after every unrestricted update the Simulator asks each leaf
  system for its witness functions, pydrake's trampoline looks for a Python override of
  `DoGetWitnessFunctions` on each Python one, and the plant's step is an unrestricted update when
  its output ports are sampled (the vehicle's plant); printed with the plant's sampled ports and
  without. Only when named in `--cases`.

With `--profile` (default) each case is flown a second time with every Python LeafSystem callback
(output calculations, update and publish events, the runner's stop monitor) wrapped by a
counter/CPU timer, installed before the diagram is built, and the `--top` systems are printed
with their calls and CPU time per simulated second (exclusive: a callback's time excludes the
Python callbacks it evaluates, but includes the C++ it evaluates, e.g. the plant's kinematics
when it is the first to ask for a body pose). The figures above the table come from the
unprofiled run.

    python bench/sim_speed.py [--cases hover,land,vio] [--rendered] [--target-speed 2]
                              [--seed 0] [--set 'KEY: VALUE' ...] [--top 10] [--no-profile]
                              [--callbacks]
"""
import argparse
import dataclasses as dc
import os
import shutil
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem

CASES = ("hover", "land", "vio", "rendered", "managed", "floor")
# (mocap named: VIO is the field scenario's default odometry; these cases keep their sensing)
CASE_OVERRIDES = {"land": ["onboard.estimator: mocap"], "vio": ["onboard.estimator: vio"],
                  "rendered": ["vehicle.down_camera.source: rendered", "onboard.estimator: mocap"],
                  "managed": ["onboard.stack: landing_managed", "onboard.estimator: mocap"]}


# --- the per-system profiler ------------------------------------------------------------------
_DECLARATIONS = ("DeclareVectorOutputPort", "DeclareAbstractOutputPort",
                 "DeclarePeriodicDiscreteUpdateEvent", "DeclarePeriodicUnrestrictedUpdateEvent",
                 "DeclarePeriodicPublishEvent", "DeclarePerStepPublishEvent",
                 "DeclareInitializationDiscreteUpdateEvent",
                 "DeclareInitializationUnrestrictedUpdateEvent",
                 "DeclareInitializationPublishEvent", "DeclareForcedPublishEvent",
                 "DeclareForcedDiscreteUpdateEvent", "DeclareForcedUnrestrictedUpdateEvent",
                 "DeclareCacheEntry")


class SystemProfiler:
    """Counts the calls and the exclusive CPU time of every Python callback of the LeafSystems
    built while it is installed (`with profiler.installed(): build...`), per system."""

    def __init__(self):
        self.calls = defaultdict(int)        # key (system id, label) -> calls
        self.seconds = defaultdict(float)    # key -> exclusive CPU seconds
        self.systems = {}                    # system id -> system (kept alive)
        self._stack = []                     # [key, start] of the callbacks being run
        self._clock = time.thread_time

    def wrap(self, key, callback):
        calls, seconds, stack, clock = self.calls, self.seconds, self._stack, self._clock

        def timed(*args, **kwargs):
            now = clock()
            if stack:
                parent = stack[-1]
                seconds[parent[0]] += now - parent[1]
            frame = [key, now]
            stack.append(frame)
            try:
                return callback(*args, **kwargs)
            finally:
                end = clock()
                seconds[key] += end - frame[1]
                calls[key] += 1
                stack.pop()
                if stack:
                    stack[-1][1] = end
        return timed

    def installed(self):
        profiler = self

        class _Installed:
            def __enter__(self):
                self.saved = {name: getattr(LeafSystem, name) for name in _DECLARATIONS
                              if hasattr(LeafSystem, name)}
                for name, original in self.saved.items():
                    setattr(LeafSystem, name, profiler._patched(name, original))

            def __exit__(self, *exc):
                for name, original in self.saved.items():
                    setattr(LeafSystem, name, original)
        return _Installed()

    def _patched(self, declaration, original):
        profiler = self

        def declare(system, *args, **kwargs):
            profiler.systems[id(system)] = system
            label = declaration.replace("Declare", "")
            args = [profiler.wrap((id(system), f"{label}:{_callback_name(a)}"), a)
                    if callable(a) and not isinstance(a, type) else a for a in args]
            kwargs = {k: profiler.wrap((id(system), f"{label}:{_callback_name(v)}"), v)
                      if callable(v) and not isinstance(v, type) else v
                      for k, v in kwargs.items()}
            return original(system, *args, **kwargs)
        return declare

    def per_system(self, root, callbacks: bool = False) -> list[tuple[str, str, int, float]]:
        """(path below `root`, class, calls, exclusive CPU seconds) per system, slowest first;
        with `callbacks`, per callback of each system (the class column then names the
        callback: its kind and function, e.g. PeriodicDiscreteUpdateEvent:_update)."""
        calls, seconds = defaultdict(int), defaultdict(float)
        for (sid, label), n in self.calls.items():
            key = (sid, label) if callbacks else (sid, None)
            calls[key] += n
            seconds[key] += self.seconds[(sid, label)]
        rows = []
        for sid, label in calls:
            system = self.systems.get(sid)
            rows.append((_path(system, root), label or _class(system), calls[(sid, label)],
                         seconds[(sid, label)]))
        return sorted(rows, key=lambda r: -r[3])

    def overhead_per_call(self) -> float:
        """CPU seconds the wrapper itself adds to one call (measured on a no-op)."""
        probe = SystemProfiler()
        noop = probe.wrap(("probe", "noop"), lambda: None)
        n = 20000
        start = time.thread_time()
        for _ in range(n):
            noop()
        wrapped = time.thread_time() - start
        start = time.thread_time()
        plain = lambda: None  # noqa: E731
        for _ in range(n):
            plain()
        return max(wrapped - (time.thread_time() - start), 0.0) / n


def _callback_name(callback) -> str:
    return getattr(callback, "__name__", type(callback).__name__)


def _class(system) -> str:
    return "-" if isinstance(system, str) else type(system).__name__ if system is not None \
        else "?"


def _path(system, root) -> str:
    if system is None:
        return "?"
    if isinstance(system, str):
        return system
    path = system.GetSystemPathname()
    prefix = root.GetSystemPathname() if root is not None else ""
    return path[len(prefix):].lstrip(":") if path.startswith(prefix) else path


# --- measured runs ------------------------------------------------------------------------------
@dc.dataclass
class Measurement:
    name: str
    simulated: float             # s
    wall: float                  # s, AdvanceTo
    cpu: float                   # s, AdvanceTo (this process)
    steps: int
    build_cpu: float = 0.0       # s, building the diagram (and the scenario)
    write_cpu: float = 0.0       # s, writing the run folder
    outcome: str = ""
    table: list = dc.field(default_factory=list)
    profiled_cpu: float = 0.0    # s, AdvanceTo of the profiled run
    per_callback: bool = False   # the table's rows are callbacks (--callbacks), not systems
    overhead: float = 0.0        # s, the profiler's own estimated cost in that run
    callbacks: int = 0
    leaves: tuple = ()           # (Python, C++) leaf systems of the diagram

    def line(self) -> str:
        whole = (self.cpu + self.build_cpu + self.write_cpu) / self.simulated
        return (f"{self.name:34s} sim {self.simulated:6.2f} s  CPU {self.cpu:6.2f} s = "
                f"{self.cpu / self.simulated:6.3f} CPU s/sim s (whole run {whole:6.3f})  "
                f"real-time factor {self.simulated / self.wall:6.2f}  steps "
                f"{self.steps / self.simulated:6.0f}/sim s  {1e6 * self.cpu / self.steps:6.1f} "
                f"CPU us/step" + (f"  [build {self.build_cpu:.2f} s, write "
                                   f"{self.write_cpu:.2f} s CPU]" if self.build_cpu else ""))


def advance(diagram, duration: float, seed: int = 0, stop_when=None):
    """(wall, CPU, steps, simulated, simulator) of simulating `diagram` to `duration` or
    `stop_when` as the runner does (seeding and initialization included)."""
    from alight.diagrams.running.simulation import simulate
    start, start_cpu = time.perf_counter(), time.process_time()
    simulator = simulate(diagram, duration, seed, stop_when=stop_when)
    return (time.perf_counter() - start, time.process_time() - start_cpu,
            simulator.get_num_steps_taken(), simulator.get_context().get_time(), simulator)


def hover_profile(duration: float):
    from alight.systems.control.scripted_pilot import PilotProfile, ProfileSegment
    takeoff = [ProfileSegment(0.5, vertical_acceleration=-9.81),
               ProfileSegment(2.0, vertical_acceleration=1.0),
               ProfileSegment(2.0, vertical_acceleration=-1.0)]
    rest = duration - sum(s.duration for s in takeoff)
    return PilotProfile(segments=takeoff + [ProfileSegment(rest)])


def hover_diagram(duration: float):
    from alight.diagrams.onboard.pilot import pilot_model
    from alight.diagrams.world.sim_vehicle import load_sim_vehicle_config, make_sim_vehicle
    from alight.systems.control.scripted_pilot import ScriptedPilot
    config = load_sim_vehicle_config()
    builder = DiagramBuilder()
    vehicle = builder.AddSystem(make_sim_vehicle(config))
    pilot = builder.AddSystem(ScriptedPilot(hover_profile(duration), pilot_model(config.airframe)))
    builder.Connect(pilot.get_output_port(), vehicle.GetInputPort("fc_command"))
    return builder.Build()


def bare_plant_diagram(with_world: bool = False):
    """The hexacopter's MultibodyPlant alone (same model, contact, step: it falls freely, no
    contact); with `with_world`, the landing world's plant in free flight: plus the ground and
    the car, its joints held by their PD drive at the start pose, gravity off so that the
    hexacopter stays in the air (no contact) as it does for most of a mission."""
    from alight.diagrams.world.ground import add_ground
    from alight.diagrams.world.sim_vehicle import load_sim_vehicle_config
    from alight.systems.plant.hexacopter import add_hexacopter
    config = load_sim_vehicle_config()
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(
        time_step=config.time_step, discrete_contact_approximation="sap",
        contact_model="point"), builder)  # as make_sim_vehicle's plant
    add_hexacopter(plant, config.airframe)
    car = None
    if with_world:
        from alight.systems.target.vehicle import add_target_vehicle, load_target_params
        add_ground(plant, config.ground_friction, True)
        car = add_target_vehicle(plant, dc.replace(load_target_params(), profile="straight"))
        plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, 0.0])
    plant.Finalize()
    if car is not None:
        from pydrake.systems.primitives import ConstantVectorSource, Multiplexer
        from alight.systems.target.vehicle import target_drive
        target = load_target_params()
        desired = builder.AddSystem(ConstantVectorSource(np.array(
            [*target.initial_position, np.radians(target.initial_heading), 0.0, 0.0, 0.0])))
        drive_input = builder.AddSystem(Multiplexer([6, plant.num_multibody_states()]))
        drive = builder.AddSystem(target_drive(plant, car))
        builder.Connect(desired.get_output_port(), drive_input.get_input_port(0))
        builder.Connect(plant.get_state_output_port(), drive_input.get_input_port(1))
        builder.Connect(drive_input.get_output_port(), drive.get_input_port())
        builder.Connect(drive.get_output_port(), plant.get_actuation_input_port(car.instance))
    body = plant.GetBodyByName(config.airframe.body)
    from pydrake.math import RigidTransform
    plant.SetDefaultFloatingBaseBodyPose(body, RigidTransform([0.0, 0.0, 5.0]))
    return builder.Build()


class _IdlePythonSystem(LeafSystem):
    """A Python leaf system that computes nothing unless its output is read (never, here)."""

    def __init__(self):
        super().__init__()
        self.DeclareVectorOutputPort("y", 1, lambda context, output: None)


def floor_diagram(count: int, python: bool, sampled: bool):
    """The bare hexacopter plant (its step, sampled ports or not) beside `count` idle leaf
    systems, Python or C++ (ConstantVectorSource)."""
    from pydrake.systems.primitives import ConstantVectorSource
    from alight.diagrams.world.sim_vehicle import load_sim_vehicle_config
    from alight.systems.plant.hexacopter import add_hexacopter
    config = load_sim_vehicle_config()
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(
        time_step=config.time_step, discrete_contact_approximation="sap",
        contact_model="point", use_sampled_output_ports=sampled), builder)
    add_hexacopter(plant, config.airframe)
    plant.Finalize()
    for _ in range(count):
        builder.AddSystem(_IdlePythonSystem() if python else ConstantVectorSource([0.0]))
    return builder.Build()


def measure_floor(duration: float, repeats: int, count: int = 25) -> list[str]:
    """Lines: CPU us per idle leaf system per plant step, Python and C++, sampled ports or not."""
    def per_step(python: bool, sampled: bool) -> tuple[float, int]:
        best = None
        for _ in range(repeats):
            _, cpu, steps, _, _ = advance(floor_diagram(count, python, sampled), duration)
            _, cpu_0, steps_0, _, _ = advance(floor_diagram(0, python, sampled), duration)
            extra = (cpu / steps - cpu_0 / steps_0) / count
            best = extra if best is None else min(best, extra)
        return best, steps
    lines = []
    for sampled in (True, False):
        (py, steps), (cpp, _) = per_step(True, sampled), per_step(False, sampled)
        step = "unrestricted (sampled ports, the vehicle)" if sampled else \
            "discrete (no sampled ports)"
        lines.append(f"floor: plant step {step:42s} per idle leaf system per step: Python "
                     f"{1e6 * py:5.2f} CPU us, C++ {1e6 * cpp:5.2f} CPU us "
                     f"({steps / duration:.0f} steps/sim s; {count} Python systems: "
                     f"{1e3 * count * py * steps / duration:.1f} CPU ms/sim s)")
    return lines


def measure_hover(duration: float, repeats: int, profile: bool,
                  per_callback: bool = False) -> Measurement:
    best = None
    for _ in range(repeats):
        wall, cpu, steps, simulated, _ = advance(hover_diagram(duration), duration)
        if best is None or cpu < best.cpu:
            best = Measurement("hover (vehicle + scripted pilot)", simulated, wall, cpu, steps)
    if profile:
        profiler = SystemProfiler()
        with profiler.installed():
            diagram = hover_diagram(duration)
        _, cpu, _, _, _ = advance(diagram, duration)
        _attach_table(best, profiler, diagram, cpu, per_callback)
    return best


def measure_bare(duration: float, repeats: int, with_world: bool) -> Measurement:
    best = None
    name = ("bare plant: landing world in flight" if with_world
            else "bare plant: hexacopter (reference)")
    for _ in range(repeats):
        wall, cpu, steps, simulated, _ = advance(bare_plant_diagram(with_world), duration)
        if best is None or cpu < best.cpu:
            best = Measurement(name, simulated, wall, cpu, steps)
    return best


def mission_scenario(case: str, target_speed: float, seed: int, sets):
    from alight.diagrams.scenario import load_scenario
    return load_scenario("field", overrides=[f"target_motion.speed: {target_speed}",
                                             *CASE_OVERRIDES[case], *sets,
                                             f"random_seed: {seed}"])


def fly_mission(scenario, profiler: SystemProfiler | None = None):
    """Builds and flies `scenario` as the runner does; returns (measurement figures, simulator,
    stack, diagram). The stop monitor is profiled too when a profiler is given."""
    from alight.diagrams.running.runner import build
    start_cpu = time.process_time()
    builder = DiagramBuilder()
    if profiler is not None:
        with profiler.installed():
            stack = build(builder, scenario)
            diagram = builder.Build()
    else:
        stack = build(builder, scenario)
        diagram = builder.Build()
    build_cpu = time.process_time() - start_cpu
    duration = min(stack.duration or np.inf, scenario.simulator.max_duration)
    stop_when = stack.finished
    if profiler is not None and stop_when is not None:
        stop_when = profiler.wrap(("runner", "monitor:stop_when"), stop_when)
        profiler.systems["runner"] = "simulator: stop condition"
    wall, cpu, steps, simulated, simulator = advance(diagram, duration, scenario.random_seed,
                                                     stop_when)
    return (wall, cpu, steps, simulated, build_cpu), simulator, stack, diagram


def count_leaves(diagram) -> tuple[int, int]:
    """(Python, C++) leaf systems under `diagram` (each Python one costs every plant step:
    the `floor` case)."""
    from pydrake.systems.framework import Diagram
    python = cpp = 0
    for system in diagram.GetSystems():
        if isinstance(system, Diagram):
            sub = count_leaves(system)
            python, cpp = python + sub[0], cpp + sub[1]
        elif type(system).__module__.startswith("pydrake"):
            cpp += 1
        else:
            python += 1
    return python, cpp


def measure_mission(case: str, args) -> Measurement:
    from alight.diagrams.analysis.landing import score_landing
    from alight.diagrams.running.run_log import RunLog, write_run_folder
    from alight.diagrams.scenario import write_scenario
    start_cpu = time.process_time()
    scenario = mission_scenario(case, args.target_speed, args.seed, args.set)
    load_cpu = time.process_time() - start_cpu
    (wall, cpu, steps, simulated, build_cpu), simulator, stack, diagram = fly_mission(scenario)
    run_dir = Path(tempfile.mkdtemp(prefix=f"sim_speed_{case}_"))
    start_cpu = time.process_time()
    context = simulator.get_context()
    write_run_folder(run_dir, stack.loggers, simulator, {
        "command": "bench", "scenario_name": scenario.name, "seed": scenario.random_seed,
        "duration": context.get_time(), "controller": scenario.onboard.controller,
        "estimator": scenario.onboard.estimator,
        "landed": stack.finished is not None and stack.finished.holds(context),
        **stack.metadata})
    write_scenario(run_dir, scenario)
    write_cpu = time.process_time() - start_cpu
    impact = scenario.scoring.impact
    score = score_landing(RunLog(run_dir), impact.vertical_speed, impact.horizontal_speed)
    shutil.rmtree(run_dir, ignore_errors=True)
    label = {"land": "land: geometric camera, mocap", "vio": "land: geometric camera, VIO",
             "rendered": "land: rendered camera, mocap",
             "managed": "land: managed stack, mocap"}[case]
    result = Measurement(label, simulated, wall, cpu, steps, load_cpu + build_cpu, write_cpu,
                         score.row(), leaves=count_leaves(diagram))
    if args.profile:
        profiler = SystemProfiler()
        (_, cpu, _, _, _), _, _, diagram = fly_mission(scenario, profiler)
        _attach_table(result, profiler, diagram, cpu, args.callbacks)
    return result


def _attach_table(result: Measurement, profiler: SystemProfiler, diagram, cpu: float,
                  per_callback: bool) -> None:
    result.per_callback = per_callback
    result.table = profiler.per_system(diagram, per_callback)
    result.profiled_cpu = cpu
    result.callbacks = sum(profiler.calls.values())
    result.overhead = result.callbacks * profiler.overhead_per_call()


def print_table(result: Measurement, top: int) -> None:
    if not result.table:
        return
    T = result.simulated
    python = sum(r[3] for r in result.table)
    print(f"  per system (profiled run: {result.profiled_cpu / T:.3f} CPU s/sim s, of which "
          f"profiler ~{result.overhead / T:.3f}; Python callbacks "
          f"{python / T:.3f}, {result.callbacks / T:.0f} calls/sim s):")
    width = 44 if result.per_callback else 26
    print(f"    {'system':48s} {'callback' if result.per_callback else 'class':{width}s} "
          f"{'calls/sim s':>11s} {'CPU ms/sim s':>12s}")
    for path, cls, calls, seconds in result.table[:top]:
        print(f"    {path[-48:]:48s} {cls[:width]:{width}s} {calls / T:11.0f} "
              f"{1e3 * seconds / T:12.1f}")
    rest = result.profiled_cpu - python - result.overhead
    print(f"    {'everything else: C++ (plant, Drake primitives, framework dispatch)':75s} "
          f"{'':11s} {1e3 * max(rest, 0.0) / T:12.1f}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="hover,land,vio",
                        help=f"comma-separated, of {', '.join(CASES)} (default hover,land,vio)")
    parser.add_argument("--rendered", action="store_true", help="add the rendered-camera case")
    parser.add_argument("--duration", type=float, default=30.0, help="hover and bare plant [s]")
    parser.add_argument("--repeats", type=int, default=3, help="hover and bare plant: best of")
    parser.add_argument("--target-speed", type=float, default=2.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", action="append", default=[], metavar="'KEY.SUB: VALUE'",
                        help="scenario override for the missions (repeatable)")
    parser.add_argument("--top", type=int, default=10, help="rows of the per-system table")
    parser.add_argument("--no-profile", dest="profile", action="store_false",
                        help="skip the profiled second run of each case")
    parser.add_argument("--callbacks", action="store_true",
                        help="the table per callback (output, update or publish) of each system")
    args = parser.parse_args()
    cases = [c for c in args.cases.split(",") if c]
    if args.rendered and "rendered" not in cases:
        cases.append("rendered")
    unknown = set(cases) - set(CASES)
    if unknown:
        parser.error(f"unknown case(s) {sorted(unknown)}; known: {', '.join(CASES)}")
    print(f"load average at start {os.getloadavg()[0]:.2f} ({os.cpu_count()} cores)", flush=True)
    bare = measure_bare(args.duration, args.repeats, with_world=False)
    world = measure_bare(args.duration, args.repeats, with_world=True)
    for reference in (bare, world):
        print(reference.line(), flush=True)
    for case in cases:
        if case == "floor":
            print("\n".join(measure_floor(args.duration, args.repeats)) + "\n", flush=True)
            continue
        result = measure_hover(args.duration, args.repeats, args.profile, args.callbacks) \
            if case == "hover" else measure_mission(case, args)
        print(result.line())
        if result.outcome:
            print(f"  outcome: {result.outcome}")
        if result.leaves:
            print(f"  leaf systems: {result.leaves[0]} Python, {result.leaves[1]} C++")
        per_sim = result.cpu / result.simulated
        print(f"  ratio CPU per sim s / bare hexacopter plant: "
              f"{per_sim / (bare.cpu / bare.simulated):.1f}; / bare landing world: "
              f"{per_sim / (world.cpu / world.simulated):.1f}")
        print_table(result, args.top)
        print(flush=True)
    print(f"load average at end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
