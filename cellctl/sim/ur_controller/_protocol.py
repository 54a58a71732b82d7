"""RTDE wire format (protocol version 2), as UR's RTDE guide describes it.

Every package is ``uint16 size`` (header included, big-endian) ``uint8 type`` + payload.
Types used here: ``V`` request protocol version, ``v`` controller version, ``M`` text message,
``O`` set up outputs, ``I`` set up inputs, ``S`` start, ``P`` pause, ``U`` data package.
"""

from __future__ import annotations

import re
import struct

__all__ = [
    "FORMATS",
    "HEADER",
    "RTDE_CONTROL_PACKAGE_PAUSE",
    "RTDE_CONTROL_PACKAGE_SETUP_INPUTS",
    "RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS",
    "RTDE_CONTROL_PACKAGE_START",
    "RTDE_DATA_PACKAGE",
    "RTDE_GET_URCONTROL_VERSION",
    "RTDE_REQUEST_PROTOCOL_VERSION",
    "RTDE_TEXT_MESSAGE",
    "input_type",
    "output_type",
    "package",
]

HEADER = struct.Struct(">HB")

RTDE_REQUEST_PROTOCOL_VERSION = ord("V")
RTDE_GET_URCONTROL_VERSION = ord("v")
RTDE_TEXT_MESSAGE = ord("M")
RTDE_DATA_PACKAGE = ord("U")
RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS = ord("O")
RTDE_CONTROL_PACKAGE_SETUP_INPUTS = ord("I")
RTDE_CONTROL_PACKAGE_START = ord("S")
RTDE_CONTROL_PACKAGE_PAUSE = ord("P")

FORMATS = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}
"""struct codes (big-endian) of the RTDE data types."""

_OUTPUTS = {
    "DOUBLE": (
        "timestamp actual_execution_time speed_scaling target_speed_fraction actual_momentum "
        "actual_main_voltage actual_robot_voltage actual_robot_current standard_analog_input0 "
        "standard_analog_input1 standard_analog_output0 standard_analog_output1 payload io_current "
        "tool_analog_input0 tool_analog_input1 tool_output_current tool_temperature"
    ),
    "VECTOR6D": (
        "target_q target_qd target_qdd target_current target_moment actual_q actual_qd actual_qdd "
        "actual_current actual_moment joint_control_output actual_TCP_pose actual_TCP_speed "
        "actual_TCP_force target_TCP_pose target_TCP_speed joint_temperatures actual_joint_voltage "
        "ft_raw_wrench payload_inertia tcp_offset actual_current_window joint_position_deviation_ratio "
        "collision_detection_ratio"
    ),
    "VECTOR3D": "actual_tool_accelerometer payload_cog elbow_position elbow_velocity",
    "UINT64": "actual_digital_input_bits actual_digital_output_bits",
    "INT32": "robot_mode safety_mode tool_mode tool_output_voltage",
    "UINT32": (
        "runtime_state robot_status_bits safety_status_bits output_bit_registers0_to_31 "
        "output_bit_registers32_to_63 input_bit_registers0_to_31 input_bit_registers32_to_63"
    ),
    "VECTOR6INT32": "joint_mode",
    "UINT8": "analog_io_types tool_analog_input_types",
}
_OUTPUT_TYPES = {name: t for t, names in _OUTPUTS.items() for name in names.split()}
_REGISTER = re.compile(r"^(input|output)_(int|double|bit)_register_(\d+)$")
_REG_TYPE = {"int": "INT32", "double": "DOUBLE", "bit": "BOOL"}
_INPUT_TYPES = {"external_force_torque": "VECTOR6D", "speed_slider_mask": "UINT32", "speed_slider_fraction": "DOUBLE"}


def _register_type(name: str) -> str | None:
    m = _REGISTER.match(name)
    if m is None:
        return None
    n = int(m.group(3))
    limit = 128 if m.group(2) == "bit" else 48
    if m.group(2) == "bit" and n < 64:
        return None  # bits 0–63 are general purpose I/O words, not registers
    return _REG_TYPE[m.group(2)] if n < limit else None


def output_type(name: str) -> str | None:
    """RTDE type of an output variable, or None (the controller answers NOT_FOUND)."""
    return _OUTPUT_TYPES.get(name) or _register_type(name)


def input_type(name: str) -> str | None:
    """RTDE type of an input variable (only registers and a few inputs), or None."""
    if name.startswith("input_"):
        return _register_type(name)
    return _INPUT_TYPES.get(name)


def package(kind: int, payload: bytes = b"") -> bytes:
    """One RTDE package."""
    return HEADER.pack(HEADER.size + len(payload), kind) + payload
