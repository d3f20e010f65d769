"""Builds the flight-controller emulation: commander -> attitude -> rate PID -> mixer -> hold."""
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import ZeroOrderHold

from alight.systems.autopilot.attitude_control import AttitudeController
from alight.systems.autopilot.commander import Commander
from alight.systems.autopilot.config import FlightControllerParams
from alight.systems.autopilot.mixer import Mixer
from alight.systems.autopilot.rate_control import RateController
from alight.systems.plant.hexacopter import Airframe


def make_flight_controller(params: FlightControllerParams, airframe: Airframe) -> Diagram:
    """Inputs `fc_command`, `fc_attitude`, `vertical_velocity`; outputs `motor_command` (held
    every period, like PWM outputs), `armed` and `fc_status`."""
    builder = DiagramBuilder()
    commander = builder.AddNamedSystem("commander", Commander(
        params.commander, airframe.thrust_curve, params.period))
    attitude = builder.AddNamedSystem("attitude_controller", AttitudeController(params.attitude))
    rate = builder.AddNamedSystem("rate_controller", RateController(
        params.rate, airframe.inertia, params.period))
    mixer = builder.AddNamedSystem("mixer", Mixer(airframe))
    hold = builder.AddNamedSystem("output_hold", ZeroOrderHold(params.period, airframe.num_rotors))
    setpoint = commander.GetOutputPort("setpoint")
    builder.Connect(setpoint, attitude.GetInputPort("setpoint"))
    builder.Connect(setpoint, rate.GetInputPort("setpoint"))
    builder.Connect(setpoint, mixer.GetInputPort("setpoint"))
    builder.Connect(attitude.GetOutputPort("rate_setpoint"), rate.GetInputPort("rate_setpoint"))
    builder.Connect(rate.GetOutputPort("torque"), mixer.GetInputPort("torque"))
    builder.Connect(mixer.GetOutputPort("motor_command"), hold.get_input_port())
    builder.ExportInput(commander.GetInputPort("fc_command"), "fc_command")
    builder.ExportInput(commander.GetInputPort("vertical_velocity"), "vertical_velocity")
    builder.ExportInput(commander.GetInputPort("fc_attitude"), "fc_attitude")
    builder.ConnectInput("fc_attitude", attitude.GetInputPort("fc_attitude"))
    builder.ConnectInput("fc_attitude", rate.GetInputPort("fc_attitude"))
    builder.ExportOutput(hold.get_output_port(), "motor_command")
    builder.ExportOutput(commander.GetOutputPort("armed"), "armed")
    builder.ExportOutput(commander.GetOutputPort("fc_status"), "fc_status")
    diagram = builder.Build()
    diagram.set_name("flight_controller")
    return diagram
