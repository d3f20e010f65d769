"""The PX4 conventions alight's MAVLink side relies on: PX4's custom flight modes in
HEARTBEAT.custom_mode and MAV_CMD_DO_SET_MODE, and the magic value that forces a disarm in air.

PX4 packs its mode as custom_mode = main_mode << 16 | sub_mode << 24 (px4_custom_mode.h).
"""
import enum

from pymavlink.dialects.v20 import common as mavlink


class MainMode(enum.IntEnum):
    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7


class AutoSubMode(enum.IntEnum):
    READY = 1
    TAKEOFF = 2
    LOITER = 3  # "Hold"
    MISSION = 4
    RTL = 5
    LAND = 6


FORCE_DISARM = 21196.0  # MAV_CMD_COMPONENT_ARM_DISARM param2: disarm even in flight


def custom_mode(main: int, sub: int = 0) -> int:
    return (int(main) & 0xFF) << 16 | (int(sub) & 0xFF) << 24


def split_custom_mode(value: int) -> tuple[int, int]:
    """(main mode, sub mode) of a HEARTBEAT custom_mode."""
    return (int(value) >> 16) & 0xFF, (int(value) >> 24) & 0xFF


OFFBOARD = custom_mode(MainMode.OFFBOARD)
HOLD = custom_mode(MainMode.AUTO, AutoSubMode.LOITER)
LAND = custom_mode(MainMode.AUTO, AutoSubMode.LAND)

MODE_NAMES = {OFFBOARD: "OFFBOARD", HOLD: "AUTO.LOITER", LAND: "AUTO.LAND"}


def mode_name(value: int) -> str:
    main, sub = split_custom_mode(value)
    if value in MODE_NAMES:
        return MODE_NAMES[value]
    try:
        name = MainMode(main).name
    except ValueError:
        return f"custom mode {value:#x}"
    return f"{name}.{sub}" if sub else name


def result_name(result: int) -> str:
    entry = mavlink.enums["MAV_RESULT"].get(int(result))
    return entry.name if entry is not None else f"MAV_RESULT {result}"


def command_name(command: int) -> str:
    entry = mavlink.enums["MAV_CMD"].get(int(command))
    return entry.name if entry is not None else f"MAV_CMD {command}"
