"""Real-time factor of 30 s of hover of the simulated hexacopter (no rendering, no logging).

Prints simulated time, wall time, real-time factor, steps, wall time per step and CPU time per
step (this process's CPU time: less sensitive to other jobs on a shared machine than the wall
time); and, as a reference measured in the same process, the same figures for the bare
MultibodyPlant (same model, contact and step, no rotors, controllers or sensors), with the ratio
between the two.

    python bench/sim_speed.py [--duration 30] [--repeats 3]
"""
import argparse
import os
import time

from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.onboard.pilot import pilot_model
from alight.diagrams.world.sim_vehicle import load_sim_vehicle_config, make_sim_vehicle
from alight.systems.control.scripted_pilot import PilotProfile, ProfileSegment, ScriptedPilot
from alight.systems.plant.hexacopter import add_hexacopter, load_hexacopter_params


def hover_profile(duration: float) -> PilotProfile:
    takeoff = [ProfileSegment(0.5, vertical_acceleration=-9.81),
               ProfileSegment(2.0, vertical_acceleration=1.0),
               ProfileSegment(2.0, vertical_acceleration=-1.0)]
    rest = duration - sum(s.duration for s in takeoff)
    return PilotProfile(segments=takeoff + [ProfileSegment(rest)])


def hover_diagram(duration: float):
    config = load_sim_vehicle_config()
    builder = DiagramBuilder()
    vehicle = builder.AddSystem(make_sim_vehicle(config))
    pilot = builder.AddSystem(ScriptedPilot(hover_profile(duration), pilot_model(config.airframe)))
    builder.Connect(pilot.get_output_port(), vehicle.GetInputPort("fc_command"))
    return builder.Build()


def bare_plant_diagram():
    config = load_sim_vehicle_config()
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(
        time_step=config.time_step, discrete_contact_approximation="sap"), builder)
    add_hexacopter(plant, load_hexacopter_params(config.vehicle))
    plant.Finalize()
    return builder.Build()


def measure(diagram, duration: float, repeats: int) -> tuple[float, float, int]:
    """Best wall time and best CPU time of `repeats` runs, and the number of simulator steps."""
    best, best_cpu, steps = float("inf"), float("inf"), 0
    for _ in range(repeats):
        simulator = Simulator(diagram)
        simulator.Initialize()
        start, start_cpu = time.perf_counter(), time.process_time()
        simulator.AdvanceTo(duration)
        best = min(best, time.perf_counter() - start)
        best_cpu = min(best_cpu, time.process_time() - start_cpu)
        steps = simulator.get_num_steps_taken()
    return best, best_cpu, steps


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    rows = []
    for name, diagram in (("hexacopter hover (full vehicle)", hover_diagram(args.duration)),
                          ("bare MultibodyPlant (reference)", bare_plant_diagram())):
        wall, cpu, steps = measure(diagram, args.duration, args.repeats)
        rows.append((name, wall, steps))
        print(f"{name:34s} sim {args.duration:5.1f} s  wall {wall:6.2f} s  "
              f"real-time factor {args.duration / wall:6.2f}  steps {steps:6d}  "
              f"{1e6 * wall / steps:7.1f} us/step  CPU {1e6 * cpu / steps:7.1f} us/step")
    print(f"full vehicle / bare plant wall-time ratio: {rows[0][1] / rows[1][1]:.1f}; load "
          f"average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
