"""The MPC tracker, M Sec. 4.1: a linear MPC drives a virtual vehicle, whose state is the
full-state reference chi of M(16), at 100 Hz, from a point or a sampled trajectory goal.

The axes x, y, z and the heading are four independent QPs (`AxisMpc`, a snap-driven chain of
integrators under one constraint group of M Sec. 7.5). Each axis re-plans every grid step h
(10 ticks at the defaults), the axes staggered by one tick so that a tick solves at most one QP;
between its solves an axis plays its plan exactly, so a goal change is taken up within h. A new
constraint group is taken up at once: every axis re-plans on the tick it arrives (waiting for an
axis' turn, up to h, keeps the old group's jerk rising, which a slower group's snap then takes
long to turn: 2.9 s instead of 2.4 s to get from 2.85 m/s under 1.05 m/s on medium -> slow).
The horizontal limits bound the norm of the x-y derivatives: each of x and y gets the limit
times its share of a direction per derivative (`horizontal_factors`), exact on straight lines.
Far goals are pulled to `lookahead` x speed x horizon of the vehicle per axis, speed the group's or
the axis' own when faster (the plan cannot get further within the horizon anyway; it keeps the
QP's errors, and OSQP's iterations, small; a pull-in shorter than an over-fast vehicle's way
hides the goal: 0.08 m past it instead of 0.001 m after medium -> slow).
"""
import dataclasses as dc
import enum

import numpy as np

from alight.models import model_path
from alight.systems.boundary import REFERENCE, STATE_ESTIMATE
from alight.systems.params import ConfigError, bounded, load_params, param_file
from alight.systems.rotations import heading
from alight.systems.tracking.axis_mpc import (ORDER, AxisLimits, AxisMpc, AxisMpcParams, chain,
                                              horizontal_factors)
from alight.systems.tracking.constraints import ConstraintGroups, check_constraint_groups
from alight.systems.tracking.goal import TrackerGoal
from alight.systems.tracking.tracker import Tracker, TrackerMemory, tracker_status

AXES = 4          # x, y, z, heading


@dc.dataclass
class MpcTrackerParams:
    period: float = bounded(0.01, 0.001, 0.1, "s")          # 100 Hz, M Sec. 4.1
    axis: AxisMpcParams = dc.field(default_factory=AxisMpcParams)
    direction_time: float = bounded(1.0, 0.01, 100.0, "s")  # position error -> velocity asked
    plan_time: float = bounded(0.5, 0.01, 100.0, "s")       # last plan's weight exp(-t / this)
    share_floor: float = bounded(0.1, 0.0, 0.3)             # least share of a horizontal limit
    lookahead: float = bounded(0.5, 0.1, 10.0)              # far goals pulled in (x V N h)
    constraints: str = "medium"                             # default group (M Sec. 7.5)
    constraint_groups: ConstraintGroups = param_file(ConstraintGroups, "constraints.yaml")


class TrackerReason(enum.IntEnum):
    """`tracker_status.reason` (INACTIVE and BAD_START: tracker.py's)."""
    OK = 0
    INACTIVE = 1
    NO_GOAL = 2          # active without a goal: holds the goal of the start (the start state)
    SOLVER_FAILED = 3    # a QP failed: the axis plays on its previous plan (still valid)
    BAD_START = 4        # cannot start: no finite last reference and no valid estimate


@dc.dataclass
class MpcTrackerMemory(TrackerMemory):
    """Abstract state: the virtual vehicle x (axes x derivatives p, v, a, j), each axis' plan
    (snaps, planned positions, ticks since its solve), the goal held without one, bookkeeping."""
    x: np.ndarray
    snaps: np.ndarray        # (AXES, N)
    planned: np.ndarray      # (AXES, N + 1) positions of the last plan
    age: np.ndarray          # (AXES,) ticks since each axis' last solve
    hold: np.ndarray         # (4,) the goal [x, y, z, heading] used when none is given
    direction: np.ndarray    # (2,) last horizontal direction
    group: str = ""          # the constraint group of the last plans
    ticks: int = 0

    @staticmethod
    def empty(N: int) -> "MpcTrackerMemory":
        return MpcTrackerMemory(np.zeros((AXES, ORDER)), np.zeros((AXES, N)),
                             np.zeros((AXES, N + 1)), np.zeros(AXES, int), np.zeros(4),
                             np.array([1.0, 1.0]) / np.sqrt(2))


class MpcTracker(Tracker):
    """Inputs  as `Tracker`, with `goal` a TrackerGoal (None: hold); `constraint_group` (1,
            optional: index into `group_names`; unconnected: the default group)
    Outputs `reference` REFERENCE (chi of M(16) in E, stamped one period ahead),
            `tracker_status` TRACKER_STATUS
    On activation the virtual vehicle starts from `last_reference` when it is finite (M Sec. 7.2),
    else at rest at the state estimate. `compute_timer` records each active tick's QP time
    (alight.systems.timing).
    """

    def __init__(self, params: MpcTrackerParams, groups: ConstraintGroups):
        super().__init__(params.period, MpcTrackerMemory.empty(params.axis.horizon),
                         TrackerGoal.point(np.zeros(3)))
        ratio = params.axis.step / params.period
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < AXES:
            raise ConfigError(f"mpc tracker: axis.step {params.axis.step} s must be a whole "
                              f"number (>= {AXES}) of periods {params.period} s")
        self.params, self.groups = params, groups
        self.group_names = sorted(groups.groups)
        groups.group(params.constraints)          # refuses an unknown default group
        self.every = int(round(ratio))
        self.N = params.axis.horizon
        self.times = params.axis.step * np.arange(1, self.N + 1)
        self.qps = [AxisMpc(params.axis) for _ in range(AXES)]
        A, B = chain(params.period)
        self._A, self._B = A, B[:, 0]
        self._group = self.DeclareVectorInputPort("constraint_group", 1)

    def _group_name(self, context) -> str:
        name = self.params.constraints
        if self._group.HasValue(context):
            index = self._group.Eval(context)[0]
            if np.isfinite(index) and 0 <= int(index) < len(self.group_names):
                name = self.group_names[int(index)]
        return name

    # --- the role's hooks (alight.systems.tracking.tracker) -----------------------------------

    def _activate(self, context, memory: MpcTrackerMemory, last_reference, estimate) -> None:
        """The virtual vehicle at `last_reference`, else at rest at the estimate."""
        x = np.zeros((AXES, ORDER))
        if last_reference is not None:
            x[:3] = np.column_stack([REFERENCE.get(last_reference, f)
                                     for f in ("p", "v", "a", "j")])
            x[3, :2] = (REFERENCE.get(last_reference, "heading"),
                        REFERENCE.get(last_reference, "heading_rate"))
        else:
            x[:3, 0] = STATE_ESTIMATE.get(estimate, "p_EB")
            x[3, 0] = STATE_ESTIMATE.get(estimate, "heading")
        memory.x, memory.hold = x, x[:, 0].copy()
        memory.snaps[:], memory.planned[:] = 0.0, x[:, :1]
        memory.age[:] = 0
        memory.ticks = 0

    def _switch_frame(self, memory: MpcTrackerMemory, R_OldNew, p_OldNew) -> None:
        """The virtual vehicle and its plans: positions p_new = R^T (p_old - p_OldNew),
        derivatives and snaps rotated, heading minus the yaw."""
        x = memory.x
        x[:3] = R_OldNew.T @ x[:3]
        x[:3, 0] -= R_OldNew.T @ p_OldNew
        memory.snaps[:3] = R_OldNew.T @ memory.snaps[:3]
        memory.planned[:3] = R_OldNew.T @ (memory.planned[:3] - p_OldNew[:, None])
        yaw = heading(R_OldNew)
        x[3, 0] -= yaw
        memory.planned[3] -= yaw
        memory.hold[:3] = R_OldNew.T @ (memory.hold[:3] - p_OldNew)
        memory.hold[3] -= yaw
        memory.direction = (R_OldNew.T @ np.append(memory.direction, 0.0))[:2]

    def _update_active(self, context, memory: MpcTrackerMemory, goal, estimate):
        reason = TrackerReason.OK if goal is not None else TrackerReason.NO_GOAL
        group = self._group_name(context)
        switched, memory.group = group != memory.group, group   # a new group: all re-plan now
        due = range(AXES) if not memory.active or switched else [
            a for a in range(AXES) if memory.ticks % self.every == a]
        now = context.get_time()
        solver_status = 0
        with self.compute_timer.measure(now):
            if due:
                ok, solver_status = self._replan(memory, list(due), goal, context)
                reason = reason if ok else TrackerReason.SOLVER_FAILED
        self._advance(memory)
        x = memory.x
        reference = REFERENCE.pack(
            stamp=now + self.params.period, p=x[:3, 0], v=x[:3, 1], a=x[:3, 2], j=x[:3, 3],
            heading=float(np.angle(np.exp(1j * x[3, 0]))), heading_rate=x[3, 1])
        return reference, tracker_status(1.0, reason, solver_status)

    def _goal_rows(self, memory: MpcTrackerMemory, goal, now: float) -> np.ndarray:
        """(4 axes, 2, N): goal positions and velocities at the horizon's times."""
        rows = goal.sample(now + self.times) if goal is not None \
            else np.tile(memory.hold, (self.N, 1))
        rows[:, 3] += 2 * np.pi * np.round((memory.x[3, 0] - rows[0, 3]) / (2 * np.pi))
        velocities = np.gradient(rows, self.params.axis.step, axis=0) if goal is not None \
            and len(goal.samples) > 1 else np.zeros_like(rows)
        return np.stack([rows.T, velocities.T], axis=1)

    def _replan(self, memory: MpcTrackerMemory, axes: list[int], goal, context):
        group = self.groups.group(memory.group)
        rows = self._goal_rows(memory, goal, context.get_time())
        limits = self._limits(memory, group, rows)
        speeds = [group.horizontal.speed] * 2 + [
            max(group.ascending.speed, group.descending.speed), group.heading.speed]
        ok, status = True, 0
        for a in axes:
            reach = self.params.lookahead * max(speeds[a], abs(memory.x[a, 1])) * self.times[-1]
            target = rows[a].copy()
            target[0] = memory.x[a, 0] + np.clip(target[0] - memory.x[a, 0], -reach, reach)
            qp = self.qps[a]
            qp.update(memory.x[a], target, limits[a])
            solved, snaps, states, status, _ = qp.solve()
            if solved and np.all(np.isfinite(snaps)):
                memory.snaps[a], memory.planned[a], memory.age[a] = snaps, states[:, 0], 0
            else:
                ok = False
        return ok, status

    def _limits(self, memory: MpcTrackerMemory, group, rows: np.ndarray) -> list[AxisLimits]:
        """Per-axis bounds (M Sec. 7.5): horizontal shares, ascent/descent, heading."""
        h = group.horizontal.as_array()
        planned = np.array([self._planned_positions(memory, a) for a in range(2)]).T
        w = self._asked_velocity(rows, planned)
        shares = horizontal_factors(w, self.params.axis.step, memory.direction,
                                    self.params.share_floor, 0.01 * h)
        if np.linalg.norm(w[0]) > 0.01 * h[0]:
            memory.direction = w[0] / np.linalg.norm(w[0])
        horizontal = [AxisLimits(h[:, None] * shares[:, :, a], h[:, None] * shares[:, :, a])
                      for a in range(2)]
        vertical = AxisLimits(group.ascending.as_array()[:, None],
                              group.descending.as_array()[:, None])
        eta = group.heading.as_array()[:, None]
        return horizontal + [vertical, AxisLimits(eta, eta)]

    def _asked_velocity(self, rows: np.ndarray, planned: np.ndarray) -> np.ndarray:
        """(N, 2): the horizontal velocity the vehicle is asked for along the horizon, whose
        direction apportions the norm limits between x and y (`horizontal_factors`). Far steps:
        the goal's velocity plus the position error over `direction_time`. Near steps: the last
        plan's own velocity, which the virtual vehicle is carrying out and cannot leave faster
        than its jerk and snap allow, blended into the goal's with weight exp(-t / plan_time).
        Without that blend a goal that turns (a circle's top) pinned the axis it turns into at
        the floor share while the vehicle still moved along it: the bound fought the motion, the
        plan swung its jerk, and the reference lagged the circle by 0.5-0.8 m for 5 s
        (docs/controllers.md, "The tracker's QP back end")."""
        p = self.params
        goal = rows[:2, 1].T + (rows[:2, 0].T - planned) / p.direction_time
        fade = np.exp(-self.times / p.plan_time)[:, None]
        return fade * np.gradient(planned, p.axis.step, axis=0) + (1.0 - fade) * goal

    def _planned_positions(self, memory: MpcTrackerMemory, a: int) -> np.ndarray:
        """Axis a's last plan at the horizon's times from now (held after its end)."""
        plan_times = self.params.axis.step * np.arange(self.N + 1)
        return np.interp(self.times + memory.age[a] * self.params.period, plan_times,
                         memory.planned[a])

    def _advance(self, memory: MpcTrackerMemory) -> None:
        """One period of every axis with its plan's current snap (0 after the plan's end)."""
        for a in range(AXES):
            k = memory.age[a] // self.every
            snap = memory.snaps[a, k] if k < self.N else 0.0
            memory.x[a] = self._A @ memory.x[a] + self._B * snap
        memory.age += 1
        memory.ticks += 1


def load_mpc_tracker_params(filename: str = "mpc_tracker.yaml") -> MpcTrackerParams:
    """A path, or a file name in models/; raises ConfigError naming the file and the key."""
    path = model_path(filename)
    params = load_params(MpcTrackerParams, path)
    check_constraint_groups(params.constraint_groups, str(path), "constraint_groups.")
    return params


def make_mpc_tracker(params: MpcTrackerParams) -> MpcTracker:
    """The tracker of `params`, on their constraint groups."""
    return MpcTracker(params, params.constraint_groups)
