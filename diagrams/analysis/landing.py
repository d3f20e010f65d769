"""Scoring a landing run physically (DESIGN.md "Landing is judged physically") with the columns of
L Table 1: outcome, average target speed, e_xy at touchdown, tracking duration (first detection
to touchdown), plus the mission time and the reason for a failure.

Judged from the simulation-only ground truth, never from the mission's own view: the first
contact of the legs with anything after take-off is the touchdown (the body at its resting height
above the platform top, or above the ground); a landing succeeds when that contact is on the
platform within the scenario's impact limits and the vehicle, disarmed, is still at rest on the
platform, upright, at the end of the run.
"""
import dataclasses as dc

import numpy as np

from alight.diagrams.running.run_log import RunLog
from alight.systems.mission.landing import Mode, Reason
from alight.systems.rotations import rotation_matrix, tilt_deg

PLATFORM_HALF_SIZE = 0.75   # m, the 1.5 m x 1.5 m platform
FOOT_REACH = 0.22           # m, the F550's feet from the body axis (legs can touch the edge)
CONTACT_TOLERANCE = 0.03    # m, above the resting height: the feet touch
AIRBORNE = 1.0              # m above the resting height: the vehicle has taken off


@dc.dataclass
class LandingScore:
    success: bool
    reason: str                   # "landed" or why it failed
    target_speed: float           # m/s, mean from the first detection to touchdown (or the end)
    e_xy: float                   # m at touchdown (nan without one)
    tracking_duration: float      # s, first detection to touchdown (nan without either)
    mission_time: float           # s, start to touchdown (or to the end of the run)
    touchdown_speed: float        # m/s, vertical, relative to the platform (nan without one)

    def row(self) -> str:
        """The run as a row of L Table 1."""
        outcome = "S" if self.success else "F"
        return (f"v {self.target_speed:4.1f} m/s  e_xy {100 * self.e_xy:5.1f} cm  tracking "
                f"{self.tracking_duration:5.2f} s  mission {self.mission_time:5.1f} s  "
                f"touchdown {self.touchdown_speed:4.2f} m/s  {outcome}  ({self.reason})")


def _first(mask: np.ndarray) -> int | None:
    index = np.flatnonzero(mask)
    return int(index[0]) if len(index) else None


def score_landing(run: RunLog, vertical_limit: float, horizontal_limit: float,
                  mission_run: RunLog | None = None) -> LandingScore:
    """Scores a `run_landing` run folder against the impact limits [m/s]. When the mission flew
    in another process (`alight hil --mission land` against `alight sim-autopilot`), `run` is the
    simulated autopilot's folder (ground truth, flight controller) and `mission_run` the
    onboard one (its `mission_status`, its clock `autopilot_clock_offset` s behind `run`'s)."""
    truth = run["ground_truth"]
    t = truth["time"].to_numpy()
    p_B, v_B = run.field("ground_truth", "p_WB").to_numpy(), run.field("ground_truth",
                                                                        "v_WB").to_numpy()
    p_T, v_T = run.field("ground_truth", "p_WT").to_numpy(), run.field("ground_truth",
                                                                        "v_WT").to_numpy()
    q_B, q_T = run.field("ground_truth", "q_WB").to_numpy(), run.field("ground_truth",
                                                                        "q_WT").to_numpy()
    rest = p_B[0, 2]  # on its legs on the ground at the start (ground at z = 0)
    status = (mission_run or run)["mission_status"]
    detections = status["first_detection"].dropna()
    first_detection = float(detections.iloc[0]) if len(detections) else np.nan
    if mission_run is not None:
        first_detection += mission_run.metadata["autopilot_clock_offset"]
    rel = p_B - p_T
    rel_T = np.einsum("nji,nj->ni", np.array([rotation_matrix(q) for q in q_T]), rel)
    over_platform = np.all(np.abs(rel_T[:, :2]) <= PLATFORM_HALF_SIZE, axis=1)
    takeoff = _first(p_B[:, 2] > rest + AIRBORNE)
    nan = float("nan")
    speed = lambda end: float(np.mean(np.linalg.norm(v_T[_speed_window(t, first_detection, end)],
                                                     axis=1)))

    def failed(reason: str, end: int, touchdown: int | None = None) -> LandingScore:
        e_xy = float(np.linalg.norm(rel[touchdown, :2])) if touchdown is not None else nan
        vz = float(-(v_B[touchdown, 2] - v_T[touchdown, 2])) if touchdown is not None else nan
        return LandingScore(False, reason, speed(end), e_xy,
                            t[end] - first_detection if touchdown is not None else nan,
                            float(t[end]), vz)

    if takeoff is None:
        return failed("never took off", len(t) - 1)
    after = np.arange(len(t)) > takeoff
    near_platform = np.all(np.abs(rel_T[:, :2]) <= PLATFORM_HALF_SIZE + FOOT_REACH, axis=1)
    on_platform = after & near_platform & (rel[:, 2] <= rest + CONTACT_TOLERANCE)
    on_ground = after & (p_B[:, 2] <= rest + CONTACT_TOLERANCE)
    touchdown = _first(on_platform | on_ground)
    if touchdown is None:
        reason = "no detection" if np.isnan(first_detection) else "no touchdown in time"
        return failed(reason, len(t) - 1)
    if not on_platform[touchdown]:
        return failed("touched the ground", touchdown, touchdown)
    vertical = float(-(v_B[touchdown, 2] - v_T[touchdown, 2]))
    horizontal = float(np.linalg.norm(v_B[touchdown, :2] - v_T[touchdown, :2]))
    if vertical > vertical_limit or horizontal > horizontal_limit:
        return failed(f"impact too hard ({vertical:.1f} m/s down, {horizontal:.1f} m/s across)",
                      touchdown, touchdown)
    end = len(t) - 1
    tilt = tilt_deg(q_B[end])[0] - tilt_deg(q_T[end])[0]
    relative_speed = np.linalg.norm(v_B[end] - v_T[end])
    armed = run["fc_status"]["armed"].to_numpy()[-1] > 0.5
    checks = [(not over_platform[end], "slid off the platform"),
              (rel[end, 2] > rest + 0.1, "not resting on the platform"),
              (np.any(on_ground[touchdown:]), "touched the ground"),
              (abs(tilt) > 20.0, "tipped over"),
              (relative_speed > 0.3, "not at rest on the platform"),
              (armed, "still armed")]
    for bad, reason in checks:
        if bad:
            return failed(reason, touchdown, touchdown)
    return LandingScore(True, "landed", speed(touchdown), float(np.linalg.norm(rel[touchdown, :2])),
                        float(t[touchdown] - first_detection), float(t[touchdown]), vertical)


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
