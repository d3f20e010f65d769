"""Measurement sources of the estimator bank (M Sec. 3.1.2) and their adapters.

A source is a port of one of the layouts below, published by a sensor (a simulated model in
`alight.systems.sensors`, or hardware). Its adapter turns one message into `Measurement`s (a
quantity of some axes, its value and variance) that a filter fuses when its YAML lists
`source.quantity[.axes]`. Adding a source is a YAML entry; adding a new *kind* of source is one
layout and one adapter function here (registered in `ADAPTERS`), nothing in the bank.

Kinds and quantities:
- `position_fix` (GNSS-like, RTK-like): `position` p [m] in the source's frame.
- `velocity_fix` (optic-flow-like): `velocity_heading` horizontal velocity in the heading frame H
  (x along the heading vector M(5), z up) [m/s]; the filter turns it by its own heading.
- `range` (down rangefinder): `height` = range * cos(tilt) (tilt from the flight controller).
- `odometry` (a STATE_ESTIMATE: mocap, VIO): `position`, `velocity`, `heading`.
The flight controller's attitude (`fc_attitude`) is the built-in source `fc`: `heading` M(3) of
its orientation (magnetometer-aided) and `heading_rate` from its body rates by M(15).
"""
import dataclasses as dc

import numpy as np

from alight.systems.boundary import FC_ATTITUDE, RANGE, STATE_ESTIMATE, VectorLayout
from alight.systems.estimation.heading import heading_rate
from alight.systems.rotations import heading, rotation_matrix

# stamp: time of the measurement [s]; p [m]; var_p [m^2]; valid (0: no fix).
POSITION_FIX = VectorLayout("position_fix", [("stamp", 1), ("p", 3), ("var_p", 3), ("valid", 1)])
# v_H: horizontal velocity in the heading frame H [m/s]; var_v [(m/s)^2].
VELOCITY_FIX = VectorLayout("velocity_fix", [("stamp", 1), ("v_H", 2), ("var_v", 2),
                                             ("valid", 1)])

AXES = {"x": 0, "y": 1, "z": 2}


@dc.dataclass(frozen=True)
class Measurement:
    quantity: str          # position, velocity, velocity_heading, height, heading, heading_rate
    axes: tuple[int, ...]  # translational axes (position, velocity); () for the others
    z: np.ndarray
    variance: np.ndarray


def position_fix(value: np.ndarray, R_o: np.ndarray) -> list[Measurement]:
    return [Measurement("position", (0, 1, 2), POSITION_FIX.get(value, "p"),
                        POSITION_FIX.get(value, "var_p"))]


def velocity_fix(value: np.ndarray, R_o: np.ndarray) -> list[Measurement]:
    return [Measurement("velocity_heading", (0, 1), VELOCITY_FIX.get(value, "v_H"),
                        VELOCITY_FIX.get(value, "var_v"))]


def range_height(value: np.ndarray, R_o: np.ndarray) -> list[Measurement]:
    cos_tilt = R_o[2, 2]
    return [Measurement("height", (2,), np.array([RANGE.get(value, "range") * cos_tilt]),
                        np.array([RANGE.get(value, "var") * cos_tilt ** 2]))]


def odometry(value: np.ndarray, R_o: np.ndarray) -> list[Measurement]:
    var = STATE_ESTIMATE.get(value, "var_pv")
    return [Measurement("position", (0, 1, 2), STATE_ESTIMATE.get(value, "p_EB"), var[:3]),
            Measurement("velocity", (0, 1, 2), STATE_ESTIMATE.get(value, "v_EB"), var[3:]),
            Measurement("heading", (), np.array([STATE_ESTIMATE.get(value, "heading")]),
                        np.array([STATE_ESTIMATE.get(value, "var_heading")]))]


@dc.dataclass(frozen=True)
class Adapter:
    layout: VectorLayout
    measurements: object  # (value, R_o) -> list[Measurement]


ADAPTERS = {"position_fix": Adapter(POSITION_FIX, position_fix),
            "velocity_fix": Adapter(VELOCITY_FIX, velocity_fix),
            "range": Adapter(RANGE, range_height),
            "odometry": Adapter(STATE_ESTIMATE, odometry)}

QUANTITIES = {"position_fix": ("position",), "velocity_fix": ("velocity_heading",),
              "range": ("height",), "odometry": ("position", "velocity", "heading"),
              "fc": ("heading", "heading_rate")}


def fc_measurements(value: np.ndarray, heading_var: float,
                    heading_rate_var: float) -> list[Measurement]:
    """The built-in `fc` source: heading M(3) and heading rate M(15) of the FC attitude."""
    R_o = rotation_matrix(FC_ATTITUDE.get(value, "q_WB"))
    return [Measurement("heading", (), np.array([heading(R_o)]), np.array([heading_var])),
            Measurement("heading_rate", (), np.array([heading_rate(
                R_o, FC_ATTITUDE.get(value, "w_B"))]), np.array([heading_rate_var]))]


def stamp_and_valid(layout: VectorLayout, value: np.ndarray) -> tuple[float, bool]:
    valid = layout.get(value, "valid") > 0.5 if "valid" in dict(layout.fields) else True
    return float(layout.get(value, "stamp")), bool(valid)
