"""Summaries of a flight's run folder: the hover demo's (`alight hover`) and the managed stack's
(`alight fly`)."""
import dataclasses as dc
from pathlib import Path

import numpy as np

from alight.diagrams.analysis.landing import REST_SPEED, REST_WINDOW, contact_began, first_index
from alight.diagrams.running.run_log import RunLog
from alight.systems.boundary import ActiveMode
from alight.systems.control.scripted_pilot import PilotProfile
from alight.systems.managers.control_manager import ManagerMode
from alight.systems.rotations import tilt_deg


@dc.dataclass
class HoverSummary:
    run_dir: Path
    max_altitude: float        # m above the resting height
    hover_altitude_std: float  # m, during the hover segment
    max_tilt: float            # deg
    touchdown_speed: float     # m/s, vertical, at the first ground contact after the flight
    disarmed_at_end: bool

    def lines(self) -> list[str]:
        return [f"max altitude      {self.max_altitude:6.2f} m",
                f"hover altitude sd {self.hover_altitude_std:6.3f} m",
                f"max tilt          {self.max_tilt:6.2f} deg",
                f"touchdown speed   {self.touchdown_speed:6.2f} m/s",
                f"disarmed at end   {self.disarmed_at_end}",
                f"run folder        {self.run_dir}"]


def summarize_hover(run: RunLog, profile: PilotProfile) -> HoverSummary:
    truth = run["ground_truth"]
    z = truth["p_WB_2"].to_numpy()
    z0 = z[0]
    t = truth["time"].to_numpy()
    # The hover segment is the longest segment with zero vertical acceleration while armed.
    starts = np.cumsum([0.0] + [s.duration for s in profile.segments])
    hover = max(range(len(profile.segments)), key=lambda i: profile.segments[i].duration
                if profile.segments[i].arm and profile.segments[i].vertical_acceleration == 0.0
                and starts[i] < 15 else -1)
    in_hover = (t >= starts[hover] + 1.0) & (t <= starts[hover + 1])
    q = run.field("ground_truth", "q_WB").to_numpy()
    tilt = tilt_deg(q)
    vz = truth["v_WB_2"].to_numpy()
    airborne = np.flatnonzero(z > z0 + 0.3)
    touchdown_speed = 0.0
    if len(airborne):
        after = np.flatnonzero((t > t[airborne[-1]]) & (z < z0 + 0.01))
        if len(after):
            touchdown_speed = float(abs(vz[max(after[0] - 1, 0)]))
    status = run["fc_status"]
    return HoverSummary(run.path, float(z.max() - z0),
                        float(np.std(z[in_hover])) if in_hover.any() else float("nan"),
                        float(tilt.max()), touchdown_speed, bool(status["armed"].iloc[-1] < 0.5))


def managed_flight_failures(run: RunLog) -> list[str]:
    """Why an `alight fly` run failed, none when it flew: a routine refused or timed out; the
    control manager's emergency landing or failsafe, or the flight controller's failsafe descent;
    not landed, judged by contact (the ground truth's, sampled every 4 ms): after the take-off
    nothing but the legs touched anything, no leg carried more than the airframe's
    `max_leg_force`, and over the last `REST_WINDOW` the vehicle rests on its legs on the ground,
    at rest; still armed at the end."""
    failures = [f"{r['routine']} " + (f"refused ({r['refusal']})" if r["refusal"] else
                                      "timed out") for r in run.metadata["routines"]
                if r["refusal"] or not r["done"]]
    modes = set(run["manager_status"]["mode"].astype(int))
    failures += [f"control manager {ManagerMode(mode).name.lower()}" for mode in
                 (ManagerMode.ELAND, ManagerMode.FAILSAFE) if mode in modes]
    if ActiveMode.FAILSAFE_DESCENT in set(run["fc_status"]["mode"].astype(int)):
        failures.append("flight controller failsafe descent")
    truth = run["ground_truth"]
    t = truth["time"].to_numpy()
    ground = contact_began(truth["legs_ground_time"].to_numpy())
    flying = first_index(~ground)  # the legs left the ground at the take-off
    if flying is None:
        return failures + ["never took off"]
    if np.any(contact_began(truth["other_contact_time"].to_numpy())[flying:]):
        failures.append("touched with the airframe")
    limit = run.metadata["vehicle_config"]["airframe"]["max_leg_force"]
    peak = float(truth["peak_leg_force"].iloc[-1])
    if peak > limit:
        failures.append(f"touchdown too hard for the legs ({peak:.0f} N on a leg, limit "
                        f"{limit:.0f} N)")
    settled = t >= t[-1] - REST_WINDOW
    speed = np.linalg.norm(run.field("ground_truth", "v_WB").to_numpy(), axis=1)
    if not (np.all(truth["legs_ground_force"].to_numpy()[settled] > 0.0)
            and np.all(speed[settled] <= REST_SPEED)):
        failures.append("not landed (not at rest on its legs on the ground)")
    if run["fc_status"]["armed"].iloc[-1] > 0.5:
        failures.append("still armed")
    return failures


def summarize_managed_flight(run: RunLog) -> list[str]:
    """Printed after `alight fly`: each routine's outcome, landed (judged by contact) and
    disarmed, closest approach to the plan's points, speed, tilt, the controllers' and trackers'
    tick times, and the outcome (`managed_flight_failures`)."""
    p = run.field("ground_truth", "p_WB").to_numpy()
    plan = run.metadata["plan"]
    points = np.asarray(plan["waypoints"] if plan["waypoints"] is not None
                        else plan["samples"], float)[:, :3]
    if plan["waypoints"] is None:
        points = points[[0, -1]]
    closest = [float(np.min(np.linalg.norm(p - w, axis=1))) for w in points]
    tilt = tilt_deg(run.field("ground_truth", "q_WB").to_numpy())
    lines = [f"{r['routine']:12s}  " + (f"refused ({r['refusal']})" if r["refusal"] else
                                        "done" if r["done"] else
                                        "timed out") + f" after {r['duration']:.1f} s"
             for r in run.metadata["routines"]]
    failures = managed_flight_failures(run)
    landed = not any(f.startswith(("not landed", "still armed", "never took off"))
                     for f in failures)
    lines += [f"landed and disarmed   {landed} after {run['ground_truth']['time'].iloc[-1]:.1f} s",
              "closest approach      " + ", ".join(f"{d:.2f} m" for d in closest),
              f"max speed / tilt      "
              f"{np.linalg.norm(run.field('ground_truth', 'v_WB'), axis=1).max():.2f} m/s / "
              f"{tilt.max():.1f} deg"]
    busy = run["timing"].groupby(["component", "part"])["seconds"].agg(["mean", "max"]) * 1e3
    for (component, part), ms in busy.iterrows():
        lines.append(f"{component + ' ' + part:34s} mean {ms['mean']:.2f} ms, "
                     f"max {ms['max']:.2f} ms")
    return lines + [f"run folder            {run.path}",
                    "outcome               " + ("flew and landed" if not failures else
                                                "FAILED: " + "; ".join(failures))]
