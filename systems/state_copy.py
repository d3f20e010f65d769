"""Cheap copies of a Python system's abstract state.

Drake clones an abstract state (pydrake: `copy.deepcopy`) whenever an unrestricted update reads
it, twice per tick of the system that owns it. The generic deepcopy walks every field and goal;
`FieldwiseCopy` copies only what can change in place.
"""
import copy
import enum

import numpy as np

_SCALARS = (bool, int, float, str, bytes, type(None), np.generic, enum.Enum)


def immutable(value) -> bool:
    """A value that no system changes in place: a scalar, a string, an enum, None, a tuple of
    those, or a frozen dataclass (such as the trackers' goals and the UAV manager's commands)."""
    if isinstance(value, _SCALARS):
        return True
    if isinstance(value, tuple):
        return all(isinstance(item, _SCALARS) for item in value)
    params = getattr(type(value), "__dataclass_params__", None)
    return params is not None and params.frozen


class FieldwiseCopy:
    """Mixin for a (non-frozen) dataclass held as abstract state: `copy.deepcopy` copies its
    arrays (keeping their memory order and, through the memo, their aliasing), shares its
    immutable values and deep-copies anything else."""

    def __deepcopy__(self, memo):
        new = object.__new__(type(self))
        memo[id(self)] = new
        fields = new.__dict__
        for name, value in self.__dict__.items():
            if isinstance(value, np.ndarray) and not value.dtype.hasobject:
                copied = memo.get(id(value))
                if copied is None:
                    copied = memo[id(value)] = value.copy(order="K")  # (as deepcopy)
                fields[name] = copied
            else:
                fields[name] = value if immutable(value) else copy.deepcopy(value, memo)
        return new
