"""The flight-stack controllers (M Sec. 5) from their parameter file, models/controllers.yaml."""
import dataclasses as dc

from alight.models import model_path
from alight.systems.control.disturbance import DisturbanceLimits, resolve_source
from alight.systems.control.failsafe import FailsafeController, FailsafeParams
from alight.systems.control.force_controller import VehicleModel
from alight.systems.control.linear_model import LinearModelParams
from alight.systems.control.linear_mpc import LinearMpc, LinearMpcParams
from alight.systems.control.mpc_force import MpcForceController, MpcForceParams
from alight.systems.control.se3 import Se3Controller, Se3Params
from alight.systems.control.so3 import So3Params
from alight.systems.params import bounded, choice, load_params, param_file

CONTROLLERS = ("se3", "mpc", "failsafe", "linear_mpc")


SOURCES = ("integrators", "auto", "acceleration")


@dc.dataclass
class DisturbanceSources:
    """Each force controller's external force, beyond M(35): also measured from the estimate's
    acceleration (`acceleration`, low-passed by `acceleration_gain` per tick), or learned by the
    integrators alone (`integrators`, M); `auto`: `acceleration` on the VIO's odometry (its a_EB
    is the IMU's), the integrators on any other (`resolve_force_disturbance`).
    models/controllers.yaml says why each has its default."""
    se3: str = choice(*SOURCES)
    mpc: str = choice(*SOURCES)


@dc.dataclass
class ControllersConfig:
    period: float = bounded(0.01, 0.001, 0.1, "s")  # 100 Hz (DESIGN.md)
    max_prediction: float = bounded(0.1, 0.0, 1.0, "s")  # estimate latency compensated at most
    disturbance_source: DisturbanceSources = dc.field(default_factory=DisturbanceSources)
    acceleration_gain: float = bounded(0.05, 0.0, 1.0)
    vehicle: VehicleModel = dc.field(default_factory=VehicleModel)
    so3: So3Params = dc.field(default_factory=So3Params)
    disturbance_limits: DisturbanceLimits = dc.field(default_factory=DisturbanceLimits)
    se3: Se3Params = dc.field(default_factory=Se3Params)
    mpc: MpcForceParams = dc.field(default_factory=MpcForceParams)
    failsafe: FailsafeParams = param_file(FailsafeParams, "failsafe.yaml")
    # The landing paper's linear MPC (L Sec. 6.1-6.2, attitude + thrust, 20 Hz) as a controller
    # of the control manager: its tuning and identified model (models/).
    linear_mpc: LinearMpcParams = param_file(LinearMpcParams, "linear_mpc.yaml")
    linear_model: LinearModelParams = param_file(LinearModelParams, "linear_model.yaml")


def load_controllers_config(filename: str = "controllers.yaml") -> ControllersConfig:
    """A path, or a file name in models/."""
    return load_params(ControllersConfig, model_path(filename))


def resolve_force_disturbance(config: ControllersConfig, estimator: str) -> ControllersConfig:
    """`config` with each `disturbance_source: auto` made `acceleration` on the VIO's odometry
    and `integrators` on any other (as the landing MPC's `resolve_disturbance`)."""
    sources = {name: resolve_source(source, estimator, otherwise="integrators")
               for name, source in dc.asdict(config.disturbance_source).items()}
    return dc.replace(config, disturbance_source=DisturbanceSources(**sources))


def _acceleration_gain(config: ControllersConfig, name: str) -> float:
    """Controller `name`'s measured disturbance gain; an unresolved `auto` (no odometry named:
    the flight tests and benches on mocap) flies the integrators alone, as on mocap."""
    source = getattr(config.disturbance_source, name)
    return config.acceleration_gain if source == "acceleration" else 0.0


def make_controller(name: str, config: ControllersConfig):
    """The LeafSystem of controller `name` (one of CONTROLLERS)."""
    if name == "se3":
        return Se3Controller(config.vehicle, config.so3, config.se3, config.disturbance_limits,
                             config.period, config.max_prediction, _acceleration_gain(config, "se3"))
    if name == "mpc":
        return MpcForceController(config.vehicle, config.so3, config.mpc,
                                  config.disturbance_limits, config.period,
                                  config.max_prediction, _acceleration_gain(config, "mpc"))
    if name == "failsafe":
        return FailsafeController(config.vehicle, config.failsafe, config.period)
    if name == "linear_mpc":
        return LinearMpc(config.linear_model, config.linear_mpc)
    raise ValueError(f"unknown controller {name!r}: expected one of {list(CONTROLLERS)}")
