"""The bank of filters with its arbiter, M Sec. 3.5 and 7.1: several linear Kalman filters
(M(7)-(11), `lkf.py`), each fusing its own subset of the sources and keeping its own frame, run
together at `period`; the arbiter (`arbiter.py`) picks the hypothesis that becomes the one
`state_estimate` every controller reads.

On a switch from filter Old to filter New the output changes `frame_id` to New's and increments
`frame_counter`, and carries X_OldNew (p_OldNew, q_OldNew), the pose of the new frame in the old
one computed from the two hypotheses at that instant (same body position and heading), so that
consumers re-express their states (p_New = R_OldNew^T (p_Old - p_OldNew)) and the vehicle does
not move. The orientation is M(12)-(14) (the flight controller's, turned to the filter's heading).

Ground contact (the input u of M(7), M Sec. 3.1.1): the unbiased desired acceleration says what
the thrust would do in the air. On the ground the ground carries what the thrust does not, so
while the `ground.source` rangefinder reads a height under `ground.height` (the vehicle rests on
its legs) the input's downward component is dropped: no filter integrates a descent the ground
prevents (during spool-up before a take-off, or while the landing controller still pushes down
before its mass estimate comes down, M Sec. 4.2).

Bad input never reaches a hypothesis: a message with a non-finite value, or with a stamp older
than the last one of its source (out of order), is rejected and counted in `bank_status`.
"""
import dataclasses as dc

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RotationMatrix
from pydrake.systems.framework import LeafSystem
from scipy.special import chdtri

from alight.systems.boundary import FC_ATTITUDE, STATE_ESTIMATE, VectorLayout
from alight.systems.estimation.arbiter import ArbiterParams, Health, choose
from alight.systems.estimation.heading import rotation_z, with_heading
from alight.systems.estimation.lkf import POSITION, VELOCITY, DecoupledKfBank, FilterModelParams
from alight.systems.estimation.measurements import (ADAPTERS, AXES, QUANTITIES, Measurement,
                                                    fc_measurements, stamp_and_valid)
from alight.systems.params import ConfigError, bounded, choice
from alight.systems.rotations import heading, rotation_matrix
from alight.systems.sensors.mocap import MocapParams
from alight.systems.sensors.optic_flow import OpticFlowParams
from alight.systems.sensors.position_fix import PositionFixParams
from alight.systems.sensors.rangefinder import RangefinderParams


# The sensor model's parameters of each source kind (simulation).
SENSOR_PARAMS = {"position_fix": PositionFixParams, "velocity_fix": OpticFlowParams,
                 "range": RangefinderParams, "odometry": MocapParams}


@dc.dataclass
class SourceParams:
    name: str = ""
    kind: str = choice("position_fix", "velocity_fix", "range", "odometry")
    timeout: float = bounded(0.5, 0.005, 600.0, "s")  # no new message this long: stopped
    # a measurement failing the innovation gate is rejected, or clipped onto the gate (lkf.py:
    # a precise source whose prediction may be the wrong one, e.g. the rangefinder)
    gate_action: str = choice("reject", "clip")
    # simulation: the source's sensor model (diagrams/onboard/estimation.py SENSOR_MODELS), given
    # as its YAML file or inline; None: the model's defaults
    sensor: PositionFixParams | OpticFlowParams | RangefinderParams | MocapParams | None = None


@dc.dataclass
class FilterParams:
    name: str = ""
    frame_id: int = bounded(0, 0, 1_000_000)
    fuse: list[str] = dc.field(default_factory=list)   # "source.quantity[.axes]"
    gate: bool = True                                  # innovation gating (chi-square)
    model: FilterModelParams = dc.field(default_factory=FilterModelParams)


@dc.dataclass
class FcSourceParams:
    """The flight controller's attitude as the built-in source `fc`."""
    heading_std: float = bounded(3.0, 0.01, 180.0, "deg")        # magnetometer-aided heading
    heading_rate_std: float = bounded(0.02, 1e-4, 10.0, "rad/s")  # gyro through M(15)


@dc.dataclass
class GroundParams:
    """Ground contact from a `range` source (module docstring); `source` empty: none."""
    source: str = ""
    height: float = bounded(0.3, 0.0, 100.0, "m")  # the reading at rest (0.22 m) + 4 sigma


@dc.dataclass
class BankParams:
    period: float = bounded(0.01, 0.001, 1.0, "s")  # 100 Hz (DESIGN.md rates)
    fc: FcSourceParams = dc.field(default_factory=FcSourceParams)
    sources: list[SourceParams] = dc.field(default_factory=list)
    filters: list[FilterParams] = dc.field(default_factory=list)
    arbiter: ArbiterParams = dc.field(default_factory=ArbiterParams)
    ground: GroundParams = dc.field(default_factory=GroundParams)


@dc.dataclass(frozen=True)
class Fusion:
    """One parsed `fuse` entry."""
    source: str
    quantity: str
    axes: tuple[int, ...]


def parse_fusion(text: str, kinds: dict[str, str], where: str) -> Fusion:
    """'gnss.position.xy' -> Fusion; a ConfigError naming the key for anything unknown."""
    parts = text.split(".")
    if len(parts) not in (2, 3):
        raise ConfigError(f"{where}: {text!r} is not 'source.quantity[.axes]'")
    source, quantity = parts[0], parts[1]
    if source not in kinds:
        raise ConfigError(f"{where}: source {source!r} is not one of {sorted(kinds)}")
    allowed = QUANTITIES[kinds[source]]
    if quantity not in allowed:
        raise ConfigError(f"{where}: source {source!r} gives {list(allowed)}, not {quantity!r}")
    default = {"position": "xyz", "velocity": "xyz", "velocity_heading": "xy", "height": "z"}
    letters = parts[2] if len(parts) == 3 else default.get(quantity, "")
    if quantity in ("heading", "heading_rate") and letters:
        raise ConfigError(f"{where}: {quantity} takes no axes, got {text!r}")
    if any(c not in default.get(quantity, "") for c in letters) or len(set(letters)) != \
            len(letters):
        raise ConfigError(f"{where}: axes {letters!r} of {text!r} must be a subset of "
                          f"{default.get(quantity, '')!r}")
    return Fusion(source, quantity, tuple(AXES[c] for c in letters))


def check_bank(params: BankParams, where: str = "<bank>") -> list[list[Fusion]]:
    """Names unique and known; returns each filter's parsed fusion list."""
    kinds = {"fc": "fc"}
    for i, s in enumerate(params.sources):
        if not s.name.isidentifier() or s.name in kinds:
            raise ConfigError(f"{where}: key 'sources[{i}].name' = {s.name!r} must be a unique "
                              f"identifier other than 'fc'")
        kinds[s.name] = s.kind
        model = SENSOR_PARAMS[s.kind]
        if s.sensor is not None and not isinstance(s.sensor, model):
            raise ConfigError(f"{where}: key 'sources[{i}].sensor' is a "
                              f"{type(s.sensor).__name__}; a '{s.kind}' source takes a "
                              f"{model.__name__} (tag it !{model.__name__})")
    if not params.filters:
        raise ConfigError(f"{where}: key 'filters' must declare at least one filter")
    names = [f.name for f in params.filters]
    if len(set(names)) != len(names) or not all(n.isidentifier() for n in names):
        raise ConfigError(f"{where}: key 'filters[].name' must be unique identifiers, got {names}")
    if params.ground.source and kinds.get(params.ground.source) != "range":
        ranges = [name for name, kind in kinds.items() if kind == "range"]
        raise ConfigError(f"{where}: key 'ground.source' = {params.ground.source!r} must be a "
                          f"source of kind 'range' ({ranges}) or empty")
    if params.arbiter.initial and params.arbiter.initial not in names:
        raise ConfigError(f"{where}: key 'arbiter.initial' = {params.arbiter.initial!r} is not "
                          f"one of {names}")
    fusions = []
    for i, f in enumerate(params.filters):
        key = f"{where}: key 'filters[{i}].fuse'"
        parsed = [parse_fusion(text, kinds, key) for text in f.fuse]
        if not any(p.quantity in ("position", "velocity", "velocity_heading", "height")
                   for p in parsed):
            raise ConfigError(f"{key} fuses no translational quantity")
        fusions.append(parsed)
    return fusions


def fusion_steps(fusions: list[list[Fusion]]) -> list[list[tuple[Fusion, np.ndarray]]]:
    """Per position j of the filters' fusion lists: each entry found there with the filters
    (rows) that have it at j. Fusing step by step keeps every filter's own order."""
    steps = []
    for j in range(max(len(f) for f in fusions)):
        groups: dict[Fusion, list[int]] = {}
        for i, entries in enumerate(fusions):
            if j < len(entries):
                groups.setdefault(entries[j], []).append(i)
        steps.append([(fusion, np.array(rows)) for fusion, rows in groups.items()])
    return steps


def status_layout(params: BankParams) -> VectorLayout:
    """`bank_status`: active filter index, switches, rejected messages (non-finite, out of order),
    on_ground (1 while the ground source reads the vehicle on the ground) and per filter:
    reliable (0/1), covariance trace, gate rejections, position p [m], velocity v [m/s] and
    heading [rad] in its own frame."""
    fields = [("active", 1), ("switches", 1), ("rejected_nan", 1), ("rejected_order", 1),
              ("on_ground", 1)]
    for f in params.filters:
        fields += [(f"{f.name}_reliable", 1), (f"{f.name}_trace", 1),
                   (f"{f.name}_gated", 1), (f"{f.name}_p", 3), (f"{f.name}_v", 3),
                   (f"{f.name}_heading", 1)]
    return VectorLayout("bank_status", fields)


@dc.dataclass
class BankState:
    filters: DecoupledKfBank        # every hypothesis, stored together (lkf.py)
    health: list[Health]
    seen: dict                      # source -> (last stamp, time of arrival)
    raw: dict                       # source -> last message (new messages differ from it)
    gated: np.ndarray               # per filter: gate rejections
    active: int = 0
    active_since: float = 0.0
    frame_counter: int = 0
    p_OldNew: np.ndarray = dc.field(default_factory=lambda: np.zeros(3))
    q_OldNew: np.ndarray = dc.field(default_factory=lambda: np.array([1.0, 0, 0, 0]))
    switches: int = 0
    rejected_nan: int = 0
    rejected_order: int = 0
    R_o: np.ndarray = dc.field(default_factory=lambda: np.eye(3))
    eta_o: float = 0.0
    stamp: float = np.nan
    heading_set: bool = False
    on_ground: bool = False          # the ground source's last recent reading: on the ground

    def copy(self) -> "BankState":
        return dc.replace(self, filters=self.filters.copy(),
                          health=[dc.replace(h, rejecting_since=h.rejecting_since.copy())
                                  for h in self.health], seen=dict(self.seen), raw=dict(self.raw),
                          gated=self.gated.copy())

    def __deepcopy__(self, memo) -> "BankState":
        """Itself: Drake clones abstract state values (copy.deepcopy) at every update, and the
        bank never changes a state held in a context (`_update` changes a `copy()` and sets
        it), so the clones may share it, as ImuSamples does."""
        return self


class EstimatorBank(LeafSystem):
    """Input  `fc_attitude`          FC_ATTITUDE (orientation R_o, body rates): source `fc`
    Input  `<source name>`        one per declared source, of its kind's layout (measurements.py)
    Input  `desired_acceleration` (3) unbiased desired acceleration M(53) in the flight
                                   controller's attitude frame [m/s^2] (unconnected: zero)
    Input  `request`              (1) index of a requested filter, -1 for none (unconnected: none)
    Output `state_estimate`       STATE_ESTIMATE of the active filter, in its frame E
    Output `bank_status`          `status_layout(params)`
    """

    def __init__(self, params: BankParams):
        super().__init__()
        self.params = params
        self._fusions = check_bank(params)
        # the chi-square quantiles (chi2.ppf p = chdtri(k, 1 - p))
        self._gate = {k: float(chdtri(k, 1.0 - params.arbiter.gate_probability))
                      for k in (1, 2, 3)}
        self.status = status_layout(params)
        self.filter_names = [f.name for f in params.filters]
        self._clip = {s.name: s.gate_action == "clip" for s in params.sources}
        self._gate_on = np.array([f.gate for f in params.filters])
        self._steps = fusion_steps(self._fusions)
        self._fc = self.DeclareVectorInputPort("fc_attitude", FC_ATTITUDE.size)
        self._sources = {s.name: (s, self.DeclareVectorInputPort(
            s.name, ADAPTERS[s.kind].layout.size)) for s in params.sources}
        self._acceleration = self.DeclareVectorInputPort("desired_acceleration", 3)
        self._request = self.DeclareVectorInputPort("request", 1)
        initial = self.filter_names.index(params.arbiter.initial) if params.arbiter.initial \
            else 0
        state = BankState(
            filters=DecoupledKfBank([f.model for f in params.filters], params.period),
            health=[Health(rejecting_since=np.full(len(f), np.nan)) for f in self._fusions],
            seen={}, raw={},
            gated=np.zeros(len(params.filters)), active=initial)
        self._state = self.DeclareAbstractState(AbstractValue.Make(state))
        self.DeclarePeriodicUnrestrictedUpdateEvent(params.period, 0.0, self._update)
        ticket = {self.abstract_state_ticket(self._state)}
        self.DeclareVectorOutputPort("state_estimate", STATE_ESTIMATE.size, self._calc_estimate,
                                     prerequisites_of_calc=ticket)
        self.DeclareVectorOutputPort("bank_status", self.status.size, self._calc_status,
                                     prerequisites_of_calc=ticket)

    # --- update -------------------------------------------------------------------------------
    def _update(self, context, state):
        s = context.get_abstract_state(self._state).get_value().copy()
        now = context.get_time()
        new = self._read_sources(context, s, now)
        self._follow_ground(s, new, now)
        self._predict(context, s)
        self._fuse(s, new, now)
        self._check_health(s, now)
        self._arbitrate(context, s, now)
        s.stamp = now
        state.get_mutable_abstract_state(self._state).set_value(s)

    def _read_sources(self, context, s: BankState, now: float) -> dict[str, list[Measurement]]:
        """New, finite, in-order messages of every source, as measurements (with their age)."""
        new = {}
        attitude = self._fc.Eval(context)
        if self._accept(s, "fc", attitude, FC_ATTITUDE, now):
            s.R_o = rotation_matrix(FC_ATTITUDE.get(attitude, "q_WB"))
            s.eta_o = heading(s.R_o)
            fc = self.params.fc
            new["fc"] = (now - FC_ATTITUDE.get(attitude, "stamp"), fc_measurements(
                attitude, np.radians(fc.heading_std) ** 2, fc.heading_rate_std ** 2))
        for name, (source, port) in self._sources.items():
            value = port.Eval(context)
            adapter = ADAPTERS[source.kind]
            if self._accept(s, name, value, adapter.layout, now):
                new[name] = (now - adapter.layout.get(value, "stamp"),
                             adapter.measurements(value, s.R_o))
        return new

    def _accept(self, s: BankState, name: str, value, layout, now: float) -> bool:
        """A new message of source `name` that is finite and in order (each counted once)."""
        if np.array_equal(value, s.raw.get(name), equal_nan=True):
            return False
        s.raw[name] = np.array(value)
        stamp, valid = stamp_and_valid(layout, value)
        last = s.seen.get(name, (-np.inf, -np.inf))[0]
        if not valid or stamp == last:
            return False
        if not np.all(np.isfinite(value)):
            s.rejected_nan += 1
            return False
        if stamp < last or stamp > now + 1e-9:
            s.rejected_order += 1
            return False
        s.seen[name] = (stamp, now)
        return True

    def _predict(self, context, s: BankState) -> None:
        u_o = self._acceleration.Eval(context) if self._acceleration.HasValue(context) \
            else np.zeros(3)
        if not np.all(np.isfinite(u_o)):
            s.rejected_nan += 1
            u_o = np.zeros(3)
        if s.on_ground:
            u_o = np.array([u_o[0], u_o[1], max(u_o[2], 0.0)])
        kfs = s.filters
        angle = kfs.eta[:, 0] - s.eta_o   # each filter's input in its frame: Rz(eta - eta_o) u_o
        c, sn = np.cos(angle), np.sin(angle)
        u = np.stack([c * u_o[0] - sn * u_o[1], sn * u_o[0] + c * u_o[1],
                      np.full(len(angle), u_o[2])], axis=1)
        kfs.predict(u)

    def _follow_ground(self, s: BankState, new: dict, now: float) -> None:
        """On the ground while the ground source's last reading, not older than the source's
        timeout, is under `ground.height` (module docstring)."""
        ground = self.params.ground
        if not ground.source:
            return
        if ground.source in new:
            heights = [m.z[0] for m in new[ground.source][1] if m.quantity == "height"]
            s.on_ground = bool(heights) and heights[0] < ground.height
        timeout = next(src.timeout for src in self.params.sources if src.name == ground.source)
        if now - s.seen.get(ground.source, (-np.inf, -np.inf))[0] > timeout:
            s.on_ground = False

    def _fuse(self, s: BankState, new: dict, now: float) -> None:
        """Every filter fuses its entries in its own order; at each position of the lists the
        filters with the same entry fuse it together (one vectorized correction)."""
        kfs = s.filters
        if "fc" in new and not s.heading_set:
            kfs.eta[:, 0] = s.eta_o  # every frame starts aligned with the flight controller's
        for j, groups in enumerate(self._steps):
            for fusion, rows in groups:
                if fusion.source not in new:
                    continue
                age, measurements = new[fusion.source]
                for m in measurements:
                    if m.quantity == fusion.quantity:
                        self._fuse_group(s, j, fusion, rows, m, age, now)
        for i, health in enumerate(s.health):
            health.initialized = bool(kfs.observed[i].all())

    def _fuse_group(self, s: BankState, j: int, fusion: Fusion, rows: np.ndarray,
                    m: Measurement, age: float, now: float) -> None:
        """Entry `j` of filters `rows` (all `fusion`): the correction, then the gate's
        bookkeeping (gate rejections, since when a source has been rejected)."""
        since = np.array([s.health[i].rejecting_since[j] for i in rows])
        reset = np.isfinite(since) & (now - since >= self.params.arbiter.reset_after)
        gated = self._gate_on[rows] & ~reset
        accepted = self._correct(s.filters, rows, fusion, m, age, gated, reset)
        for i, ok, first in zip(rows, accepted, ~np.isfinite(since)):
            if ok:
                s.health[i].rejecting_since[j] = np.nan
            else:
                s.gated[i] += 1
                if first:
                    s.health[i].rejecting_since[j] = now

    def _correct(self, kfs: DecoupledKfBank, rows: np.ndarray, fusion: Fusion, m: Measurement,
                 age: float, gated: np.ndarray, reset: np.ndarray) -> np.ndarray:
        """Fuses one measurement into filters `rows`; per row False if the innovation gate
        rejected it. A reset (the gate failed for `reset_after`) re-initializes a position from
        the measurement."""
        q = fusion.quantity
        if q in ("heading", "heading_rate"):
            order = 0 if q == "heading" else 1
            n = len(rows)
            if order == 1 or not gated.any():
                return kfs.correct_heading(rows, np.full(n, m.z[0]), np.full(n, m.variance[0]),
                                           order=order)
            accepted = np.ones(n, bool)
            for gate, select in ((self._gate[1], gated), (None, ~gated)):
                if select.any():
                    accepted[select] = kfs.correct_heading(
                        rows[select], np.full(select.sum(), m.z[0]),
                        np.full(select.sum(), m.variance[0]), order=0, gate=gate)
            return accepted
        axes = list(fusion.axes)
        z = m.z[[m.axes.index(a) for a in axes]]
        var = m.variance[[m.axes.index(a) for a in axes]]
        order = VELOCITY if q in ("velocity", "velocity_heading") else POSITION
        z = np.broadcast_to(z, (len(rows), len(axes)))
        if q == "velocity_heading":   # turned by each filter's own heading
            c, sn = np.cos(kfs.eta[rows, 0]), np.sin(kfs.eta[rows, 0])
            v = m.z
            z = np.stack([c * v[0] - sn * v[1], sn * v[0] + c * v[1], np.zeros(len(rows))],
                         axis=1)[:, axes]
            var = np.full(len(axes), var.max())
        var = np.broadcast_to(var, (len(rows), len(axes)))
        accepted = np.ones(len(rows), bool)
        if order == POSITION:  # initialization, or re-initialization
            start = reset | ~kfs.positioned[np.ix_(rows, axes)].all(axis=1)
            if start.any():
                kfs.set_position(rows[start], axes, z[start], var[start])
            rows, z, var, gated = rows[~start], z[~start], var[~start], gated[~start]
            keep = ~start
        else:
            keep = accepted
        if len(rows):
            accepted[keep] = kfs.correct(rows, axes, order, z, var, age,
                                         gate=self._gate[len(axes)], gated=gated,
                                         clip=self._clip[fusion.source])[0]
        return accepted

    def _check_health(self, s: BankState, now: float) -> None:
        timeouts = {src.name: src.timeout for src in self.params.sources}
        for i, health in enumerate(s.health):
            sources = {f.source for f in self._fusions[i] if f.source != "fc"}
            health.stopped = any(now - s.seen.get(name, (np.inf, -np.inf))[0] > timeouts[name]
                                 for name in sources)
            health.update(now, self.params.arbiter)
        s.heading_set = s.heading_set or "fc" in s.seen

    def _arbitrate(self, context, s: BankState, now: float) -> None:
        request = int(self._request.Eval(context)[0]) if self._request.HasValue(context) else -1
        traces = s.filters.covariance_traces()
        chosen = choose(s.active, s.active_since, now, s.health, traces, request,
                        self.params.arbiter)
        if chosen == s.active:
            return
        kfs = s.filters
        R_OldNew = rotation_z(kfs.eta[s.active, 0] - kfs.eta[chosen, 0])
        s.p_OldNew = kfs.x[s.active, :, 0] - R_OldNew @ kfs.x[chosen, :, 0]
        s.q_OldNew = RotationMatrix(R_OldNew).ToQuaternion().wxyz()
        s.active, s.active_since = chosen, now
        s.frame_counter += 1
        s.switches += 1

    # --- outputs ------------------------------------------------------------------------------
    def _calc_estimate(self, context, output):
        s = context.get_abstract_state(self._state).get_value()
        kfs, i = s.filters, s.active
        x, eta, var_pv, var_heading = kfs.x[i], kfs.eta[i], kfs.variances(i), kfs.P_eta[i, 0, 0]
        q_EB = RotationMatrix.ProjectToRotationMatrix(with_heading(s.R_o, eta[0])) \
            .ToQuaternion().wxyz()
        values = np.concatenate([x.ravel(), eta, var_pv, q_EB])
        valid = s.health[i].initialized and bool(np.all(np.isfinite(values)))
        if not valid:  # never hand a non-finite value on; say the estimate is not usable
            x, eta = np.zeros((3, 3)), np.zeros(2)
            var_pv, var_heading = DecoupledKfBank.initial_variances(kfs.params[i])
            q_EB = np.array([1.0, 0.0, 0.0, 0.0])
        output.SetFromVector(STATE_ESTIMATE.pack(
            stamp=s.stamp if np.isfinite(s.stamp) else context.get_time(),
            p_EB=x[:, 0], v_EB=x[:, 1], a_EB=x[:, 2], q_EB=q_EB,
            heading=eta[0], heading_rate=eta[1], var_pv=var_pv,
            var_heading=var_heading, frame_id=float(self.params.filters[i].frame_id),
            frame_counter=float(s.frame_counter), p_OldNew=s.p_OldNew, q_OldNew=s.q_OldNew,
            valid=float(valid)))

    def _calc_status(self, context, output):
        s = context.get_abstract_state(self._state).get_value()
        kfs = s.filters
        traces = kfs.covariance_traces()
        values = {"active": s.active, "switches": s.switches, "rejected_nan": s.rejected_nan,
                  "rejected_order": s.rejected_order, "on_ground": float(s.on_ground)}
        for i, name in enumerate(self.filter_names):
            values[f"{name}_reliable"] = float(s.health[i].reliable)
            values[f"{name}_trace"] = traces[i]
            values[f"{name}_gated"] = s.gated[i]
            values[f"{name}_p"] = kfs.x[i, :, 0]
            values[f"{name}_v"] = kfs.x[i, :, 1]
            values[f"{name}_heading"] = kfs.eta[i, 0]
        output.SetFromVector(self.status.pack(**values))
