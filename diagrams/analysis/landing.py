"""Scoring a landing run physically (DESIGN.md "Landing is judged physically") with the columns of
L Table 1: outcome, average target speed, e_xy at touchdown, tracking duration (first detection
to touchdown), plus the mission time, the touchdown speed, the peak force on one leg, the signed
offset ahead of the platform's centre at touchdown and the reason for a failure.

Judged from the simulation-only ground truth, never from the mission's own view, by contact: the
vehicle's contacts with the platform, the ground and anything else, accumulated every 4 ms
(alight.systems.sensors.contacts), so that no contact and no force peak falls between two logged
samples. The first contact after take-off is the touchdown: it must be the legs on the platform,
within the scenario's impact speed limits (relative to the platform, just before the contact).
From the touchdown to the end of the run, which lasts the settle time after the disarm, the
vehicle touches nothing but the platform with its legs (a bounce on them allowed), no leg carries
more than the airframe's structural limit `max_leg_force` at any sample, and the vehicle stays
over the platform and upright; the earliest of these failures is the reason. Over the last
`REST_WINDOW` it rests on its legs on the platform, at rest relative to it.
"""
import dataclasses as dc

import numpy as np
import yaml

from alight.diagrams.running.run_log import RunLog
from alight.systems.mission.landing import Mode, Reason
from alight.systems.rotations import rotation_matrix, tilt_deg

PLATFORM_HALF_SIZE = 0.75   # m, the 1.5 m x 1.5 m platform
FOOT_REACH = 0.22           # m, the F550's feet from the body axis (legs can touch the edge)
AIRBORNE = 1.0              # m above the resting height: the vehicle has taken off
MAX_TILT = 20.0             # deg, relative to the platform: tipped over beyond
REST_WINDOW = 0.5           # s, at the end of the settle time: resting on the legs, at rest
REST_SPEED = 0.1            # m/s relative to the platform: at rest (0.00-0.04 measured)
SCENARIO_FILE = "scenario.yaml"  # a run folder's resolved scenario (diagrams.scenario's name)


@dc.dataclass
class LandingScore:
    success: bool
    reason: str                   # "landed" or why it failed
    target_speed: float           # m/s, mean from the first detection to touchdown (or the end)
    e_xy: float                   # m at touchdown (nan without one)
    tracking_duration: float      # s, first detection to touchdown (nan without either)
    mission_time: float           # s, start to touchdown (or to the end of the run)
    touchdown_speed: float        # m/s, vertical, relative to the platform (nan without one)
    peak_leg_force: float         # N, the largest normal force on one leg (nan without touchdown)
    # m at touchdown along the platform's forward axis x_T, signed (+: ahead of its centre): a
    # reference that leads or lags the car shows here as a bias growing with its speed
    e_ahead: float = float("nan")

    def row(self) -> str:
        """The run as a row of L Table 1."""
        outcome = "S" if self.success else "F"
        return (f"v {self.target_speed:4.1f} m/s  e_xy {100 * self.e_xy:5.1f} cm (ahead "
                f"{100 * self.e_ahead:+5.1f})  tracking "
                f"{self.tracking_duration:5.2f} s  mission {self.mission_time:5.1f} s  "
                f"touchdown {self.touchdown_speed:4.2f} m/s  peak leg {self.peak_leg_force:4.0f} N"
                f"  {outcome}  ({self.reason})")


def first_index(mask: np.ndarray) -> int | None:
    """The first index where `mask` holds, None if nowhere."""
    index = np.flatnonzero(mask)
    return int(index[0]) if len(index) else None


def contact_began(accumulated: np.ndarray) -> np.ndarray:
    """Samples at which an accumulated contact time (`legs_ground_time`, ...) grew: a contact
    within the interval since the previous sample, however short."""
    return np.diff(accumulated, prepend=accumulated[0]) > 0.0


def score_landing(run: RunLog, vertical_limit: float, horizontal_limit: float,
                  mission_run: RunLog | None = None, *, settle_time: float | None = None,
                  max_leg_force: float | None = None) -> LandingScore:
    """Scores a landing run folder against the impact limits [m/s], the settle time [s] and the
    structural limit of a leg [N] (by default the run's own: its scenario.yaml's
    `scoring.settle_time` and `vehicle.airframe.max_leg_force`). When the mission flew in another
    process (`alight hil --mission land` against `alight sim-autopilot`), `run` is the simulated
    autopilot's folder (ground truth, flight controller; give the two limits) and `mission_run`
    the onboard one (its `mission_status`, its clock `autopilot_clock_offset` s behind `run`'s)."""
    if settle_time is None or max_leg_force is None:
        scenario = pinned_scenario(run)
        settle_time = scenario["scoring"]["settle_time"] if settle_time is None else settle_time
        max_leg_force = (scenario["vehicle"]["airframe"]["max_leg_force"]
                         if max_leg_force is None else max_leg_force)
    truth = run["ground_truth"]
    t = truth["time"].to_numpy()
    field = lambda name: run.field("ground_truth", name).to_numpy()
    p_B, v_B, p_T, v_T, q_B, q_T = (field(name) for name in
                                    ("p_WB", "v_WB", "p_WT", "v_WT", "q_WB", "q_WT"))
    rest = p_B[0, 2]  # on its legs on the ground at the start (ground at z = 0)
    status = (mission_run or run)["mission_status"]
    detections = status["first_detection"].dropna()
    first_detection = float(detections.iloc[0]) if len(detections) else np.nan
    if mission_run is not None:
        first_detection += mission_run.metadata["autopilot_clock_offset"]
    rel = p_B - p_T
    rel_T = np.einsum("nji,nj->ni", np.array([rotation_matrix(q) for q in q_T]), rel)
    takeoff = first_index(p_B[:, 2] > rest + AIRBORNE)
    nan = float("nan")
    speed = lambda end: float(np.mean(np.linalg.norm(v_T[_speed_window(t, first_detection, end)],
                                                     axis=1)))
    peak_leg_force = float(truth["peak_leg_force"].iloc[-1])

    def failed(reason: str, end: int, touchdown: int | None = None) -> LandingScore:
        if touchdown is None:
            return LandingScore(False, reason, speed(end), nan, nan, float(t[end]), nan, nan)
        return LandingScore(False, reason, speed(end), float(np.linalg.norm(rel[touchdown, :2])),
                            t[end] - first_detection, float(t[end]),
                            _descent_speed(v_B, v_T, touchdown), peak_leg_force,
                            float(rel_T[touchdown, 0]))

    if takeoff is None:
        return failed("never took off", len(t) - 1)
    after = np.arange(len(t)) > takeoff
    on_platform = after & contact_began(truth["legs_platform_time"].to_numpy())
    on_ground = after & contact_began(truth["legs_ground_time"].to_numpy())
    collided = after & contact_began(truth["other_contact_time"].to_numpy())
    touchdown = first_index(on_platform | on_ground | collided)
    if touchdown is None:
        reason = "no detection" if np.isnan(first_detection) else "no touchdown in time"
        return failed(reason, len(t) - 1)
    if on_ground[touchdown] or collided[touchdown]:
        if not collided[touchdown] and (status["reason"] == Reason.SEARCH_TIMEOUT).any():
            return LandingScore(False, RETURNED_HOME, speed(touchdown), nan, nan,   # no target
                                float(t[touchdown]), _descent_speed(v_B, np.zeros_like(v_B),
                                                                    touchdown), peak_leg_force)
        return failed("touched the ground" if on_ground[touchdown] else COLLIDED, touchdown,
                      touchdown)
    vertical = _descent_speed(v_B, v_T, touchdown)
    horizontal = float(np.linalg.norm(v_B[touchdown - 1, :2] - v_T[touchdown - 1, :2]))
    if vertical > vertical_limit or horizontal > horizontal_limit:
        return failed(f"impact too hard ({vertical:.1f} m/s down, {horizontal:.1f} m/s across)",
                      touchdown, touchdown)
    end = len(t) - 1
    since = np.arange(len(t)) >= touchdown
    over_platform = np.all(np.abs(rel_T[:, :2]) <= PLATFORM_HALF_SIZE + FOOT_REACH, axis=1)
    tilt = tilt_deg(q_B) - tilt_deg(q_T)
    overloaded = truth["peak_leg_force"].to_numpy() > max_leg_force
    overload = (f"impact too hard for the legs ({peak_leg_force:.0f} N on a leg, limit "
                f"{max_leg_force:.0f} N)")
    # What went wrong from the touchdown on, the earliest first.
    events = [(first_index(since & on_ground), "touched the ground"),
              (first_index(since & collided), COLLIDED),
              (first_index(since & overloaded), overload),
              (first_index(since & ~over_platform), "slid off the platform"),
              (first_index(since & (np.abs(tilt) > MAX_TILT)), "tipped over")]
    happened = [(at, reason) for at, reason in events if at is not None]
    if happened:
        return failed(min(happened, key=lambda event: event[0])[1], touchdown, touchdown)
    armed = run["fc_status"]["armed"].to_numpy() > 0.5
    disarms = np.flatnonzero(~armed[1:] & armed[:-1]) + 1
    disarmed_at = run["fc_status"]["time"].to_numpy()[disarms[-1]] if len(disarms) else nan
    settled = (t >= t[end] - REST_WINDOW) & since
    resting = truth["legs_platform_force"].to_numpy() > 0.0
    # The vehicle's speed relative to the platform where it stands: its position's rate in the
    # platform frame T. On a turning car a vehicle at rest r off the centre moves with the
    # platform at v_T + w_T x r, not v_T (the MBZIRC figure-eight's curve: 0.29 rad/s x 0.37 m
    # read 0.11 m/s "relative" speed for a vehicle that had not moved on the platform).
    relative_speed = np.linalg.norm(np.gradient(rel_T, t, axis=0), axis=1)
    checks = [(armed[-1], "still armed"),
              (t[end] - disarmed_at < settle_time - _period(t),
               "run ended before the settle time"),
              (not np.all(resting[settled]), "not resting on the platform"),
              (np.any(relative_speed[settled] > REST_SPEED), "not at rest on the platform")]
    for bad, reason in checks:
        if bad:
            return failed(reason, touchdown, touchdown)
    return LandingScore(True, "landed", speed(touchdown), float(np.linalg.norm(rel[touchdown, :2])),
                        float(t[touchdown] - first_detection), float(t[touchdown]), vertical,
                        peak_leg_force, float(rel_T[touchdown, 0]))


COLLIDED = "hit the car or touched with the airframe"
RETURNED_HOME = "landed at the take-off point: no target seen within the search timeout"


def _descent_speed(v_B: np.ndarray, v_T: np.ndarray, touchdown: int) -> float:
    """Downward speed relative to the platform at the last sample before the first contact."""
    return float(-(v_B[touchdown - 1, 2] - v_T[touchdown - 1, 2]))


def _period(t: np.ndarray) -> float:
    return float(np.median(np.diff(t))) if len(t) > 1 else 0.0


def pinned_scenario(run: RunLog) -> dict:
    """A run folder's resolved scenario (scenario.yaml, as diagrams/scenario.py writes it; this
    layer reads run folders only) as plain YAML data, the typed tags dropped."""
    path = run.path / SCENARIO_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing; a run folder without its scenario is scored "
                                f"with settle_time and max_leg_force given")
    return yaml.load(path.read_text(), Loader=_UntaggedLoader)


class _UntaggedLoader(yaml.SafeLoader):
    """YAML without the typed tags (`!WaypointPlan`, ...) of Drake's yaml_dump_typed."""


_UntaggedLoader.add_multi_constructor("!", lambda loader, suffix, node: (
    loader.construct_mapping(node, deep=True) if isinstance(node, yaml.MappingNode) else
    loader.construct_sequence(node, deep=True) if isinstance(node, yaml.SequenceNode) else
    loader.construct_scalar(node)))


def _speed_window(t: np.ndarray, start: float, end: int) -> np.ndarray:
    """Samples from `start` [s] (the whole run if nan) to index `end`."""
    window = np.arange(len(t)) <= end
    if np.isfinite(start):
        window &= t >= start
    return window if window.any() else np.arange(len(t)) <= end


def mission_transitions(run: RunLog) -> list[tuple[float, Mode, Reason]]:
    """Every mode transition of a landing run: (time [s], new mode, reason)."""
    status = run["mission_status"]
    changed = status[status["transitions"].diff().fillna(status["transitions"]) != 0]
    return [(float(r["time"]), Mode(int(r["mode"])), Reason(int(r["reason"])))
            for _, r in changed.iterrows()]


def tracker_switches(run: RunLog) -> list[tuple[float, str]]:
    """The control manager's active tracker over a managed landing run: (time [s], name) at the
    start and at every switch (`manager_status`; names from the run's metadata)."""
    names = run.metadata["trackers"]
    status = run["manager_status"]
    changed = status[status["tracker_switches"].diff().fillna(1.0) != 0]
    return [(float(row["time"]), names[int(row["tracker"])]) for _, row in changed.iterrows()]
