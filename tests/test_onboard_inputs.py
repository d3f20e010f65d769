"""No onboard system reads the simulation's ground truth (DESIGN.md "Vehicle boundary", issue 21
item 6): every onboard stack of the registry (diagrams/stacks.py `STACKS`), built by the runner
from each shipped scenario with each estimator that applies, is walked connection by connection
(`Diagram.connection_map`, into sub-diagrams and through their exported ports, down to leaf
systems) and no truth reaches an onboard input.

The rule. Truth is any output of the `MultibodyPlant` or `SceneGraph` (state, poses, geometry)
and any output port named `ground_truth`. World-side systems may read it:
- every system inside the simulated vehicle's diagram ("vehicle", diagrams/world/sim_vehicle.py:
  plant, motors, wind, IMU, flight controller, cameras, the car);
- simulated sensors outside it: systems whose class lives in `alight.systems.sensors` (mocap and
  the bank's sampled sources: true value + noise + latency, M Sec. 3.1.2);
- sinks, systems without output ports (the run folder's stream loggers): nothing they compute
  reaches the vehicle.
Every other leaf system is onboard, and none of its inputs may be fed by truth.
Building only (no simulation): about 0.3-1 s per diagram."""
import pytest

from pydrake.geometry import SceneGraph
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import PassThrough

from alight.diagrams.running.runner import build
from alight.diagrams.scenario import SCENARIOS, STACK_MISSIONS, load_scenario
from alight.diagrams.stacks import NEEDS_ODOMETRY, STACKS

VEHICLE = "vehicle"             # runner.build's name of the simulated vehicle (the world)
SENSORS = "alight.systems.sensors"
ESTIMATORS = ("mocap", "vio", "bank")


def _leaf_source(system, port_index):
    """The leaf (system, output port) behind an output port, through exported outputs."""
    while isinstance(system, Diagram):
        system, port_index = system.get_output_port_locator(port_index)
    return system, system.get_output_port(port_index)


def _leaf_inputs(system, port_index):
    """The leaf input ports fed by an input port, through exported inputs."""
    if not isinstance(system, Diagram):
        return [(system, system.get_input_port(port_index))]
    return [leaf for child, index in system.GetInputPortLocators(port_index)
            for leaf in _leaf_inputs(child, index)]


def leaf_connections(diagram: Diagram):
    """Every connection of `diagram` and its sub-diagrams as (source leaf system, its output
    port, destination leaf system, its input port)."""
    edges = []
    for (destination, input_index), (source, output_index) in diagram.connection_map().items():
        leaf, output = _leaf_source(source, output_index)
        edges += [(leaf, output, reader, port)
                  for reader, port in _leaf_inputs(destination, input_index)]
    for child in diagram.GetSystems():
        if isinstance(child, Diagram):
            edges += leaf_connections(child)
    return edges


def _leaves(system):
    if not isinstance(system, Diagram):
        return [system]
    return [leaf for child in system.GetSystems() for leaf in _leaves(child)]


def _path(system) -> str:
    """The system's path below the root diagram, e.g. 'vehicle::plant'."""
    return "::".join(system.GetSystemPathname().split("::")[2:])


def is_truth(system, port) -> bool:
    return isinstance(system, (MultibodyPlant, SceneGraph)) or port.get_name() == "ground_truth"


def _vehicle_leaves(diagram: Diagram) -> set:
    return {id(leaf) for child in diagram.GetSystems() if child.get_name() == VEHICLE
            for leaf in _leaves(child)}


def _sensor_or_sink(system) -> bool:
    return type(system).__module__.startswith(SENSORS) or system.num_output_ports() == 0


def truth_readers(diagram: Diagram):
    """(violations, sensed): a line naming the onboard system, its input port and the truth it
    reads for every violation of the module text's rule, and the number of reads of truth by
    simulated sensors and sinks outside the vehicle."""
    vehicle, violations, sensed = _vehicle_leaves(diagram), [], 0
    for source, output, reader, port in leaf_connections(diagram):
        if not is_truth(source, output) or id(reader) in vehicle:
            continue
        if _sensor_or_sink(reader):
            sensed += 1
        else:
            violations.append(f"{_path(reader)} input '{port.get_name()}' reads "
                              f"{_path(source)} output '{output.get_name()}'")
    return violations, sensed


def _stack_cases():
    """(scenario, stack, estimator): every shipped scenario with every stack that flies its kind
    of mission (`--stack managed` on a landing scenario), on every estimator that applies."""
    cases = []
    for name in sorted(SCENARIOS):
        mission = type(load_scenario(name).mission)
        for stack in sorted(STACKS):
            if STACK_MISSIONS[stack] is mission:
                cases += [(name, stack, estimator) for estimator in
                          (ESTIMATORS if stack in NEEDS_ODOMETRY else (None,))]
    return cases


def test_every_stack_is_covered():
    """The shipped scenarios build every stack of the registry."""
    assert {stack for _, stack, _ in _stack_cases()} == set(STACKS)


@pytest.mark.parametrize("scenario_name, stack, estimator", _stack_cases())
def test_no_onboard_system_reads_ground_truth(scenario_name, stack, estimator):
    overrides = [f"onboard.stack: {stack}"] + ([f"onboard.estimator: {estimator}"]
                                               if estimator else [])
    scenario = load_scenario(scenario_name, overrides=overrides)
    builder = DiagramBuilder()
    build(builder, scenario)
    violations, sensed = truth_readers(builder.Build())
    assert violations == []
    # The walk sees the simulated sensors and loggers that do read truth (not a vacuous pass).
    assert sensed >= 1


def _vehicle_and_onboard(leak: bool):
    """A hand-made world ("vehicle": a plant, its state exported as ground_truth) and an onboard
    sub-diagram with one relay behind an exported input; `leak` wires the truth into it."""
    world = DiagramBuilder()
    plant = world.AddNamedSystem("plant", MultibodyPlant(0.0))
    plant.Finalize()
    world.ExportOutput(plant.get_state_output_port(), "ground_truth")
    onboard = DiagramBuilder()
    relay = onboard.AddNamedSystem("relay", PassThrough(plant.num_multibody_states()))
    onboard.ExportInput(relay.get_input_port(), "odometry")
    onboard.ExportOutput(relay.get_output_port(), "estimate")
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem(VEHICLE, world.Build())
    stack = builder.AddNamedSystem("onboard", onboard.Build())
    if leak:
        builder.Connect(vehicle.GetOutputPort("ground_truth"), stack.GetInputPort("odometry"))
    return builder.Build()


def test_truth_wired_into_onboard_input_is_caught():
    violations, _ = truth_readers(_vehicle_and_onboard(leak=True))
    assert violations == ["onboard::relay input 'u' reads vehicle::plant output 'state'"]
    assert truth_readers(_vehicle_and_onboard(leak=False)) == ([], 0)


def test_ground_truth_into_real_stack_is_caught():
    """The landing stack with one onboard system reading the vehicle's ground_truth."""
    builder = DiagramBuilder()
    build(builder, load_scenario("field"))
    vehicle = builder.GetSubsystemByName(VEHICLE)
    size = vehicle.GetOutputPort("ground_truth").size()
    leak = builder.AddNamedSystem("leak", PassThrough(size))
    builder.Connect(vehicle.GetOutputPort("ground_truth"), leak.get_input_port())
    violations, _ = truth_readers(builder.Build())
    assert violations == ["leak input 'u' reads vehicle::ground_truth output 'ground_truth'"]
