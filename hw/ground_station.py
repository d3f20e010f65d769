"""What the simulated autopilot answers a ground station (QGroundControl, MAVSDK, MAVProxy) beyond
commands: PX4's parameter protocol over the emulated PX4 parameters, and the mission protocol with
no mission on board.

Parameters carry PX4's names, types and units; each maps to the flight-controller emulation's
field that does what PX4's parameter does (models/sim_vehicle.yaml `flight_controller`). A
writable one changes the running emulation at the next bridge tick (the commander and the attitude
controller read these fields every step). A read-only one is fixed when the simulation is built
(a value cached at construction, or an identity): setting it is refused with the current value
and a STATUSTEXT, as PX4 answers a PARAM_SET it cannot apply. Integer parameters are encoded
bytewise in PARAM_VALUE.param_value, as PX4 does (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE).
"""
import dataclasses as dc
import math
import struct
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from alight.hw.autopilot_rules import OFFBOARD_LOSS_ACTIONS

REAL32 = mavlink.MAV_PARAM_TYPE_REAL32
INT32 = mavlink.MAV_PARAM_TYPE_INT32


@dc.dataclass(frozen=True)
class Parameter:
    """One emulated PX4 parameter: `read()` in PX4's unit; `write(value)` (None: read-only) with
    the allowed range [lo, hi] in PX4's unit."""
    name: str
    kind: int
    read: Callable[[], float]
    write: Callable[[float], None] | None = None
    lo: float = -math.inf
    hi: float = math.inf
    fixed_why: str = ""  # why a read-only parameter cannot change while the simulation runs
    allowed: tuple = ()  # the values emulated, where not every one in [lo, hi] is


def _field(params, name: str, index: int | None = None, scale: float = 1.0, also=None,
           writable: bool = True, why: str = ""):
    """read/write/range of a (bounded) dataclass field of `params`, or of element `index` of a
    list field, in PX4's unit = ours * `scale`; `also(value)` applies a write elsewhere too."""
    lo, hi = next(f for f in dc.fields(params) if f.name == name).metadata["range"]

    def read():
        value = getattr(params, name)
        return float(value if index is None else value[index]) * scale

    integer = isinstance(getattr(params, name), int)

    def write(value):
        ours = int(value) if integer else value / scale
        if index is None:
            setattr(params, name, ours)
        else:
            getattr(params, name)[index] = ours
        if also is not None:
            also(ours)
    return dict(read=read, write=write if writable else None, lo=lo * scale, hi=hi * scale,
                fixed_why=why)


def emulated_parameters(flight_controller, rules, system_id: int,
                        component_id: int) -> list[Parameter]:
    """The PX4 parameters of the simulated autopilot, sorted by name as PX4 lists them.
    `flight_controller`: the running emulation's FlightControllerParams (the same objects its
    systems read); `rules`: the autopilot's AutopilotRules (its offboard-loss timeout and
    action)."""
    commander, attitude = flight_controller.commander, flight_controller.attitude
    cached = "fixed at start"  # the commander / inner loop cache it (models/sim_vehicle.yaml)

    def set_loss_timeout(value):
        rules.stale_timeout = value
    table = [
        Parameter("COM_OF_LOSS_T", REAL32, **_field(commander, "stale_timeout",
                                                     also=set_loss_timeout)),
        Parameter("COM_DISARM_LAND", REAL32, **_field(commander, "land_time")),
        Parameter("COM_OBL_RC_ACT", INT32, **_field(rules.params, "com_obl_rc_act"),
                  allowed=tuple(sorted(OFFBOARD_LOSS_ACTIONS))),
        Parameter("MPC_LAND_SPEED", REAL32, **_field(commander, "failsafe_descent_speed")),
        Parameter("MPC_THR_HOVER", REAL32, **_field(commander, "hover_thrust", writable=False,
                                                     why=cached)),
        Parameter("MC_YAW_WEIGHT", REAL32, **_field(attitude, "yaw_weight")),
        Parameter("MAV_SYS_ID", INT32, lambda: system_id, fixed_why="identity"),
        Parameter("MAV_COMP_ID", INT32, lambda: component_id, fixed_why="identity"),
        Parameter("MAV_PROTO_VER", INT32, lambda: 0,
                  fixed_why="hw/endpoint.py"),
        Parameter("SYS_HITL", INT32, lambda: 1, fixed_why="simulated vehicle"),
    ]
    hold = rules.params.hold  # Hold/Position's controller, read at every command
    for name, field in (("MPC_XY_P", "xy_p"), ("MPC_Z_P", "z_p"),
                        ("MPC_XY_VEL_P_ACC", "xy_vel_p_acc"), ("MPC_XY_VEL_I_ACC", "xy_vel_i_acc"),
                        ("MPC_Z_VEL_P_ACC", "z_vel_p_acc"), ("MPC_Z_VEL_I_ACC", "z_vel_i_acc"),
                        ("MPC_Z_VEL_MAX_DN", "z_vel_max"), ("MPC_TILTMAX_AIR", "tiltmax_air")):
        table.append(Parameter(name, REAL32, **_field(hold, field)))
    for axis, name in enumerate(("ROLL", "PITCH", "YAW")):
        table.append(Parameter(f"MC_{name}_P", REAL32, **_field(attitude, "gain", axis)))
        table.append(Parameter(f"MC_{name}RATE_MAX", REAL32, **_field(
            attitude, "max_rate", axis, scale=180.0 / math.pi, writable=False, why=cached)))
    return sorted(table, key=lambda p: p.name)


def wire_value(parameter: Parameter) -> float:
    """PARAM_VALUE.param_value: the float, or the int32's bytes read as a float (bytewise)."""
    value = parameter.read()
    if parameter.kind == INT32:
        return struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return float(value)


def from_wire(parameter: Parameter, param_value: float) -> float:
    if parameter.kind == INT32:
        return float(struct.unpack("<i", struct.pack("<f", param_value))[0])
    return float(param_value)


class GroundStationService:
    """Answers PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET and MISSION_REQUEST_LIST /
    MISSION_COUNT / MISSION_CLEAR_ALL. `answer(message)` returns the messages to send (built
    with `mav`, the endpoint's encoder), or None for a message it does not handle."""

    KINDS = ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET", "MISSION_REQUEST_LIST",
             "MISSION_COUNT", "MISSION_CLEAR_ALL")

    def __init__(self, parameters: list[Parameter], mav):
        self.parameters = parameters
        self._index = {p.name: i for i, p in enumerate(parameters)}
        self._mav = mav
        self.refusals: list[str] = []

    def answer(self, message) -> list | None:
        kind = message.get_type()
        if kind == "PARAM_REQUEST_LIST":
            return [self._value(i) for i in range(len(self.parameters))]
        if kind == "PARAM_REQUEST_READ":
            index = self._find(message.param_id) if message.param_index < 0 \
                else message.param_index
            return [self._value(index)] if index is not None and 0 <= index < len(
                self.parameters) else []  # unknown: no answer (MAVLink parameter protocol)
        if kind == "PARAM_SET":
            return self._set(message)
        header = message.get_header()
        mission_type = getattr(message, "mission_type", 0)
        if kind == "MISSION_REQUEST_LIST":
            return [self._mav.mission_count_encode(header.srcSystem, header.srcComponent, 0,
                                                   mission_type)]
        if kind == "MISSION_COUNT":  # an upload: no mission can be flown here
            return [self._mav.mission_ack_encode(header.srcSystem, header.srcComponent,
                                                 mavlink.MAV_MISSION_UNSUPPORTED, mission_type)]
        if kind == "MISSION_CLEAR_ALL":
            return [self._mav.mission_ack_encode(header.srcSystem, header.srcComponent,
                                                 mavlink.MAV_MISSION_ACCEPTED, mission_type)]
        return None

    def _find(self, param_id) -> int | None:
        name = param_id.decode("ascii", "replace") if isinstance(param_id, bytes) else param_id
        return self._index.get(name.rstrip("\x00"))

    def _value(self, index: int):
        parameter = self.parameters[index]
        return self._mav.param_value_encode(parameter.name.encode(), wire_value(parameter),
                                            parameter.kind, len(self.parameters), index)

    def _set(self, message) -> list:
        index = self._find(message.param_id)
        if index is None:
            return [self._refuse(f"{message.param_id}: no such parameter")]
        parameter = self.parameters[index]
        value = from_wire(parameter, message.param_value)
        if message.param_type != parameter.kind:
            why = f"{parameter.name}: type {message.param_type}, not {parameter.kind}"
        elif parameter.write is None:
            why = f"{parameter.name} read-only: {parameter.fixed_why}"
        elif not (math.isfinite(value) and parameter.lo <= value <= parameter.hi):
            why = f"{parameter.name} {value:g} outside [{parameter.lo:g}, {parameter.hi:g}]"
        elif parameter.allowed and value not in parameter.allowed:
            why = f"{parameter.name} {value:g} not in {list(parameter.allowed)}"
        else:
            parameter.write(value)
            return [self._value(index)]
        return [self._refuse(why), self._value(index)]  # the unchanged value

    def _refuse(self, text: str):
        self.refusals.append(text)
        return self._mav.statustext_encode(mavlink.MAV_SEVERITY_WARNING, text.encode()[:50])
