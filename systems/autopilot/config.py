"""Parameters of the flight-controller emulation (models/sim_vehicle.yaml, `flight_controller`)."""
import dataclasses as dc

from alight.systems.autopilot.attitude_control import AttitudeControlParams
from alight.systems.autopilot.commander import CommanderParams
from alight.systems.autopilot.ev_fusion import ExternalVisionParams
from alight.systems.autopilot.rate_control import RateControlParams
from alight.systems.params import bounded


@dc.dataclass
class FlightControllerParams:
    period: float = bounded(0.004, 0.001, 0.02, "s")  # 250 Hz (DESIGN.md: 250-500 Hz)
    commander: CommanderParams = dc.field(default_factory=CommanderParams)
    attitude: AttitudeControlParams = dc.field(default_factory=AttitudeControlParams)
    rate: RateControlParams = dc.field(default_factory=RateControlParams)
    # EKF2's external-vision fusion of the `odometry` input (PX4 EKF2_EV_* parameters)
    external_vision: ExternalVisionParams = dc.field(default_factory=ExternalVisionParams)
