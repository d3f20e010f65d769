"""Trajectory generation through waypoints, M Sec. 6: polynomial segments, time allocation,
constraint satisfaction and sub-sectioning, sampled into a `TrackerGoal` for the MPC tracker.

Waypoints [x, y, z, heading] in the estimator frame E are joined by polynomial segments, one per
pair, per axis (x, y, z and the heading unwrapped the short way round). With segment times T_i and
normalized time tau = t / T_i in [0, 1], segment i of one axis is p_i(tau) = w_i + sum_j c_ij
tau^j (degree 2r - 1) and the coefficients solve the QP of [37]

    min  sum_i int_0^T_i |d^r p_i / dt^r|^2 + w_v |d p_i / dt|^2 dt     (r = 4: snap, r = 3: jerk)
       = sum_i T_i^(1 - 2r) c_i^T H_r c_i + w_v T_i^-1 c_i^T H_1 c_i
    s.t. p_i(0) = w_i, p_i(1) = w_{i+1},  derivatives 1..r-1 zero at both ends (rest),
         d^k p_i(1) / T_i^k = d^k p_{i+1}(0) / T_{i+1}^k,  k = 1..continuity,

a Drake MathematicalProgram built once per waypoint count and solved by Clarabel (the cost and the
constraint coefficients are updated when the times change). The velocity term (w_v > 0) is ours:
with the pure minimum-snap cost (w_v = 0) a stretched segment becomes cheap (T^(1-2r)) and takes
on wild motion from its neighbours, so stretching a violating segment can make it violate more;
the velocity term keeps long segments near their straight line. M Sec. 6's extensions of [55]:

- initial segment times are lower bounds: per axis group (horizontal distance, climb or descent,
  heading change) the time at the group's speed with an acceleration ramp from or to rest on the
  first and last segment (trapezoidal profile), the largest of the groups;
- constraint satisfaction stretches only the segments whose sampled derivatives exceed the
  constraint group (horizontal norm, ascent, descent, heading; 1st..`max_derivative`-th), by their
  violation ratio (peak / limit)^(1/k), and re-solves until none does; the baseline of [55]
  (`rescaling: uniform`) scales every segment time by the worst ratio instead (exact: a uniform
  time scale s scales the k-th derivative by s^-k);
- iterative sub-sectioning: a segment whose samples lie farther than `max_deviation` from the
  straight line between its waypoints gets its midpoint as a new waypoint, and all is solved again.
"""
import dataclasses as dc
import math

import numpy as np
import scipy.sparse as sp
from pydrake.polynomial import Polynomial
from pydrake.solvers import ClarabelSolver, MathematicalProgram
from pydrake.trajectories import PiecewisePolynomial

from alight.models import model_path
from alight.systems.params import ConfigError, bounded, choice, load_params, param_file
from alight.systems.timing import ComputeTimer
from alight.systems.tracking.constraints import (ConstraintGroup, ConstraintGroups,
                                                 check_constraint_groups, derivative_peaks,
                                                 limits_table)
from alight.systems.tracking.goal import TrackerGoal

AXES = 4          # x, y, z, heading
ORDERS = {"snap": 4, "jerk": 3}


@dc.dataclass
class TrajectoryGenerationParams:
    """models/trajectory_generation.yaml."""
    minimize: str = choice("snap", "jerk")                  # r = 4 (degree 7) or 3 (degree 5)
    continuity: int = bounded(4, 2, 6)                      # derivatives continuous at waypoints
    velocity_weight: float = bounded(1.0, 0.0, 1e3, "s^(2-2r)")  # w_v (0: pure minimum snap)
    constraints: str = "medium"                             # default group (M Sec. 7.5)
    constraint_groups: ConstraintGroups = param_file(ConstraintGroups, "constraints.yaml")
    max_derivative: int = bounded(3, 1, 4)                  # checked: speed .. jerk (4: snap)
    samples_per_segment: int = bounded(100, 10, 10000)      # constraint and deviation checks
    rescaling: str = choice("per_segment", "uniform")       # M Sec. 6, or the baseline of [55]
    min_stretch: float = bounded(1.02, 1.001, 2.0)          # least stretch of a violating segment
    max_stretch: float = bounded(2.0, 1.01, 10.0)           # most stretch per iteration
    max_iterations: int = bounded(200, 2, 10000)            # QP solves, then uniform rescaling
    max_deviation: float = bounded(1.0, 0.01, 100.0, "m")   # from the straight waypoint path
    subsection: bool = True
    max_subsection_rounds: int = bounded(8, 0, 50)
    min_segment_time: float = bounded(0.2, 0.01, 10.0, "s")
    duplicate_distance: float = bounded(0.01, 0.0, 1.0, "m")  # closer waypoints are merged
    sample_period: float = bounded(0.01, 0.001, 1.0, "s")   # TrackerGoal period


@dc.dataclass
class WaypointTrajectory:
    """The result: waypoints actually joined (sub-sections inserted, heading unwrapped), segment
    times, normalized coefficients (segments, 2r, 4 axes) of p_i(tau) - w_i, and how it got
    there (iterations, sub-sectioning rounds, deviation, peaks over the group's limits)."""
    waypoints: np.ndarray
    segment_times: np.ndarray
    coefficients: np.ndarray
    iterations: int               # QP solves (of the last sub-sectioning round)
    subsection_rounds: int
    max_deviation: float          # largest sampled distance from the straight waypoint path [m]
    peak_ratios: np.ndarray       # (4 quantities, max_derivative) sampled peak / limit
    uniform_fallback: bool        # per-segment stretching gave up: uniform rescaling used
    sample_period: float = 0.01

    @property
    def breaks(self) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(self.segment_times)])

    @property
    def total_time(self) -> float:
        return float(np.sum(self.segment_times))

    def derivative(self, times, order: int = 0) -> np.ndarray:
        """(len(times), 4) d^order/dt^order of [x, y, z, heading] at `times` (clamped to the
        trajectory: at rest before and after)."""
        times = np.atleast_1d(np.asarray(times, float))
        t = np.clip(times, 0.0, self.total_time)
        i = np.clip(np.searchsorted(self.breaks, t, side="right") - 1, 0,
                    len(self.segment_times) - 1)
        T = self.segment_times[i]
        rows = basis_rows(order, (t - self.breaks[i]) / T, self.coefficients.shape[1])
        values = np.einsum("sn,sna->sa", rows, self.coefficients[i]) / T[:, None] ** order
        if order == 0:
            return values + self.waypoints[i]
        values[(times < 0.0) | (times > self.total_time)] = 0.0
        return values

    def value(self, times) -> np.ndarray:
        return self.derivative(times, 0)

    def goal(self, period: float | None = None, t_start: float = 0.0) -> TrackerGoal:
        """The trajectory sampled every `period` (default the YAML's), from its start at `t_start`
        (tracker time) to its end, the last sample the last waypoint."""
        period = self.sample_period if period is None else period
        if not (np.isfinite(period) and period > 0.0):
            raise ValueError(f"goal period must be > 0, got {period}")
        count = int(math.ceil(self.total_time / period - 1e-9)) + 1
        return TrackerGoal(self.value(period * np.arange(count)), t_start, period)

    def piecewise_polynomial(self) -> PiecewisePolynomial:
        """The same trajectory as a Drake PiecewisePolynomial (4 x 1: x, y, z, heading)."""
        polynomials = []
        for w, c, T in zip(self.waypoints, self.coefficients, self.segment_times):
            scaled = c / T ** np.arange(len(c))[:, None]          # in t - t_i instead of tau
            scaled[0] += w
            polynomials.append(np.array([[Polynomial(scaled[:, a])] for a in range(AXES)]))
        return PiecewisePolynomial(polynomials, list(self.breaks))


def basis_rows(order: int, tau: np.ndarray, count: int) -> np.ndarray:
    """(len(tau), count): d^order/dtau^order of tau^j, j = 0..count-1."""
    tau = np.atleast_1d(np.asarray(tau, float))
    rows = np.zeros((len(tau), count))
    for j in range(order, count):
        rows[:, j] = math.perm(j, order) * tau ** (j - order)
    return rows


def cost_hessian(r: int, count: int) -> np.ndarray:
    """H with c^T H c = int_0^1 (d^r p / dtau^r)^2 dtau for p = sum_j c_j tau^j."""
    H = np.zeros((count, count))
    for j in range(r, count):
        for k in range(r, count):
            H[j, k] = math.perm(j, r) * math.perm(k, r) / (j + k - 2 * r + 1)
    return H


def ramp_time(distance, speed: float, acceleration: float, ramps) -> np.ndarray:
    """Least time to cover `distance` within `speed` and `acceleration` with `ramps` (0, 1, 2)
    accelerations from or to rest: a trapezoidal (or triangular) speed profile."""
    distance, ramps = np.asarray(distance, float), np.asarray(ramps, float)
    cruise = distance / speed + ramps * speed / (2.0 * acceleration)
    short = np.sqrt(2.0 * ramps * distance / acceleration)
    return np.where(distance >= ramps * speed ** 2 / (2.0 * acceleration), cruise, short)


def initial_segment_times(waypoints: np.ndarray, group: ConstraintGroup,
                          least: float) -> np.ndarray:
    """M Sec. 6 lower bounds: the slowest of the horizontal, vertical and heading groups."""
    step = np.diff(waypoints, axis=0)
    m = len(step)
    ramps = np.zeros(m)
    ramps[0] += 1.0
    ramps[-1] += 1.0
    horizontal = ramp_time(np.linalg.norm(step[:, :2], axis=1), group.horizontal.speed,
                           group.horizontal.acceleration, ramps)
    up = ramp_time(np.maximum(step[:, 2], 0.0), group.ascending.speed,
                   group.ascending.acceleration, ramps)
    down = ramp_time(np.maximum(-step[:, 2], 0.0), group.descending.speed,
                     group.descending.acceleration, ramps)
    turn = ramp_time(np.abs(step[:, 3]), group.heading.speed, group.heading.acceleration, ramps)
    return np.maximum.reduce([horizontal, up, down, turn, np.full(m, least)])


class SegmentQp:
    """The QP of the module docstring for `segments` segments and all four axes, built once:
    `solve(waypoints, times)` -> coefficients (segments, 2r, 4)."""

    def __init__(self, segments: int, r: int, continuity: int, velocity_weight: float = 0.0):
        self.m, self.r, self.n = segments, r, 2 * r
        self._H1 = np.kron(np.eye(AXES), cost_hessian(1, self.n)) * velocity_weight
        self.continuity = continuity
        self.prog = prog = MathematicalProgram()
        self.c = prog.NewContinuousVariables(AXES * segments * self.n, "c")   # [axis][seg][j]
        index = np.arange(AXES * segments * self.n).reshape(AXES, segments, self.n)
        self._H = np.kron(np.eye(AXES), cost_hessian(r, self.n))
        self._costs = [prog.AddQuadraticCost(self._H, np.zeros(AXES * self.n),
                                             self.c[index[:, i].ravel()], is_convex=True)
                       for i in range(segments)]
        A = self._constraint(np.ones(segments))
        self._equality = prog.AddLinearEqualityConstraint(A, np.zeros(A.shape[0]), self.c)
        self._index = index
        self.solver = ClarabelSolver()

    def _axis_rows(self, times: np.ndarray) -> sp.csr_matrix:
        """One axis' equality rows: positions (2 per segment), rest, continuity (row-scaled)."""
        m, n, r = self.m, self.n, self.r
        at0 = [basis_rows(k, 0.0, n)[0] for k in range(n)]
        at1 = [basis_rows(k, 1.0, n)[0] for k in range(n)]
        rows, cols, vals = [], [], []
        count = 0

        def add(entries):
            nonlocal count
            for segment, row in entries:
                nz = np.flatnonzero(row)
                rows.extend([count] * len(nz))
                cols.extend(segment * n + nz)
                vals.extend(row[nz])
            count += 1

        for i in range(m):
            add([(i, at0[0])])
            add([(i, at1[0])])
        for k in range(1, r):
            add([(0, at0[k])])
            add([(m - 1, at1[k])])
        for i in range(m - 1):
            for k in range(1, self.continuity + 1):
                scale = min(times[i], times[i + 1]) ** k
                add([(i, at1[k] * scale / times[i] ** k),
                     (i + 1, -at0[k] * scale / times[i + 1] ** k)])
        return sp.csr_matrix((vals, (rows, cols)), shape=(count, m * n))

    def _constraint(self, times: np.ndarray) -> sp.csc_matrix:
        return sp.block_diag([self._axis_rows(times)] * AXES, format="csc")

    def solve(self, waypoints: np.ndarray, times: np.ndarray) -> np.ndarray:
        reference = np.mean(times)
        for cost, T in zip(self._costs, times):
            cost.evaluator().UpdateCoefficients(
                2.0 * (self._H * (reference / T) ** (2 * self.r - 1)
                       + self._H1 * reference ** (2 * self.r - 1) / T), np.zeros(AXES * self.n),
                0.0, True)
        A = self._constraint(times)
        rows = A.shape[0] // AXES
        b = np.zeros((AXES, rows))
        b[:, 1:2 * self.m:2] = np.diff(waypoints, axis=0).T        # p_i(1) - w_i
        self._equality.evaluator().UpdateCoefficients(A, b.ravel())
        result = self.solver.Solve(self.prog)
        if not result.is_success() or not np.all(np.isfinite(result.GetSolution(self.c))):
            raise RuntimeError(f"trajectory generation: the segment QP failed "
                               f"({result.get_solution_result()}) for times {times}")
        x = result.GetSolution(self.c)[self._index]                # (AXES, m, n)
        return np.transpose(x, (1, 2, 0))


class TrajectoryGenerator:
    """Waypoints -> `WaypointTrajectory` under one constraint group (module docstring).
    `compute_timer` records the wall-clock time of every `generate` (alight.systems.timing)."""

    def __init__(self, params: TrajectoryGenerationParams, groups: ConstraintGroups):
        self.compute_timer = ComputeTimer()
        self.r = ORDERS[params.minimize]
        if params.continuity > 2 * self.r - 2:
            raise ConfigError(f"trajectory generation: key 'continuity' = {params.continuity} "
                              f"must be <= {2 * self.r - 2} for minimize: {params.minimize}")
        groups.group(params.constraints)          # refuses an unknown default group
        self.params, self.groups = params, groups
        self._qps: dict[int, SegmentQp] = {}
        tau = np.linspace(0.0, 1.0, params.samples_per_segment)
        self._rows = [basis_rows(k, tau, 2 * self.r) for k in range(params.max_derivative + 1)]

    def generate(self, waypoints, group: str | None = None, rescaling: str | None = None,
                 max_deviation: float | None = None, stamp: float = math.nan
                 ) -> WaypointTrajectory:
        """waypoints (n >= 2, 4) [x, y, z, heading] in E; group: a constraint group name (default
        the YAML's); rescaling: "per_segment" or "uniform"; max_deviation [m] (default the YAML's;
        sub-sectioning off when the YAML says so); stamp: the simulation time of the call [s]
        for `compute_timer` (nan: outside a simulation)."""
        with self.compute_timer.measure(stamp, "generate"):
            return self._generate(waypoints, group, rescaling, max_deviation)

    def _generate(self, waypoints, group, rescaling, max_deviation) -> WaypointTrajectory:
        p = self.params
        limits = self.groups.group(p.constraints if group is None else group)
        rescaling = p.rescaling if rescaling is None else rescaling
        if rescaling not in ("per_segment", "uniform"):
            raise ValueError(f"rescaling must be 'per_segment' or 'uniform', got {rescaling!r}")
        max_deviation = p.max_deviation if max_deviation is None else float(max_deviation)
        if not (np.isfinite(max_deviation) and max_deviation > 0.0):
            raise ValueError(f"max_deviation must be > 0 m, got {max_deviation}")
        points = clean_waypoints(waypoints, p.duplicate_distance)
        rounds = 0
        while True:
            times = initial_segment_times(points, limits, p.min_segment_time)
            coefficients, times, iterations, ratios, fallback = self._satisfy(
                points, times, limits, rescaling)
            deviation = self._deviations(points, coefficients)
            far = deviation > max_deviation
            if not p.subsection or not far.any() or rounds >= p.max_subsection_rounds:
                break
            points = insert_midpoints(points, far)
            rounds += 1
        return WaypointTrajectory(points, times, coefficients, iterations, rounds,
                                  float(deviation.max()), ratios, fallback, p.sample_period)

    def _qp(self, segments: int) -> SegmentQp:
        if segments not in self._qps:
            if len(self._qps) >= 16:              # keep the programs of recent waypoint counts
                self._qps.pop(next(iter(self._qps)))
            self._qps[segments] = SegmentQp(segments, self.r, self.params.continuity,
                                             self.params.velocity_weight)
        return self._qps[segments]

    def _satisfy(self, points, times, limits, rescaling):
        """Stretch the violating segments (or all, uniformly) until every sampled derivative is
        within the group. The uniform rescaling of the initial times is the ceiling: should the
        per-segment stretching get slower than it (or its QP fail, or max_iterations run out),
        that result is returned with `fallback` set. Returns coefficients, times, QP solves,
        overall peak ratios (4, max_derivative), fallback."""
        qp, p = self._qp(len(points) - 1), self.params
        coefficients = qp.solve(points, times)
        stretch, ratios = self._stretch(coefficients, times, limits)
        if not np.any(stretch > 1.0):
            return coefficients, times, 1, ratios.max(axis=0), False
        uniform = times * stretch.max()       # exact: the same shape, k-th derivative / s^k
        solves = 1
        if rescaling == "per_segment":
            while solves < p.max_iterations:
                violating = stretch > 1.0
                times = times.copy()
                times[violating] *= np.clip(stretch[violating], p.min_stretch, p.max_stretch)
                if times.sum() >= uniform.sum():
                    break
                try:
                    coefficients = qp.solve(points, times)
                except RuntimeError:
                    break
                solves += 1
                stretch, ratios = self._stretch(coefficients, times, limits)
                if not np.any(stretch > 1.0):
                    return coefficients, times, solves, ratios.max(axis=0), False
        coefficients = qp.solve(points, uniform)
        _, ratios = self._stretch(coefficients, uniform, limits)
        return coefficients, uniform, solves + 1, ratios.max(axis=0), rescaling == "per_segment"

    def _stretch(self, coefficients, times, limits):
        """Per segment the time stretch that would bring it within the group, max over
        quantities and derivatives k of (peak / limit)^(1/k); and the ratios themselves."""
        ratios = self._segment_ratios(coefficients, times, limits)
        exponents = 1.0 / np.arange(1, self.params.max_derivative + 1)
        return np.max(ratios ** exponents, axis=(1, 2)), ratios

    def _segment_ratios(self, coefficients, times, limits) -> np.ndarray:
        """(segments, 4 quantities, max_derivative): sampled peak / the group's limit."""
        K = self.params.max_derivative
        table = limits_table(limits)[:, :K]
        ratios = np.empty((len(times), 4, K))
        for i, (c, T) in enumerate(zip(coefficients, times)):
            derivatives = [self._rows[k] @ c / T ** k for k in range(1, K + 1)]
            ratios[i] = derivative_peaks(derivatives)[:, :K] / table
        return ratios

    def _deviations(self, points, coefficients) -> np.ndarray:
        """Per segment: the largest sampled distance from the segment between its waypoints."""
        a, b = points[:-1, :3], points[1:, :3]
        p = np.einsum("sn,mna->msa", self._rows[0], coefficients[:, :, :3]) + a[:, None]
        d = b - a
        length2 = np.maximum(np.sum(d ** 2, axis=1), 1e-12)[:, None]
        s = np.clip(np.einsum("msa,ma->ms", p - a[:, None], d) / length2, 0.0, 1.0)
        closest = a[:, None] + s[..., None] * d[:, None]
        return np.linalg.norm(p - closest, axis=2).max(axis=1)


def clean_waypoints(waypoints, duplicate_distance: float) -> np.ndarray:
    """(n, 4) checked, headings unwrapped the short way round, consecutive waypoints closer than
    `duplicate_distance` merged (the later heading kept)."""
    points = np.asarray(waypoints, dtype=float)
    if points.ndim != 2 or points.shape[1] != 4:
        raise ValueError(f"waypoints must be rows of [x, y, z, heading], got shape "
                         f"{np.shape(waypoints)}")
    if len(points) < 2:
        raise ValueError(f"trajectory generation needs at least 2 waypoints, got {len(points)}")
    bad = np.flatnonzero(~np.all(np.isfinite(points), axis=1))
    if len(bad):
        raise ValueError(f"waypoint {bad[0]} is not finite: {points[bad[0]]}")
    kept = [points[0]]
    for point in points[1:]:
        if np.linalg.norm(point[:3] - kept[-1][:3]) <= duplicate_distance:
            kept[-1] = np.append(kept[-1][:3], point[3])
        else:
            kept.append(point)
    if len(kept) < 2:
        raise ValueError(f"all {len(points)} waypoints lie within {duplicate_distance} m of each "
                         f"other: nothing to fly")
    points = np.array(kept)
    points[:, 3] = np.unwrap(points[:, 3])
    return points


def insert_midpoints(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """`points` with the midpoint (position and unwrapped heading) of each flagged segment."""
    rows = [points[0]]
    for i, split in enumerate(segments):
        if split:
            rows.append(0.5 * (points[i] + points[i + 1]))
        rows.append(points[i + 1])
    return np.array(rows)


def load_trajectory_generation_params(
        filename: str = "trajectory_generation.yaml") -> TrajectoryGenerationParams:
    """A path, or a file name in models/; raises ConfigError naming the file and the key."""
    path = model_path(filename)
    params = load_params(TrajectoryGenerationParams, path)
    check_constraint_groups(params.constraint_groups, str(path), "constraint_groups.")
    return params


def make_trajectory_generator(params: TrajectoryGenerationParams) -> TrajectoryGenerator:
    """The generator of `params`, on their constraint groups."""
    return TrajectoryGenerator(params, params.constraint_groups)
