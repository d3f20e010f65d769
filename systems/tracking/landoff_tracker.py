"""The landoff tracker, M Sec. 4.2 and 7.4: take-off and landing references, at 100 Hz.

Take-off climbs from the estimated position to `height` above it at `takeoff_speed` along a smooth
profile (`AxisProfile`: braking curve -> speed -> acceleration, limited, with a first-order lag on
the acceleration, which stays continuous). Admittance (M Sec. 4.2): the reference is held
wherever one more step would take it further than `admittance_distance` from the estimated
position, so a vehicle held on the ground (tangled in foliage) is not driven into aggressive
action; it moves on as soon as the vehicle follows.

Landing: the reference descends at `landing_speed` (the horizontal position is held) and is never
more than `landing_offset` below the estimated position, so it goes below the estimated altitude
by that offset on the ground and landing works with an unknown ground height. While the offset
holds, the reference's velocity stays the landing velocity (the controller keeps pushing down).
Touchdown: the apparent mass M(34) of the issued thrust (`last_command`) under
`touchdown_mass_fraction` of the vehicle's mass for `touchdown_time`, with the estimated vertical
speed under `touchdown_speed`; the tracker then reports LANDED on `tracker_status` and 1 on
`landed`, for the caller to disarm. Without `last_command` there is no touchdown detection.

The heading is held. Without a goal (or from a goal's end), the reference stops where its
profile can (the stop point of its velocity) and holds there.
"""
import dataclasses as dc
import enum

import numpy as np

from alight.models import model_path
from alight.systems.boundary import FC_COMMAND, REFERENCE, STATE_ESTIMATE
from alight.systems.control.force_controller import VehicleModel, advance_reference
from alight.systems.control.touchdown import light_time
from alight.systems.params import ConfigError, bounded, load_params
from alight.systems.estimation.frames import reexpress_point
from alight.systems.tracking.chi_tracker import ChiMemory, ChiReason, ChiTracker

ACTIONS = ("takeoff", "land")


@dc.dataclass(frozen=True)
class LandoffGoal:
    """action "takeoff": climb `height` [m] above the estimated position where it starts;
    action "land": descend until touchdown (`height` unused). Raises ValueError when invalid."""
    action: str
    height: float = 0.0

    def __post_init__(self):
        if self.action not in ACTIONS:
            raise ValueError(f"landoff goal: action {self.action!r} is not one of {ACTIONS}")
        if not np.isfinite(self.height):
            raise ValueError(f"landoff goal: height {self.height} must be finite")
        if self.action == "takeoff" and not self.height > 0.0:
            raise ValueError(f"landoff goal: take-off height {self.height} m must be > 0")

    @staticmethod
    def takeoff(height: float) -> "LandoffGoal":
        return LandoffGoal("takeoff", float(height))

    @staticmethod
    def land() -> "LandoffGoal":
        return LandoffGoal("land")


@dc.dataclass
class ProfileParams:
    """The per-axis profile: braking curve, speed, acceleration (first-order lag)."""
    acceleration: float = bounded(1.0, 0.05, 20.0, "m/s^2")
    acceleration_time: float = bounded(0.05, 0.005, 1.0, "s")  # lag: jerk = (a_d - a) / this
    position_gain: float = bounded(1.5, 0.05, 20.0, "1/s")    # speed asked per m to go
    velocity_gain: float = bounded(6.0, 0.1, 100.0, "1/s")    # acceleration per m/s of error
    braking_fraction: float = bounded(0.5, 0.1, 1.0)          # of `acceleration`, to stop

    def check(self, period: float, source: str = "<params>") -> None:
        """The cascade's loops must be separated (each at least twice the outer's bandwidth) and
        the lag at least one period, or the profile can overshoot or ring."""
        if self.velocity_gain < 2.0 * self.position_gain:
            raise ConfigError(f"{source}: key 'profile.velocity_gain' = {self.velocity_gain} must "
                              f"be >= 2 x profile.position_gain ({2.0 * self.position_gain})")
        if 1.0 / self.acceleration_time < 2.0 * self.velocity_gain:
            raise ConfigError(f"{source}: key 'profile.acceleration_time' = "
                              f"{self.acceleration_time} s must be <= 1 / (2 x "
                              f"profile.velocity_gain) = {0.5 / self.velocity_gain:.4g} s")
        if self.acceleration_time < period:
            raise ConfigError(f"{source}: key 'profile.acceleration_time' = "
                              f"{self.acceleration_time} s must be >= the period {period} s")


@dc.dataclass
class LandoffTrackerParams:
    period: float = bounded(0.01, 0.001, 0.1, "s")              # 100 Hz
    takeoff_speed: float = bounded(1.0, 0.05, 10.0, "m/s")
    max_takeoff_height: float = bounded(50.0, 0.1, 1000.0, "m")   # larger goals are refused
    horizontal_speed: float = bounded(1.0, 0.05, 10.0, "m/s")     # to stop a moving start
    admittance_distance: float = bounded(0.5, 0.05, 1e4, "m")     # M Sec. 4.2
    landing_speed: float = bounded(0.5, 0.05, 5.0, "m/s")
    landing_offset: float = bounded(1.0, 0.05, 10.0, "m")         # at most below the estimate
    touchdown_mass_fraction: float = bounded(0.5, 0.05, 0.95)     # of the mass, M(34)
    touchdown_time: float = bounded(0.5, 0.0, 30.0, "s")
    touchdown_speed: float = bounded(0.3, 0.01, 10.0, "m/s")      # |v_z| estimated, at most
    profile: ProfileParams = dc.field(default_factory=ProfileParams)


class Phase(enum.IntEnum):
    HOLD = 0
    TAKEOFF = 1
    LANDING = 2
    LANDED = 3


@dc.dataclass
class LandoffMemory(ChiMemory):
    """The phase, the point the profile goes to (take-off top, horizontal hold), and how long
    the issued thrust has been light [s]."""
    phase: Phase = Phase.HOLD
    target: np.ndarray = dc.field(default_factory=lambda: np.zeros(3))
    light: float = 0.0


class AxisProfile:
    """Per axis: a speed from the braking curve toward a target (or a given speed), an
    acceleration from the speed error, both limited, and a jerk that moves the acceleration
    toward it with the lag `acceleration_time`: no overshoot, speed and acceleration within
    their limits (tests/test_landoff_speed_trackers.py)."""

    def __init__(self, params: ProfileParams):
        self.p = params
        self._braking = params.braking_fraction * params.acceleration

    def braking_speed(self, distance: np.ndarray) -> np.ndarray:
        """The speed from which the profile stops within `distance` [m]."""
        c = self._braking * self.p.acceleration_time
        return -c + np.sqrt(c * c + 2.0 * self._braking * np.abs(distance))

    def stop_point(self, p: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Where the profile comes to rest from speed v (the inverse of `braking_speed`)."""
        return p + v * np.abs(v) / (2.0 * self._braking) + v * self.p.acceleration_time

    def speed_to(self, p, target, up, down) -> np.ndarray:
        """The speed asked toward `target`, at most `up` (positive) and `down` (negative)."""
        e = np.asarray(target) - p
        limit = self.braking_speed(e)
        return np.clip(self.p.position_gain * e, -np.minimum(down, limit),
                       np.minimum(up, limit))

    def jerk(self, v, a, v_desired) -> np.ndarray:
        a_desired = np.clip(self.p.velocity_gain * (np.asarray(v_desired) - v),
                            -self.p.acceleration, self.p.acceleration)
        return (a_desired - a) / self.p.acceleration_time


class LandoffTracker(ChiTracker):
    """Inputs  as `Tracker`, with `goal` a LandoffGoal (None: hold); `last_command` FC_COMMAND
            (optional: the command last issued, for touchdown detection)
    Outputs `reference` REFERENCE (chi of M(16) in E, stamped one period ahead);
            `tracker_status` TRACKER_STATUS (reason: ChiReason); `landed` (1): touchdown
    """

    def __init__(self, params: LandoffTrackerParams, vehicle: VehicleModel):
        params.profile.check(params.period)
        super().__init__(params.period, LandoffMemory(), LandoffGoal.land())
        self.params, self._vehicle = params, vehicle
        self._profile = AxisProfile(params.profile)
        self._command = self.DeclareVectorInputPort("last_command", FC_COMMAND.size)
        self.DeclareVectorOutputPort(
            "landed", 1, lambda context, output: output.SetFromVector(
                [float(self.memory(context).phase == Phase.LANDED)]),
            {self.all_state_ticket()})

    def _begin(self, context, memory: LandoffMemory, goal, estimate) -> ChiReason:
        P = REFERENCE
        if goal is not None and goal.action == "takeoff" and (
                estimate is None or goal.height > self.params.max_takeoff_height):
            return ChiReason.BAD_GOAL
        memory.chi[P.slice("heading_rate")] = 0.0
        memory.target = self._profile.stop_point(P.get(memory.chi, "p"), P.get(memory.chi, "v"))
        memory.phase, memory.light = Phase.HOLD, 0.0
        if goal is not None and goal.action == "takeoff":
            memory.phase = Phase.TAKEOFF
            memory.target[2] = STATE_ESTIMATE.get(estimate, "p_EB")[2] + goal.height
        elif goal is not None:
            memory.phase = Phase.LANDING
        return ChiReason.OK

    def _switch_frame(self, memory: LandoffMemory, R_OldNew, p_OldNew) -> None:
        super()._switch_frame(memory, R_OldNew, p_OldNew)
        memory.target = reexpress_point(memory.target, R_OldNew, p_OldNew)

    def _step(self, context, memory: LandoffMemory, estimate) -> ChiReason:
        P, params = REFERENCE, self.params
        chi = memory.chi
        p, v, a = (P.get(chi, f) for f in ("p", "v", "a"))
        landing = memory.phase in (Phase.LANDING, Phase.LANDED)
        up = np.array([params.horizontal_speed] * 2 + [params.takeoff_speed])
        down = np.array([params.horizontal_speed] * 2 + [params.landing_speed])
        v_desired = self._profile.speed_to(p, memory.target, up, down)
        if landing:
            v_desired[2] = -params.landing_speed
        chi[P.slice("j")] = self._profile.jerk(v, a, v_desired)
        new = advance_reference(chi, self.period)
        reason = {Phase.HOLD: ChiReason.OK, Phase.TAKEOFF: ChiReason.TAKING_OFF,
                  Phase.LANDING: ChiReason.LANDING, Phase.LANDED: ChiReason.LANDED}[memory.phase]
        if estimate is not None:
            p_EB = STATE_ESTIMATE.get(estimate, "p_EB")
            if landing:
                self._hold_offset(new, p_EB)
                self._detect_touchdown(context, memory, estimate)
            elif self._admittance_holds(p, P.get(new, "p"), p_EB):
                new = chi.copy()
                new[P.slice("v")] = new[P.slice("a")] = new[P.slice("j")] = 0.0
                reason = ChiReason.ADMITTANCE
        memory.chi = new
        if memory.phase == Phase.TAKEOFF and np.linalg.norm(
                P.get(new, "p") - memory.target) < 0.01 and np.linalg.norm(P.get(new, "v")) < 0.01:
            memory.phase = Phase.HOLD
        return ChiReason.LANDED if memory.phase == Phase.LANDED else reason

    def _admittance_holds(self, p_old, p_new, p_EB) -> bool:
        """M Sec. 4.2: one more step would take the reference further than the admittance
        distance from the estimate, and further than it is."""
        distance = np.linalg.norm(p_new - p_EB)
        return distance > self.params.admittance_distance and \
            distance > np.linalg.norm(p_old - p_EB)

    def _hold_offset(self, chi: np.ndarray, p_EB: np.ndarray) -> None:
        """Landing: never more than `landing_offset` below the estimate (at the landing speed)."""
        floor = p_EB[2] - self.params.landing_offset
        p = REFERENCE.slice("p")
        if chi[p][2] < floor:
            chi[p.start + 2] = floor
            chi[REFERENCE.slice("v").start + 2] = -self.params.landing_speed
            chi[REFERENCE.slice("a").start + 2] = chi[REFERENCE.slice("j").start + 2] = 0.0

    def _detect_touchdown(self, context, memory: LandoffMemory, estimate) -> None:
        if memory.phase != Phase.LANDING or not self._command.HasValue(context):
            return
        slow = abs(STATE_ESTIMATE.get(estimate, "v_EB")[2]) < self.params.touchdown_speed
        memory.light = light_time(memory.light, self._command.Eval(context), self._vehicle,
                                  self.params.touchdown_mass_fraction, self.period) \
            if slow else 0.0
        if memory.light >= self.params.touchdown_time:
            memory.phase = Phase.LANDED


def load_landoff_tracker_params(filename: str = "landoff_tracker.yaml") -> LandoffTrackerParams:
    """A path, or a file name in models/; raises ConfigError naming the file and the key."""
    path = model_path(filename)
    params = load_params(LandoffTrackerParams, path)
    params.profile.check(params.period, str(path))
    return params


def make_landoff_tracker(vehicle: VehicleModel, params: LandoffTrackerParams) -> LandoffTracker:
    """`vehicle`: what the controllers know of it (models/controllers.yaml `vehicle`)."""
    return LandoffTracker(params, vehicle)
