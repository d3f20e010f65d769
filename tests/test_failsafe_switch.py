"""The direct stacks' failsafe switch (the control manager's fallback, M Sec. 7.2, 5.10) alone, on
fixed inputs: every cause hands over at the tick, from the last issued command, for good; a
reference step is not a control error; nothing is watched on the ground; no unusable command is
forwarded (issue 21)."""
import dataclasses as dc

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from alight.diagrams.onboard.mpc_loop import load_failsafe_switch
from alight.systems.boundary import FC_COMMAND, FC_STATUS, STATE_ESTIMATE, ActiveMode
from alight.systems.control.controller import ControllerReason, level_command, status_vector
from alight.systems.managers.control_manager import MANAGER_STATUS, FailsafeCause, ManagerMode
from alight.systems.managers.failsafe_switch import FailsafeSwitch
from test_failsafe import HOVER_THRUST, falling, reference


def spoiled(field: str, value: float) -> np.ndarray:
    """A hover command with `field` set to `value`."""
    command = level_command(0.0, 0.0, HOVER_THRUST, 1.0)
    command[FC_COMMAND.slice(field)] = value
    return command



def fc_status(mode: ActiveMode) -> np.ndarray:
    return FC_STATUS.vector(armed=1.0, mode=mode, link_alive=1.0)


class SwitchBench:
    """The failsafe switch as `dut` (threshold 5 m, step speed 1 m/s), flying: the controller
    issues hover thrust, the failsafe 0.9 of it."""

    def __init__(self):
        self.params = dc.replace(load_failsafe_switch(), failsafe_threshold=5.0, step_speed=1.0)
        self.dut = FailsafeSwitch(self.params)
        self.context = self.dut.CreateDefaultContext()
        self.simulator = Simulator(self.dut, self.context)
        self.set(state_estimate=falling(0.0), reference=reference(), arm=[1.0, 1.0],
                 fc_status=fc_status(ActiveMode.ATTITUDE_THRUST),
                 **{"controller.controller_status": status_vector(ControllerReason.OK),
                    "controller.fc_command": self.hover(1.0),
                    "failsafe.fc_command": self.hover(0.9)})

    @staticmethod
    def hover(fraction: float) -> np.ndarray:
        return level_command(0.0, 0.0, fraction * HOVER_THRUST, 1.0)

    def set(self, **values):
        for name, value in values.items():
            self.dut.GetInputPort(name).FixValue(self.context, np.asarray(value, dtype=float))

    def run(self, seconds: float):
        self.simulator.AdvanceTo(self.context.get_time() + seconds)

    def thrust(self) -> float:
        return FC_COMMAND.get(self.dut.GetOutputPort("fc_command").Eval(self.context), "thrust")

    def status(self, field: str) -> float:
        return MANAGER_STATUS.get(self.dut.GetOutputPort("manager_status").Eval(self.context),
                                  field)

    def active(self) -> list[int]:
        return [int(self.dut.GetOutputPort(f"{name}.active").Eval(self.context)[0])
                for name in ("controller", "failsafe")]


@pytest.mark.parametrize("fault, cause", [
    ({"state_estimate": falling(0.0, valid=0.0)}, FailsafeCause.BAD_ESTIMATE),
    ({"state_estimate": falling(np.nan)}, FailsafeCause.BAD_ESTIMATE),
    ({"controller.controller_status": status_vector(ControllerReason.SOLVER_FAILED)},
     FailsafeCause.BAD_CONTROLLER),
    ({"controller.fc_command": spoiled("q_WD", np.nan)}, FailsafeCause.BAD_CONTROLLER),
    ({"controller.fc_command": spoiled("stamp", np.inf)}, FailsafeCause.BAD_CONTROLLER),
    ({"controller.fc_command": spoiled("thrust", 1.5)}, FailsafeCause.BAD_CONTROLLER),
    ({"state_estimate": STATE_ESTIMATE.vector(p_EB=[5.1, 0.0, 5.0])},
     FailsafeCause.CONTROL_ERROR),
    ({"fc_status": fc_status(ActiveMode.FAILSAFE_DESCENT)}, FailsafeCause.FLIGHT_CONTROLLER)])
def test_every_cause_hands_over_at_the_tick_from_the_last_command_and_for_good(fault, cause):
    bench = SwitchBench()
    bench.run(0.1)
    assert bench.active() == [1, 0] and bench.status("mode") == ManagerMode.NORMAL
    bench.set(**fault)
    # The failsafe computes at this tick, reading the command the switch still forwards: the
    # controller's last usable one (an unusable command is never forwarded).
    assert bench.active() == [0, 1]
    assert bench.thrust() == pytest.approx(HOVER_THRUST)
    bench.run(0.01)
    assert bench.status("mode") == ManagerMode.FAILSAFE and bench.status("failsafe_cause") == cause
    assert bench.thrust() == pytest.approx(0.9 * HOVER_THRUST)
    bench.set(state_estimate=falling(0.0), reference=reference(),
              **{"controller.controller_status": status_vector(ControllerReason.OK),
                 "controller.fc_command": bench.hover(1.0)})
    bench.run(1.0)                                   # everything fine again: no way back
    assert bench.active() == [0, 1] and bench.status("mode") == ManagerMode.FAILSAFE


def test_a_reference_step_is_allowed_and_the_allowance_shrinks_at_the_step_speed():
    bench = SwitchBench()
    bench.run(0.1)
    bench.set(reference=reference([12.0, 0.0, 5.0]))        # a 12 m waypoint step: allowed
    bench.run(0.5)
    assert bench.status("mode") == ManagerMode.NORMAL
    assert bench.status("control_error") == pytest.approx(12.0)
    # Not flown at all: 12 m > 5 m + (12 m - 1 m/s t) once t > 5 s.
    bench.run(4.4)
    assert bench.status("mode") == ManagerMode.NORMAL
    bench.run(0.3)
    assert bench.status("mode") == ManagerMode.FAILSAFE
    assert bench.status("failsafe_cause") == FailsafeCause.CONTROL_ERROR


def test_a_reference_moving_with_its_own_velocity_is_no_step_but_may_lead_by_a_chase():
    """A reference moving at v is no step; a vehicle accelerating after it at
    `chase_acceleration` (3 m/s^2) lags it by up to v^2 / (2 a): 1.5 m at 3 m/s."""
    bench = SwitchBench()
    bench.run(0.1)
    k = 0
    while bench.status("mode") == ManagerMode.NORMAL and k < 60:
        k += 1                          # 3 m/s, updated at 20 Hz, the vehicle left behind
        bench.set(reference=reference([0.15 * k, 0.0, 5.0], v=[3.0, 0.0, 0.0]))
        bench.run(0.05)
    assert k == 44                      # the first sample over 5 + 1.5 m (6.6 m): no step grew
    assert bench.status("failsafe_cause") == FailsafeCause.CONTROL_ERROR
    assert bench.status("control_error") == pytest.approx(6.6)


def test_a_car_at_8_ms_may_lead_the_vehicle_by_10_m_one_at_4_ms_by_7_7_m():
    """The car passing the vehicle at the waypoint at 8 m/s led it by 9-10 m while it
    accelerated (campaign, issue 23): 5 m + 8^2 / 6 = 15.7 m are allowed; behind a reference at
    4 m/s, 5 + 2.7 m."""
    bench = SwitchBench()
    bench.run(0.1)
    for k in range(1, 26):              # 8 m/s at 20 Hz: 10 m ahead after 1.25 s
        bench.set(reference=reference([0.4 * k, 0.0, 5.0], v=[8.0, 0.0, 0.0]))
        bench.run(0.05)
    assert bench.status("control_error") == pytest.approx(10.0)
    assert bench.status("mode") == ManagerMode.NORMAL
    bench = SwitchBench()
    bench.run(0.1)
    k = 0
    while bench.status("mode") == ManagerMode.NORMAL and k < 60:
        k += 1
        bench.set(reference=reference([0.2 * k, 0.0, 5.0], v=[4.0, 0.0, 0.0]))
        bench.run(0.05)
    assert bench.status("control_error") == pytest.approx(7.8)   # the first sample over 7.67 m
    assert bench.status("failsafe_cause") == FailsafeCause.CONTROL_ERROR


def test_nothing_is_watched_before_the_take_off_and_after_the_mission_disarmed():
    bench = SwitchBench()
    bench.set(arm=[0.0, 0.0])
    bench.run(0.1)
    for arm in ([0.0, 0.0], [1.0, 0.0]):
        bench.set(arm=arm, state_estimate=falling(0.0, valid=0.0),
                  reference=reference([20.0, 0.0, 5.0]))
        bench.run(0.5)
        assert bench.active() == [1, 0] and bench.status("mode") == ManagerMode.NORMAL
    bench.set(arm=[1.0, 1.0], state_estimate=falling(0.0))
    bench.run(4.9)          # taking off to 20 m: a step from where it rests, allowed ...
    assert bench.status("mode") == ManagerMode.NORMAL
    bench.run(0.3)          # ... until 5 m + (20 m - 1 m/s t) < 20 m, not flown at all
    assert bench.status("failsafe_cause") == FailsafeCause.CONTROL_ERROR
    bench = SwitchBench()
    bench.run(0.1)
    bench.set(arm=[0.0, 0.0], state_estimate=falling(0.0, valid=0.0),
              **{"controller.fc_command": spoiled("thrust", np.nan)})
    bench.run(0.5)          # the mission has disarmed: nothing is watched
    assert bench.active() == [1, 0] and bench.status("mode") == ManagerMode.NORMAL


def test_an_unusable_failsafe_command_is_not_forwarded_either():
    bench = SwitchBench()
    bench.set(state_estimate=falling(0.0, valid=0.0))
    bench.run(0.1)
    bench.set(**{"failsafe.fc_command": spoiled("thrust", np.nan)})
    bench.run(0.1)
    command = bench.dut.GetOutputPort("fc_command").Eval(bench.context)
    assert np.all(np.isfinite(command)) and bench.thrust() == pytest.approx(0.9 * HOVER_THRUST)


def test_the_failsafe_tuning_is_one_file_for_every_stack():
    from alight.diagrams.onboard.controllers import load_controllers_config
    assert load_controllers_config().failsafe == load_failsafe_switch().failsafe


def test_in_failsafe_the_mission_can_no_longer_disarm():
    """Issue 21 fault campaign: the landing mission, not knowing the flight controller flew its own
    failsafe after a link loss, judged itself landed from its estimate and disarmed 1.1 m up. The
    switch's `arm` output is the mission's request until the hand-over, then [1, 1]: the failsafe
    controller disarms itself once on the ground."""
    bench = SwitchBench()
    bench.run(0.1)
    arm = lambda: list(bench.dut.GetOutputPort("arm").Eval(bench.context))
    bench.set(arm=[1.0, 0.0])
    assert arm() == [1.0, 0.0]                      # NORMAL: the mission's request
    bench.set(arm=[1.0, 1.0], fc_status=fc_status(ActiveMode.FAILSAFE_DESCENT))
    bench.run(0.01)
    assert bench.status("mode") == ManagerMode.FAILSAFE
    bench.set(arm=[0.0, 0.0])
    bench.run(0.5)
    assert arm() == [1.0, 1.0]
