"""Judging a flight flown with an injected fault (issue 21's fault campaign, bench/faults.py): was
it safe, and did it still do its job? From the simulation-only ground truth (contacts included)
and the run folder's logged streams, never from the stack's own view.

Unsafe, the first of:
- `nan at actuator`: a NaN or infinite value in the command the vehicle received (`fc_command`)
  or in the flight controller's ESC commands (ground truth `motor_command`);
- `hard impact`: a leg loaded over the airframe's `max_leg_force`, anything but the legs touching
  (airframe on the ground or the car), or the first touchdown after the take-off faster than the
  scenario's vertical impact limit (relative to what it touched: the ground, or the platform);
- `flyaway`: the vehicle more than `FLYAWAY` horizontally from the mission's area at any time:
  the take-off point and the waypoint legs, or every point the car drove through.
Safe, then:
- `landed`: the mission's own success (a landing scored by `score_landing`; a waypoint flight
  that flew its plan, no failsafe, landed and disarmed at rest on its legs);
- `failsafe landing`: a failsafe took over (the switch's or the manager's `manager_status` mode
  FAILSAFE, or the flight controller's own failsafe descent on a lost command link) and the
  vehicle ended at rest on its legs, disarmed;
- `not landed`: anything else (e.g. a landing that missed the platform, a flight still in the air
  when the time ran out), with the reason.
"""
import dataclasses as dc

import numpy as np

from alight.diagrams.analysis.landing import (AIRBORNE, REST_SPEED, REST_WINDOW, contact_began,
                                              first_index, pinned_scenario, score_landing)
from alight.diagrams.running.run_log import RunLog
from alight.systems.boundary import ActiveMode
from alight.systems.managers.control_manager import ManagerMode

FLYAWAY = 10.0     # m, horizontal, beyond the mission's area: a flyaway
LANDED, FAILSAFE_LANDING, NOT_LANDED, UNSAFE = ("landed", "failsafe landing", "not landed",
                                                "unsafe")
OUTCOMES = (LANDED, FAILSAFE_LANDING, NOT_LANDED, UNSAFE)


@dc.dataclass
class FaultOutcome:
    outcome: str          # one of OUTCOMES
    reason: str           # why (unsafe: nan at actuator / hard impact / flyaway, with figures)
    failsafe: bool        # a failsafe took over (onboard, or the flight controller's)
    distance: float       # m, the largest horizontal distance from the mission's area
    peak_leg_force: float  # N
    touchdown_speed: float  # m/s, down, relative to what the legs first touched (nan: none)


def mission_area(run: RunLog, scenario: dict) -> np.ndarray:
    """(N, 2) points of the mission's area: the waypoint legs (every 0.1 m) from the take-off
    point, or the car's path (the ground truth's target)."""
    truth = run["ground_truth"]
    start = truth[["p_WB_0", "p_WB_1"]].to_numpy()[:1]
    if truth["target_present"].iloc[0] > 0.5:
        return np.vstack([start, truth[["p_WT_0", "p_WT_1"]].to_numpy()])
    corners = np.vstack([start, np.asarray(scenario["mission"]["waypoints"], float)[:, :2]])
    legs = [np.linspace(a, b, max(2, int(np.linalg.norm(b - a) / 0.1) + 1))
            for a, b in zip(corners[:-1], corners[1:])]
    return np.vstack([corners, *legs])


def _distance_from(points: np.ndarray, area: np.ndarray, chunk: int = 500) -> np.ndarray:
    return np.concatenate([np.min(np.linalg.norm(points[i:i + chunk, None] - area[None], axis=2),
                                  axis=1) for i in range(0, len(points), chunk)])


def judge_fault_run(run: RunLog) -> FaultOutcome:
    """The outcome of a run folder (the module text's rules)."""
    scenario = pinned_scenario(run)
    truth = run["ground_truth"]
    t = truth["time"].to_numpy()
    field = lambda name: run.field("ground_truth", name).to_numpy()
    p_B, v_B, v_T = field("p_WB"), field("v_WB"), field("v_WT")
    failsafe = bool(np.any(run["manager_status"]["mode"].to_numpy() == ManagerMode.FAILSAFE)
                    or np.any(run["fc_status"]["mode"].to_numpy()
                              == ActiveMode.FAILSAFE_DESCENT))
    peak = float(truth["peak_leg_force"].iloc[-1])
    limit = scenario["vehicle"]["airframe"]["max_leg_force"]
    vertical_limit = scenario["scoring"]["impact"]["vertical_speed"]
    takeoff = first_index(p_B[:, 2] > p_B[0, 2] + min(AIRBORNE, 0.3))
    after = np.arange(len(t)) > (takeoff if takeoff is not None else len(t))
    platform = after & contact_began(truth["legs_platform_time"].to_numpy())
    ground = after & contact_began(truth["legs_ground_time"].to_numpy())
    other = after & contact_began(truth["other_contact_time"].to_numpy())
    touchdown = first_index(platform | ground)
    speed = float("nan") if touchdown is None else float(
        -(v_B[touchdown - 1, 2] - (v_T[touchdown - 1, 2] if platform[touchdown] else 0.0)))
    step = max(1, int(round(0.1 / np.median(np.diff(t)))))     # judged at 10 Hz
    distance = float(np.max(_distance_from(p_B[::step, :2], mission_area(run, scenario))))
    outcome = lambda kind, reason: FaultOutcome(kind, reason, failsafe, distance, peak, speed)

    commands = run["fc_command"].drop(columns="time").to_numpy(float)
    if not np.all(np.isfinite(commands)) or not np.all(np.isfinite(field("motor_command"))):
        return outcome(UNSAFE, "nan at actuator")
    if peak > limit:
        return outcome(UNSAFE, f"hard impact ({peak:.0f} N on a leg, limit {limit:.0f} N)")
    if other.any():
        return outcome(UNSAFE, "hard impact (touched with the airframe)")
    if speed > vertical_limit:
        return outcome(UNSAFE, f"hard impact (touchdown {speed:.1f} m/s, limit "
                               f"{vertical_limit:.1f} m/s)")
    if distance > FLYAWAY:
        return outcome(UNSAFE, f"flyaway ({distance:.1f} m from the mission's area)")
    if truth["target_present"].iloc[0] > 0.5:
        score = score_landing(run, vertical_limit, scenario["scoring"]["impact"][
            "horizontal_speed"])
        if score.success:
            return outcome(LANDED, "landed")
        reason = score.reason
    else:
        reason = "" if run.metadata.get("landed") else "did not finish its plan"
    settled = t >= t[-1] - REST_WINDOW
    resting = (truth["legs_ground_force"].to_numpy() + truth["legs_platform_force"].to_numpy()
               > 0.0)[settled]
    at_rest = np.all(np.linalg.norm(v_B - v_T * (truth["legs_platform_force"].to_numpy()
                                                 > 0.0)[:, None], axis=1)[settled] <= REST_SPEED)
    down = bool(np.all(resting) and at_rest and run["fc_status"]["armed"].iloc[-1] < 0.5)
    if failsafe:
        return outcome(FAILSAFE_LANDING, "failsafe landing") if down else \
            outcome(NOT_LANDED, "failsafe still flying at the end")
    if not reason and down:
        return outcome(LANDED, "landed")
    return outcome(NOT_LANDED, reason or "not at rest on its legs, disarmed, at the end")
