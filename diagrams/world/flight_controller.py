"""Builds the flight-controller emulation: commander -> inner loop (attitude, rate PID, mixer; its
ESC commands held every period, like PWM outputs), and EKF2's external-vision fusion of the
`odometry` input into the autopilot's local position."""
from pydrake.systems.framework import Diagram, DiagramBuilder

from alight.systems.autopilot.commander import Commander
from alight.systems.autopilot.config import FlightControllerParams
from alight.systems.autopilot.ev_fusion import ExternalVisionFusion
from alight.systems.autopilot.inner_loop import InnerLoop
from alight.systems.plant.hexacopter import Airframe


def make_flight_controller(params: FlightControllerParams, airframe: Airframe) -> Diagram:
    """Inputs `fc_command`, `fc_attitude`, `vertical_velocity`, `odometry` (external vision, may
    stay unconnected), `imu`; outputs `motor_command` (held every period, like PWM outputs),
    `armed`, `fc_status` and `local_position` (ev_fusion.LOCAL_POSITION)."""
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
    fusion = builder.AddNamedSystem("ev_fusion", ExternalVisionFusion(params.external_vision))
    builder.ExportInput(fusion.GetInputPort("odometry"), "odometry")
    builder.ExportInput(fusion.GetInputPort("imu"), "imu")
    builder.ConnectInput("fc_attitude", fusion.GetInputPort("fc_attitude"))
    builder.ExportOutput(fusion.GetOutputPort("local_position"), "local_position")
    builder.ExportOutput(inner.GetOutputPort("motor_command"), "motor_command")
    builder.ExportOutput(commander.GetOutputPort("armed"), "armed")
    builder.ExportOutput(commander.GetOutputPort("fc_status"), "fc_status")
    diagram = builder.Build()
    diagram.set_name("flight_controller")
    return diagram
