"""The control manager (M Sec. 7.2) alone, on fixed inputs: switch requests and schedules, the
safety area's refusals, the emergency landing, the failsafe, no NaN forwarded, frame changes,
and the YAML list of controllers."""
import dataclasses as dc
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.primitives import ConstantVectorSource

from alight.diagrams.onboard.control_manager import (ControlManagerConfig, ControllerEntry,
                                                     TrackerEntry, build_controller, build_tracker,
                                                     check_control_manager_config,
                                                     load_control_manager_config, parse_switch)
from alight.diagrams.onboard.controllers import load_controllers_config
from alight.systems.boundary import FC_COMMAND, REFERENCE, STATE_ESTIMATE
from alight.systems.control.controller import (Controller, ControllerReason, level_command,
                                               status_vector)
from alight.systems.control.force_controller import VehicleModel
from alight.systems.managers.control_manager import (MANAGER_STATUS, ControlManager,
                                                     EmergencyParams, FailsafeCause, ManagerMode,
                                                     Refusal, SafetyArea, inside_polygon)
from alight.systems.params import ConfigError, load_params
from alight.systems.thrust_curve import GRAVITY
from alight.systems.tracking.tracker import Tracker

NAMES = ["se3", "mpc", "failsafe"]
AREA = SafetyArea(polygon=[[-5, -5], [5, -5], [5, 5], [-5, 5]], min_height=0.5, max_height=4.0)
VEHICLE = VehicleModel()
HOVER_THRUST = float(VEHICLE.curve.thrust(VEHICLE.mass * GRAVITY))


def estimate(p=(0.0, 0.0, 2.0), **fields):
    return STATE_ESTIMATE.vector(p_EB=p, **fields)


def goal(p=(0.0, 0.0, 2.0), heading=0.0):
    return REFERENCE.pack(stamp=0.0, p=p, v=0.0, a=0.0, j=0.0, heading=heading,
                          heading_rate=0.0)


class Bench:
    """The manager as `dut` with fixed inputs; every controller issues its own thrust."""

    def __init__(self, schedule=None, area=AREA):
        self.dut = ControlManager(
            controllers=NAMES, initial_controller="se3", failsafe_controller="failsafe",
            emergency_controller="se3", vehicle=VEHICLE, safety_area=area,
            emergency=EmergencyParams(), period=0.01, schedule=schedule)
        self.context = self.dut.CreateDefaultContext()
        self.simulator = Simulator(self.dut, self.context)
        self.set(state_estimate=estimate(), goal=goal(), switch_request=[0, 0])
        for i, name in enumerate(NAMES):
            self.command(i, HOVER_THRUST + 0.01 * i)
            self.set(**{f"{name}.controller_status": status_vector(ControllerReason.OK)})

    def set(self, **values):
        for name, value in values.items():
            self.dut.GetInputPort(name).FixValue(self.context, np.asarray(value, dtype=float))

    def command(self, i, thrust):
        self.set(**{f"{NAMES[i]}.fc_command": level_command(0.0, 0.0, thrust, 1.0)})

    def run(self, seconds):
        self.simulator.AdvanceTo(self.context.get_time() + seconds)

    def status(self, field):
        return MANAGER_STATUS.get(self.dut.GetOutputPort("manager_status").Eval(self.context),
                                  field)

    def output(self, port):
        return self.dut.GetOutputPort(port).Eval(self.context)

    def active(self):
        return [int(self.output(f"{name}.active")[0]) for name in NAMES]


def test_switch_request_activates_the_controller_at_the_same_tick():
    bench = Bench()
    bench.run(0.05)
    assert bench.active() == [1, 0, 0]
    bench.set(switch_request=[1, 1])            # request id 1: controller 1 (mpc)
    # Before the tick the new controller is already told it is active (it computes at the
    # tick, reading the command the previous one issued as `last_command`) ...
    assert bench.active() == [0, 1, 0]
    assert FC_COMMAND.get(bench.output("fc_command"), "thrust") == pytest.approx(HOVER_THRUST)
    bench.run(0.01)
    # ... and after it the manager forwards the new controller's command.
    assert FC_COMMAND.get(bench.output("fc_command"), "thrust") == pytest.approx(
        HOVER_THRUST + 0.01)
    assert bench.status("switches") == 1
    bench.set(switch_request=[2, 7])            # no controller 7: refused, nothing changes
    bench.run(0.02)
    assert bench.active() == [0, 1, 0] and bench.status("refusal") == Refusal.UNKNOWN_CONTROLLER


def test_scheduled_switches_happen_at_their_times():
    bench = Bench(schedule=[(0.2, "mpc"), (0.5, "se3")])
    bench.run(0.195)
    assert bench.status("active") == 0
    bench.run(0.01)
    assert bench.status("active") == 1
    bench.run(0.3)
    assert bench.status("active") == 0 and bench.status("switches") == 2


def test_goals_outside_the_area_are_refused_with_a_reason_and_the_vehicle_holds():
    bench = Bench()
    bench.set(goal=goal([4.0, 0.0, 2.0], heading=0.3), state_estimate=estimate([4.0, 0.0, 2.0]))
    bench.run(0.05)
    assert REFERENCE.get(bench.output("reference"), "p") == pytest.approx([4.0, 0.0, 2.0])
    for p, reason in (([6.0, 0.0, 2.0], Refusal.OUTSIDE_POLYGON),
                      ([4.0, 0.0, 4.5], Refusal.ABOVE_MAX_HEIGHT),
                      ([4.0, 0.0, 0.2], Refusal.BELOW_MIN_HEIGHT),
                      ([np.nan, 0.0, 2.0], Refusal.NOT_FINITE)):
        bench.set(goal=goal(p))
        bench.run(0.05)
        reference = bench.output("reference")
        assert bench.status("refusal") == reason and bench.status("held") == 1
        assert REFERENCE.get(reference, "p") == pytest.approx([4.0, 0.0, 2.0])   # holds
        assert REFERENCE.get(reference, "heading") == pytest.approx(0.3)
        assert np.all(REFERENCE.get(reference, "v") == 0.0)
        bench.set(goal=goal([4.2, 0.0, 2.0], heading=0.3))   # back within rejoin_distance
        bench.run(0.02)
        assert bench.status("held") == 0
        assert REFERENCE.get(bench.output("reference"), "p") == pytest.approx([4.2, 0.0, 2.0])
        bench.set(goal=goal([4.0, 0.0, 2.0], heading=0.3))
        bench.run(0.02)
    # A goal that comes back inside far from the hold point is not followed (no jump).
    bench.set(goal=goal([6.0, 0.0, 2.0]))
    bench.run(0.02)
    bench.set(goal=goal([-4.0, 0.0, 2.0]))
    bench.run(0.02)
    assert bench.status("held") == 1


def test_control_error_over_the_threshold_starts_the_emergency_landing_then_disarms():
    bench = Bench(schedule=[(0.0, "mpc")])
    bench.run(0.05)
    bench.set(state_estimate=estimate([2.5, 0.0, 2.0]))     # 2.5 m from the goal: over 2 m
    bench.run(0.01)
    assert bench.status("mode") == ManagerMode.ELAND
    assert bench.active() == [1, 0, 0]                # the emergency controller (se3)
    bench.run(1.0)
    reference = bench.output("reference")
    # Holds the estimated position of that moment, descending at 0.5 m/s.
    assert REFERENCE.get(reference, "p")[:2] == pytest.approx([2.5, 0.0])
    assert REFERENCE.get(reference, "p")[2] == pytest.approx(2.0 - 0.5 * 1.0, abs=0.02)
    assert REFERENCE.get(reference, "v") == pytest.approx([0.0, 0.0, -0.5])
    bench.set(switch_request=[1, 1])                  # no switching during the landing
    bench.run(0.02)
    assert bench.status("active") == 0
    assert bench.status("refusal") == Refusal.NOT_IN_NORMAL_MODE
    bench.command(0, 0.2 * HOVER_THRUST)              # on the ground: little thrust left
    bench.run(0.45)
    assert bench.status("mode") == ManagerMode.ELAND  # not yet 0.5 s
    bench.run(0.1)
    assert bench.status("mode") == ManagerMode.LANDED
    command = bench.output("fc_command")
    assert FC_COMMAND.get(command, "arm") == 0.0 and FC_COMMAND.get(command, "thrust") == 0.0


def test_estimate_loss_and_invalid_controller_output_switch_to_the_failsafe():
    bench = Bench()
    bench.run(0.05)
    bench.set(state_estimate=estimate(valid=0.0))
    bench.run(0.01)
    assert bench.status("mode") == ManagerMode.FAILSAFE
    assert bench.status("failsafe_cause") == FailsafeCause.BAD_ESTIMATE
    assert bench.active() == [0, 0, 1]
    bench.set(state_estimate=estimate(), switch_request=[1, 0])   # no way back
    bench.run(0.05)
    assert bench.active() == [0, 0, 1]

    bench = Bench()
    bench.run(0.05)
    bench.set(**{"se3.controller_status": status_vector(ControllerReason.SOLVER_FAILED)})
    bench.run(0.01)
    assert bench.status("failsafe_cause") == FailsafeCause.BAD_CONTROLLER
    assert bench.active() == [0, 0, 1]


def test_no_valid_estimate_before_the_first_one_is_not_a_failure():
    bench = Bench()
    bench.set(state_estimate=estimate(valid=0.0),
              **{"se3.controller_status": status_vector(ControllerReason.BAD_ESTIMATE)})
    bench.run(0.2)
    assert bench.status("mode") == ManagerMode.NORMAL and bench.active() == [1, 0, 0]


def test_a_nan_command_is_never_forwarded():
    bench = Bench()
    bench.run(0.05)
    bad = level_command(0.0, 0.0, HOVER_THRUST, 1.0)
    bad[FC_COMMAND.slice("w_D")] = np.nan
    bench.set(**{"se3.fc_command": bad})
    command = bench.output("fc_command")
    assert np.all(np.isfinite(command))
    assert FC_COMMAND.get(command, "thrust") == pytest.approx(HOVER_THRUST)  # the last good one
    bench.run(0.01)
    assert bench.status("failsafe_cause") == FailsafeCause.BAD_CONTROLLER


def test_the_hold_point_follows_an_estimator_frame_change():
    bench = Bench()
    bench.set(goal=goal([4.0, 1.0, 2.0]), state_estimate=estimate([4.0, 1.0, 2.0]))
    bench.run(0.05)
    bench.set(goal=goal([9.0, 1.0, 2.0]))            # refused: hold at (4, 1, 2) in frame 0
    bench.run(0.02)
    # New frame: rotated 90 deg about z and shifted by (1, 0, 0) from the old one.
    q = [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]
    bench.set(state_estimate=estimate([1.0, -3.0, 2.0], frame_counter=1, p_OldNew=[1.0, 0.0, 0.0],
                                q_OldNew=q))
    bench.run(0.02)
    # p_new = R_OldNew^T (p_old - p_OldNew) = R_z(-90 deg) (3, 1, 2) = (1, -3, 2).
    assert REFERENCE.get(bench.output("reference"), "p") == pytest.approx([1.0, -3.0, 2.0])
    assert REFERENCE.get(bench.output("reference"), "heading") == pytest.approx(-np.pi / 2)
    assert bench.status("mode") == ManagerMode.NORMAL      # no control error from the change


def test_inside_polygon_on_a_concave_area():
    l_shape = np.array([[0, 0], [4, 0], [4, 1], [1, 1], [1, 4], [0, 4]], dtype=float)
    assert inside_polygon([0.5, 3.0], l_shape) and inside_polygon([3.0, 0.5], l_shape)
    assert not inside_polygon([3.0, 3.0], l_shape)
    assert inside_polygon([4.0, 0.5], l_shape)          # on an edge


def not_a_controller(controllers_config):
    return ConstantVectorSource([0.0])


def test_the_yaml_list_builds_the_controllers_and_bad_entries_are_named():
    config = load_control_manager_config()
    assert config.names == NAMES + ["linear_mpc"]
    assert config.tracker_names == ["mpc_tracker", "landoff", "speed", "target"]
    controllers_config = config.controller_params
    for entry in config.controllers:     # each derives from the role's base class
        assert isinstance(build_controller(entry, controllers_config), Controller)
    for entry in config.trackers:
        assert isinstance(build_tracker(entry, controllers_config, config.tracker_params),
                          Tracker)
    with pytest.raises(ConfigError, match="share the names"):
        check_control_manager_config(dc.replace(config, trackers=[TrackerEntry(
            "se3", f"{__name__}:not_a_controller")], initial_tracker="se3"))
    with pytest.raises(ValueError, match="share the names"):
        ControlManager(controllers=NAMES, initial_controller="se3", failsafe_controller="failsafe",
                       emergency_controller="se3", vehicle=VEHICLE, trackers=["se3"])
    with pytest.raises(ConfigError, match="initial_tracker"):
        check_control_manager_config(dc.replace(config, initial_tracker="pid"))
    with pytest.raises(ConfigError, match="goal"):
        check_control_manager_config(dc.replace(config, trackers=[
            TrackerEntry("mine", f"{__name__}:not_a_controller", goal="pose")]))
    with pytest.raises(ConfigError, match="tracker contract"):
        build_tracker(TrackerEntry("bad", f"{__name__}:not_a_controller"), controllers_config,
                      config.tracker_params)
    with pytest.raises(ConfigError, match="emergency_controller"):
        check_control_manager_config(dc.replace(config, emergency_controller="pid"))
    with pytest.raises(ConfigError, match="built-in"):
        check_control_manager_config(dc.replace(config, controllers=[ControllerEntry("pid")]))
    with pytest.raises(ConfigError, match="controller contract"):
        build_controller(ControllerEntry("bad", f"{__name__}:not_a_controller"),
                         controllers_config)
    with pytest.raises(ConfigError, match="cannot load factory"):
        build_controller(ControllerEntry("bad", "no_such_module:make"), controllers_config)
    with pytest.raises(ConfigError, match="polygon"):
        check_control_manager_config(dc.replace(config, safety_area=SafetyArea(polygon=[[0, 0]])))
    assert parse_switch("12.5:mpc", NAMES) == (12.5, "mpc")
    with pytest.raises(ValueError, match="TIME:NAME"):
        parse_switch("soon:mpc", NAMES)


def test_the_documented_example_controller_registers_and_flies(tmp_path, monkeypatch):
    """docs/controllers.md: its example module, registered through a YAML factory entry, follows
    the contract and, active on a hover estimate 0.5 m under the goal, commands a climb."""
    page = (Path(__file__).parent.parent / "docs" / "controllers.md").read_text()
    code = page.split("```python\n")[1].split("```")[0]
    (tmp_path / "my_controllers.py").write_text(code)
    monkeypatch.syspath_prepend(str(tmp_path))
    config = load_params(ControlManagerConfig, data=(
        "controllers:\n  - {name: se3}\n  - {name: failsafe}\n"
        "  - {name: bandwidth, factory: 'my_controllers:make_bandwidth_controller'}\n"))
    check_control_manager_config(config)
    controllers_config = config.controller_params
    dut = build_controller(config.controllers[2], controllers_config)
    context = dut.CreateDefaultContext()
    dut.GetInputPort("state_estimate").FixValue(context, estimate([0.0, 0.0, 1.5]))
    dut.GetInputPort("reference").FixValue(context, goal([0.0, 0.0, 2.0]))
    dut.GetInputPort("active").FixValue(context, [1.0])
    dut.GetInputPort("last_command").FixValue(context, level_command(0.0, 0.0, HOVER_THRUST, 1.0))
    Simulator(dut, context).AdvanceTo(0.5)
    command = dut.GetOutputPort("fc_command").Eval(context)
    status = dut.GetOutputPort("controller_status").Eval(context)
    assert status[0] == 1.0 and np.all(np.isfinite(command))
    # k_p e = 2.5^2 * 0.5 m = 3.1 m/s^2 up: more than hover thrust (after the activation ramp).
    assert FC_COMMAND.get(command, "thrust") > HOVER_THRUST + 0.05


def test_a_controller_takes_over_the_previous_ones_disturbance_estimates():
    """M Sec. 7.2: the newly active controller starts from the previous one's state: the MPC,
    activated with the SE(3)'s estimates on `last_disturbance`, publishes them from its first
    tick (its integrators are frozen during the activation ramp)."""
    from alight.diagrams.onboard.controllers import make_controller
    from alight.systems.control.disturbance import DISTURBANCE_ESTIMATE
    controllers_config = load_controllers_config()
    dut = make_controller("mpc", controllers_config)
    context = dut.CreateDefaultContext()
    handed = DISTURBANCE_ESTIMATE.pack(d_w=[1.2, -0.4], d_b=[0.3, 0.1], m_e=2.8)
    dut.GetInputPort("state_estimate").FixValue(context, estimate([0.0, 0.0, 2.0]))
    dut.GetInputPort("reference").FixValue(context, goal([0.0, 0.0, 2.0]))
    dut.GetInputPort("active").FixValue(context, [1.0])
    dut.GetInputPort("last_command").FixValue(context, level_command(0.0, 0.0, HOVER_THRUST, 1.0))
    dut.GetInputPort("last_disturbance").FixValue(context, handed)
    Simulator(dut, context).AdvanceTo(0.005)
    np.testing.assert_allclose(dut.GetOutputPort("disturbance_estimate").Eval(context), handed,
                               atol=1e-9)


class TrackerBench(Bench):
    """The manager with two trackers (fixed references) and the `arm` input connected."""

    TRACKERS = ["mpc_tracker", "landoff"]

    def __init__(self):
        self.dut = ControlManager(
            controllers=NAMES, initial_controller="se3", failsafe_controller="failsafe",
            emergency_controller="se3", vehicle=VEHICLE, trackers=self.TRACKERS,
            initial_tracker="landoff", safety_area=AREA, emergency=EmergencyParams(),
            period=0.01)
        self.context = self.dut.CreateDefaultContext()
        self.simulator = Simulator(self.dut, self.context)
        self.set(state_estimate=estimate([1.0, 2.0, 0.2]), switch_request=[0, 0],
                 tracker_request=[0, 0], arm=[0.0, 0.0])
        for i, name in enumerate(NAMES):
            self.command(i, HOVER_THRUST + 0.01 * i)
            self.set(**{f"{name}.controller_status": status_vector(ControllerReason.OK)})
        for name, z in zip(self.TRACKERS, (2.0, 1.0)):
            self.set(**{f"{name}.reference": goal([1.0, 2.0, z]),
                        f"{name}.tracker_status": status_vector(ControllerReason.OK)})

    def trackers_active(self):
        return [int(self.output(f"{name}.active")[0]) for name in self.TRACKERS]


def test_disarmed_manager_sends_zero_thrust_and_arming_starts_the_initial_pair():
    bench = TrackerBench()
    bench.run(0.1)
    command = bench.output("fc_command")
    assert bench.status("mode") == ManagerMode.DISARMED
    assert FC_COMMAND.get(command, "arm") == 0.0 and FC_COMMAND.get(command, "thrust") == 0.0
    assert bench.active() == [0, 0, 0] and bench.trackers_active() == [0, 0]
    # The reference rests at the estimate, so that a tracker starts from the vehicle.
    assert REFERENCE.get(bench.output("reference"), "p") == pytest.approx([1.0, 2.0, 0.2])
    bench.set(tracker_request=[1, 0])       # selectable while disarmed: used on arming
    bench.run(0.02)
    assert bench.status("tracker") == 0 and bench.trackers_active() == [0, 0]
    bench.set(arm=[1.0, 0.0])                # armed at zero thrust (what PX4 arms at)
    bench.run(0.02)
    command = bench.output("fc_command")
    assert FC_COMMAND.get(command, "arm") == 1.0 and FC_COMMAND.get(command, "thrust") == 0.0
    assert bench.status("mode") == ManagerMode.DISARMED and bench.active() == [0, 0, 0]
    bench.set(arm=[1.0, 1.0])
    # At the arming tick the initial controller and the selected tracker compute, the
    # controller reading the disarmed command as its last command (it spools up from zero).
    assert bench.active() == [1, 0, 0] and bench.trackers_active() == [1, 0]
    assert FC_COMMAND.get(bench.output("fc_command"), "thrust") == 0.0
    bench.run(0.02)
    assert bench.status("mode") == ManagerMode.NORMAL
    assert FC_COMMAND.get(bench.output("fc_command"), "thrust") == pytest.approx(HOVER_THRUST)
    assert REFERENCE.get(bench.output("reference"), "p") == pytest.approx([1.0, 2.0, 2.0])
    bench.set(arm=[0.0, 0.0])                     # disarm (after landing): zero thrust at once
    bench.run(0.01)
    assert bench.status("mode") == ManagerMode.DISARMED
    assert FC_COMMAND.get(bench.output("fc_command"), "thrust") == 0.0


def test_tracker_switch_is_taken_at_the_tick_and_a_failed_tracker_holds():
    bench = TrackerBench()
    bench.set(arm=[1.0, 1.0])
    bench.run(0.05)
    assert bench.trackers_active() == [0, 1]
    assert REFERENCE.get(bench.output("reference"), "p")[2] == pytest.approx(1.0)
    bench.set(tracker_request=[1, 0])
    assert bench.trackers_active() == [1, 0]   # the new one computes at this tick ...
    bench.run(0.02)                            # ... and its reference is followed after it
    assert REFERENCE.get(bench.output("reference"), "p")[2] == pytest.approx(2.0)
    assert bench.status("tracker_switches") == 1
    bench.set(tracker_request=[2, 5])          # no tracker 5: refused, nothing changes
    bench.run(0.02)
    assert bench.status("refusal") == Refusal.UNKNOWN_TRACKER and bench.trackers_active() == [1, 0]
    bench.set(**{"mpc_tracker.tracker_status": status_vector(ControllerReason.BAD_ESTIMATE),
                 "mpc_tracker.reference": goal([3.0, 2.0, 2.0])})
    bench.run(0.02)                            # cannot produce a reference: the vehicle holds
    assert bench.status("refusal") == Refusal.TRACKER_FAILED and bench.status("held") == 1
    assert REFERENCE.get(bench.output("reference"), "p") == pytest.approx([1.0, 2.0, 2.0])
    bad = goal([1.0, 2.0, 2.0])
    bad[REFERENCE.slice("v")] = np.nan
    bench.set(**{"mpc_tracker.tracker_status": status_vector(ControllerReason.OK),
                 "mpc_tracker.reference": bad})
    bench.run(0.02)
    assert np.all(np.isfinite(bench.output("reference"))) and bench.status("held") == 1
    bench.set(**{"mpc_tracker.reference": goal([1.2, 2.0, 2.0])})   # usable again, near the hold
    bench.run(0.02)
    assert bench.status("held") == 0
    assert REFERENCE.get(bench.output("reference"), "p") == pytest.approx([1.2, 2.0, 2.0])
