"""Builds the flight-controller emulation: commander -> inner loop (attitude, rate PID, mixer; its
ESC commands held every period, like PWM outputs)."""
from pydrake.systems.framework import Diagram, DiagramBuilder

from alight.systems.autopilot.commander import Commander
from alight.systems.autopilot.config import FlightControllerParams
from alight.systems.autopilot.inner_loop import InnerLoop
from alight.systems.plant.hexacopter import Airframe


def make_flight_controller(params: FlightControllerParams, airframe: Airframe) -> Diagram:
    """Inputs `fc_command`, `fc_attitude`, `vertical_velocity`; outputs `motor_command` (held
    every period, like PWM outputs), `armed` and `fc_status`."""
    builder = DiagramBuilder()
    commander = builder.AddNamedSystem("commander", Commander(
        params.commander, airframe.thrust_curve, params.period))
    inner = builder.AddNamedSystem("inner_loop", InnerLoop(
        params.attitude, params.rate, airframe, params.period))
    builder.Connect(commander.GetOutputPort("setpoint"), inner.GetInputPort("setpoint"))
    builder.ExportInput(commander.GetInputPort("fc_command"), "fc_command")
    builder.ExportInput(commander.GetInputPort("vertical_velocity"), "vertical_velocity")
    builder.ExportInput(commander.GetInputPort("fc_attitude"), "fc_attitude")
    builder.ConnectInput("fc_attitude", inner.GetInputPort("fc_attitude"))
    builder.ExportOutput(inner.GetOutputPort("motor_command"), "motor_command")
    builder.ExportOutput(commander.GetOutputPort("armed"), "armed")
    builder.ExportOutput(commander.GetOutputPort("fc_status"), "fc_status")
    diagram = builder.Build()
    diagram.set_name("flight_controller")
    return diagram
