"""The gain & constraint manager, M Sec. 7.5: which dynamic constraint group (slow / medium / fast,
models/constraints.yaml) the trackers use and which SE(3) gain group (soft / medium / tight,
models/controllers.yaml) the controller uses, per state estimator (models/constraint_manager.yaml).

Each estimator, named with the `frame_id` its estimate carries (STATE_ESTIMATE), has a list of
allowed constraint groups with a fallback among them, and likewise for the gain groups; the
`default` entry serves every frame id not listed (mocap, frame 0). The rules of M Sec. 7.5:

- a request (the mission, M Sec. 7.7) switches to an allowed group of the current estimator;
  any other request is refused, with its reason on `constraint_status`;
- when the estimator changes (a valid estimate with another `frame_id`), a group the new
  estimator does not allow is replaced by its fallback; an allowed one is kept.

Before the first valid estimate the `default` entry rules and its fallbacks are active. The
outputs are state, updated every `period`: a change reaches the trackers and the controller on
the tick after the one that decided it (10 ms at 100 Hz).
"""
import dataclasses as dc
import enum

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.models import model_path
from alight.systems.boundary import STATE_ESTIMATE, VectorLayout
from alight.systems.control.se3 import gain_group_names
from alight.systems.params import ConfigError, bounded, load_params, param_file, validate
from alight.systems.tracking.constraints import ConstraintGroups, check_constraint_groups


@dc.dataclass
class GroupRule:
    """The groups one estimator allows, and the one switched in when the current is not."""
    allowed: list[str] = dc.field(default_factory=lambda: ["medium"])
    fallback: str = "medium"


@dc.dataclass
class GroupRules:
    constraints: GroupRule = dc.field(default_factory=GroupRule)  # models/constraints.yaml groups
    gains: GroupRule = dc.field(default_factory=GroupRule)        # se3.groups of controllers.yaml


@dc.dataclass
class EstimatorRules(GroupRules):
    frame_id: int = bounded(0, 0, 1_000_000)   # the estimator's frame id (STATE_ESTIMATE)


@dc.dataclass
class ConstraintManagerParams:
    period: float = bounded(0.01, 0.001, 0.1, "s")     # 100 Hz with the trackers (DESIGN.md)
    constraint_groups: ConstraintGroups = param_file(ConstraintGroups, "constraints.yaml")
    default: GroupRules = dc.field(default_factory=GroupRules)   # any frame id not listed
    estimators: dict[str, EstimatorRules] = dc.field(default_factory=dict)


class GroupRefusal(enum.IntEnum):
    """`constraint_status.*_refusal`: the outcome of the last request of that kind."""
    NONE = 0           # accepted (or no request yet)
    UNKNOWN_GROUP = 1  # the index names no group
    NOT_ALLOWED = 2    # the current estimator does not allow the group


NO_ESTIMATOR = -1.0   # `constraint_status.frame_id` before the first valid estimate

# `constraint_status`: the active constraint group (index into the sorted constraint group names)
# and gain group (index into the SE(3) gain group names); the id and outcome (GroupRefusal) of the
# last constraint request and of the last gain request; the number of group switches (requested
# and automatic); the frame id of the estimator the groups were chosen for (NO_ESTIMATOR: none).
CONSTRAINT_STATUS = VectorLayout("constraint_status", [
    ("constraint_group", 1), ("gain_group", 1), ("constraint_request", 1),
    ("constraint_refusal", 1), ("gain_request", 1), ("gain_refusal", 1), ("switches", 1),
    ("frame_id", 1)])

# `request`: [constraint request id, constraint group index, gain request id, gain group index];
# an id > 0 that differs from the last one seen is a new request.
REQUEST = VectorLayout("group_request", [
    ("constraint_request", 1), ("constraint_group", 1), ("gain_request", 1), ("gain_group", 1)])

_KINDS = (("constraints", "constraint_group", "constraint_request", "constraint_refusal"),
          ("gains", "gain_group", "gain_request", "gain_refusal"))


class ConstraintManager(LeafSystem):
    """M Sec. 7.5; see the module docstring.

    Inputs  `state_estimate` STATE_ESTIMATE (its `frame_id` names the active estimator);
            `request` (4) REQUEST (optional: unconnected means no requests)
    Outputs `constraint_group` (1) index into `constraint_group_names` (the MPC tracker's
            `constraint_group` input); `gain_group` (1) index into `gain_group_names` (the SE(3)
            controller's `gain_group` input); `constraint_status` CONSTRAINT_STATUS
    """

    def __init__(self, params: ConstraintManagerParams, constraint_group_names: list[str],
                 gain_group_names: list[str], source: str = "<params>"):
        super().__init__()
        check_rules(params, constraint_group_names, gain_group_names, source)
        self.constraint_group_names = list(constraint_group_names)
        self.gain_group_names = list(gain_group_names)
        self._names = {"constraints": self.constraint_group_names, "gains": self.gain_group_names}
        self._default = params.default
        self._by_frame = {rules.frame_id: rules for rules in params.estimators.values()}
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        self._request = self.DeclareVectorInputPort("request", REQUEST.size)
        x0 = CONSTRAINT_STATUS.pack(
            constraint_group=self.constraint_index(params.default.constraints.fallback),
            gain_group=self.gain_index(params.default.gains.fallback), constraint_request=0,
            constraint_refusal=GroupRefusal.NONE, gain_request=0, gain_refusal=GroupRefusal.NONE,
            switches=0, frame_id=NO_ESTIMATOR)
        self._state = self.DeclareDiscreteState(x0)
        self.DeclarePeriodicDiscreteUpdateEvent(params.period, 0.0, self._update)
        for field in ("constraint_group", "gain_group"):
            self.DeclareVectorOutputPort(
                field, 1, lambda context, output, field=field: output.SetFromVector(
                    [CONSTRAINT_STATUS.get(self._x(context), field)]),
                {self.all_state_ticket()})
        self.DeclareStateOutputPort("constraint_status", self._state)

    def constraint_index(self, name: str) -> int:
        """The index of constraint group `name` (what `request` and the tracker take)."""
        return _index(self.constraint_group_names, name, "constraint")

    def gain_index(self, name: str) -> int:
        """The index of gain group `name` (what `request` and the SE(3) controller take)."""
        return _index(self.gain_group_names, name, "gain")

    def rules(self, frame_id: float) -> GroupRules:
        """The entry of the estimator with `frame_id`; `default` when none is listed."""
        if not np.isfinite(frame_id) or frame_id != int(frame_id):
            return self._default
        return self._by_frame.get(int(frame_id), self._default)

    def _x(self, context) -> np.ndarray:
        return context.get_discrete_state(self._state).get_value()

    def _update(self, context, discrete_state):
        x = self._x(context).copy()
        estimate = self._estimate.Eval(context)
        frame_id = STATE_ESTIMATE.get(estimate, "frame_id")
        if STATE_ESTIMATE.get(estimate, "valid") > 0.5 and np.isfinite(frame_id) \
                and frame_id != CONSTRAINT_STATUS.get(x, "frame_id"):
            self._fall_back(x, frame_id)
        if self._request.HasValue(context):
            self._handle_requests(x, self._request.Eval(context))
        discrete_state.set_value(self._state, x)

    def _fall_back(self, x: np.ndarray, frame_id: float) -> None:
        """The estimator changed: each group it does not allow is replaced by its fallback."""
        x[CONSTRAINT_STATUS.slice("frame_id")] = frame_id
        rules = self.rules(frame_id)
        for kind, group_field, _, _ in _KINDS:
            rule, names = getattr(rules, kind), self._names[kind]
            if names[int(CONSTRAINT_STATUS.get(x, group_field))] not in rule.allowed:
                self._switch(x, group_field, names.index(rule.fallback))

    def _handle_requests(self, x: np.ndarray, request: np.ndarray) -> None:
        rules = self.rules(CONSTRAINT_STATUS.get(x, "frame_id"))
        for kind, group_field, id_field, refusal_field in _KINDS:
            request_id, index = REQUEST.get(request, id_field), REQUEST.get(request, group_field)
            if not (np.isfinite(request_id) and request_id > 0
                    and request_id != CONSTRAINT_STATUS.get(x, id_field)):
                continue
            x[CONSTRAINT_STATUS.slice(id_field)] = request_id
            names = self._names[kind]
            if not (np.isfinite(index) and index == int(index) and 0 <= index < len(names)):
                refusal = GroupRefusal.UNKNOWN_GROUP
            elif names[int(index)] not in getattr(rules, kind).allowed:
                refusal = GroupRefusal.NOT_ALLOWED
            else:
                refusal = GroupRefusal.NONE
                self._switch(x, group_field, int(index))
            x[CONSTRAINT_STATUS.slice(refusal_field)] = refusal

    @staticmethod
    def _switch(x: np.ndarray, group_field: str, index: int) -> None:
        if CONSTRAINT_STATUS.get(x, group_field) != index:
            x[CONSTRAINT_STATUS.slice(group_field)] = index
            x[CONSTRAINT_STATUS.slice("switches")] += 1


def _index(names: list[str], name: str, kind: str) -> int:
    if name not in names:
        raise ValueError(f"unknown {kind} group {name!r}: expected one of {names}")
    return names.index(name)


def check_rules(params: ConstraintManagerParams, constraint_group_names: list[str],
                gain_group_names: list[str], source: str = "<params>") -> None:
    """Raises ConfigError naming `source` and the key: an unknown group name, an empty allowed
    list, a fallback not in its allowed list, two estimators with one frame id."""
    entries = [("default", params.default)] + [
        (f"estimators.{name}", rules) for name, rules in params.estimators.items()]
    for key, rules in entries:
        validate(rules, source, key + ".")     # validate() does not descend into dicts
        for kind, names in (("constraints", constraint_group_names),
                            ("gains", gain_group_names)):
            _check_rule(getattr(rules, kind), names, f"{key}.{kind}", source)
    seen = {}
    for name, rules in params.estimators.items():
        if rules.frame_id in seen:
            raise ConfigError(f"{source}: key 'estimators.{name}.frame_id' = {rules.frame_id} is "
                              f"already the frame id of 'estimators.{seen[rules.frame_id]}'")
        seen[rules.frame_id] = name


def _check_rule(rule: GroupRule, names: list[str], key: str, source: str) -> None:
    if not rule.allowed:
        raise ConfigError(f"{source}: key '{key}.allowed' is empty: list at least one of "
                          f"{names}")
    for name in rule.allowed:
        if name not in names:
            raise ConfigError(f"{source}: key '{key}.allowed' names unknown group {name!r}: "
                              f"expected groups of {names}")
    if rule.fallback not in rule.allowed:
        raise ConfigError(f"{source}: key '{key}.fallback' = {rule.fallback!r} is not in its "
                          f"allowed list {rule.allowed}")


def load_constraint_manager_params(filename: str = "constraint_manager.yaml"
                                   ) -> ConstraintManagerParams:
    """A path, or a file name in models/; checks the groups against its `constraint_groups`
    and the SE(3) gain groups; raises ConfigError naming the file and key."""
    path = model_path(filename)
    params = load_params(ConstraintManagerParams, path)
    check_constraint_groups(params.constraint_groups, str(path), "constraint_groups.")
    check_rules(params, sorted(params.constraint_groups.groups), gain_group_names(), str(path))
    return params


def make_constraint_manager(params: ConstraintManagerParams,
                            source: str = "<params>") -> ConstraintManager:
    """The manager of `params` (`source` names them in errors), with its `constraint_groups`
    sorted by name as the MPC tracker indexes them (`tracker.group_names`)."""
    names = sorted(params.constraint_groups.groups)
    return ConstraintManager(params, names, gain_group_names(), source)
