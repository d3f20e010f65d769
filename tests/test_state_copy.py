"""The field-by-field copy of abstract states (systems/state_copy.py): a copy is independent of
the original wherever either can change in place, and shares only what cannot."""
import copy
import dataclasses as dc
import enum

import numpy as np

from alight.systems.managers.uav_manager import UavMemory
from alight.systems.state_copy import FieldwiseCopy, immutable
from alight.systems.tracking.goal import TrackerGoal


class Mode(enum.IntEnum):
    A = 1


@dc.dataclass(frozen=True)
class Goal:
    points: tuple


@dc.dataclass
class Memory(FieldwiseCopy):
    plan: np.ndarray
    view: np.ndarray
    history: list
    goal: Goal
    mode: Mode = Mode.A
    stamp: float = 0.0


def make_memory() -> Memory:
    plan = np.asfortranarray(np.arange(6.0).reshape(2, 3))
    return Memory(plan=plan, view=plan, history=[np.zeros(2)], goal=Goal((1.0, 2.0)))


def test_a_copy_owns_its_arrays_and_containers_and_shares_only_immutable_values():
    original = make_memory()
    twin = copy.deepcopy(original)
    assert type(twin) is Memory
    twin.plan[0, 0] = 99.0
    twin.history[0][0] = 5.0
    twin.history.append(None)
    assert original.plan[0, 0] == 0.0 and original.history[0][0] == 0.0
    assert len(original.history) == 1
    # arrays: copied with their memory order; two names of one array stay one array
    assert twin.plan is not original.plan and twin.plan.flags.f_contiguous
    assert twin.view is twin.plan
    # what cannot change in place is shared
    assert twin.goal is original.goal and twin.mode is Mode.A
    np.testing.assert_array_equal(copy.deepcopy(make_memory()).plan, make_memory().plan)


def test_immutable_values():
    assert all(immutable(v) for v in (1, 2.0, "s", None, Mode.A, np.float64(1.0), (1, "a"),
                                      Goal((1.0,))))
    assert not any(immutable(v) for v in ([1], {"a": 1}, np.zeros(2), (np.zeros(2),),
                                          make_memory()))


def test_the_uav_managers_memory_copies_independently():
    memory = UavMemory(target=np.array([1.0, 2.0, 3.0, 0.5]))
    memory.trajectory = TrackerGoal(memory.target[None, :])
    twin = copy.deepcopy(memory)
    twin.home[0] = 7.0
    twin.group_request[:] = 1.0
    twin.target[0] = -1.0
    assert memory.home[0] == 0.0 and not memory.group_request.any()
    assert memory.target[0] == 1.0
    assert twin.trajectory is memory.trajectory
