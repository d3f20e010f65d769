"""Dynamic constraint groups of M Sec. 7.5: speed, acceleration, jerk and snap for horizontal
translation, vertical ascent, vertical descent and heading, in named groups (slow / medium / fast)
loaded from models/constraints.yaml. Trackers and the trajectory generator read one group."""
import dataclasses as dc

import numpy as np

from alight.models import model_path
from alight.systems.params import ConfigError, bounded, load_params, validate


@dc.dataclass
class DerivativeLimits:
    """Bounds on the 1st..4th time derivative (m/s, m/s^2, m/s^3, m/s^4; rad/... for heading)."""
    speed: float = bounded(2.0, 0.01, 100.0)
    acceleration: float = bounded(2.0, 0.01, 100.0)
    jerk: float = bounded(10.0, 0.01, 1000.0)
    snap: float = bounded(10.0, 0.01, 10000.0)

    def as_array(self) -> np.ndarray:
        """[speed, acceleration, jerk, snap]."""
        return np.array([self.speed, self.acceleration, self.jerk, self.snap])


@dc.dataclass
class ConstraintGroup:
    """One group of M Sec. 7.5. Horizontal limits bound the norm of the x-y derivative."""
    horizontal: DerivativeLimits = dc.field(default_factory=DerivativeLimits)
    ascending: DerivativeLimits = dc.field(default_factory=DerivativeLimits)
    descending: DerivativeLimits = dc.field(default_factory=DerivativeLimits)
    heading: DerivativeLimits = dc.field(default_factory=DerivativeLimits)


@dc.dataclass
class ConstraintGroups:
    default: str = "medium"
    groups: dict[str, ConstraintGroup] = dc.field(
        default_factory=lambda: {"medium": ConstraintGroup()})

    def group(self, name: str | None = None) -> ConstraintGroup:
        name = self.default if name is None else name
        if name not in self.groups:
            raise ConfigError(f"unknown constraint group {name!r}: expected one of "
                              f"{sorted(self.groups)}")
        return self.groups[name]


def load_constraint_groups(filename: str = "constraints.yaml") -> ConstraintGroups:
    """A path, or a file name in models/; raises ConfigError naming the file and the key."""
    path = model_path(filename)
    groups = load_params(ConstraintGroups, path)
    check_constraint_groups(groups, str(path))
    return groups


def check_constraint_groups(groups: ConstraintGroups, source: str, prefix: str = "") -> None:
    """What `load_params` cannot check: the default names a group, and every group's ranges
    (validate() does not descend into dicts). ConfigError names `source` and the key (under
    `prefix` where the groups are a field of other parameters)."""
    if groups.default not in groups.groups:
        raise ConfigError(f"{source}: key '{prefix}default' = {groups.default!r} is not one of "
                          f"the groups {sorted(groups.groups)}")
    for name, group in groups.groups.items():
        validate(group, source, f"{prefix}groups.{name}.")


def load_constraint_group(name: str | None = None,
                          filename: str = "constraints.yaml") -> ConstraintGroup:
    return load_constraint_groups(filename).group(name)


def derivative_peaks(derivatives: list[np.ndarray]) -> np.ndarray:
    """Peak of each quantity of a sampled motion, as a (4 quantities x 4 derivatives) array:
    rows horizontal norm, ascent (max of +z), descent (max of -z), heading (|.|); columns the
    1st..4th derivatives given as (samples, 4) arrays [x, y, z, heading]."""
    peaks = np.zeros((4, 4))
    for k, d in enumerate(derivatives):
        peaks[0, k] = np.max(np.linalg.norm(d[:, :2], axis=1))
        peaks[1, k] = max(0.0, np.max(d[:, 2]))
        peaks[2, k] = max(0.0, np.max(-d[:, 2]))
        peaks[3, k] = np.max(np.abs(d[:, 3]))
    return peaks


def limits_table(group: ConstraintGroup) -> np.ndarray:
    """The group as the (4 x 4) array that `derivative_peaks` is compared with."""
    return np.array([group.horizontal.as_array(), group.ascending.as_array(),
                     group.descending.as_array(), group.heading.as_array()])
