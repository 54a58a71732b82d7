"""What the UR controller's RTDE words mean: robot and safety modes, the safety status bits, and
which of them is a fault (:func:`classify_fault`). Pure tables and functions, no ur-rtde import.
"""

from __future__ import annotations

from cellctl.messages import FaultCondition

__all__ = [
    "CONDITIONS",
    "FAULT_BITS",
    "PLAYING",
    "REDUCED",
    "ROBOT_MODES",
    "RTDE_VARIABLES",
    "RUNNING",
    "SAFETY_FLAGS",
    "SAFETY_MODES",
    "classify_fault",
    "condition_of",
]

ROBOT_MODES = {
    -1: "NO_CONTROLLER",
    0: "DISCONNECTED",
    1: "CONFIRM_SAFETY",
    2: "BOOTING",
    3: "POWER_OFF",
    4: "POWER_ON",
    5: "IDLE",
    6: "BACKDRIVE",
    7: "RUNNING",
    8: "UPDATING_FIRMWARE",
}
RUNNING = 7
PLAYING = 2
FAULT_BITS = (  # safety_status_bits (RTDE guide), most severe first
    ((1 << 5) | (1 << 6) | (1 << 7), "emergency stop"),
    (1 << 9, "safety fault"),
    (1 << 8, "safety violation"),
    (1 << 2, "protective stop"),
    (1 << 4, "safeguard stop"),
)
REDUCED = 1 << 1
SAFETY_MODES = {
    1: "NORMAL",
    2: "REDUCED",
    3: "PROTECTIVE_STOP",
    4: "RECOVERY",
    5: "SAFEGUARD_STOP",
    6: "SYSTEM_EMERGENCY_STOP",
    7: "ROBOT_EMERGENCY_STOP",
    8: "VIOLATION",
    9: "FAULT",
    10: "VALIDATE_JOINT_ID",
    11: "UNDEFINED_SAFETY_MODE",
    12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
    13: "SYSTEM_THREE_POSITION_ENABLING_STOP",
}
SAFETY_FLAGS = (  # safety_status_bits, bit -> name (RTDE guide)
    (0, "normal_mode"),
    (1, "reduced_mode"),
    (2, "protective_stopped"),
    (3, "recovery_mode"),
    (4, "safeguard_stopped"),
    (5, "system_emergency_stopped"),
    (6, "robot_emergency_stopped"),
    (7, "emergency_stopped"),
    (8, "violation"),
    (9, "fault"),
    (10, "stopped_due_to_safety"),
)
CONDITIONS: dict[str, FaultCondition] = {
    "emergency stop": "emergency_stop",
    "safety fault": "safety_fault",
    "safety violation": "safety_violation",
    "protective stop": "protective_stop",
    "safeguard stop": "safeguard_stop",
    "reduced mode": "reduced_mode",
}
RTDE_VARIABLES = [
    "timestamp",
    "actual_q",
    "actual_TCP_pose",
    "robot_mode",
    "safety_mode",
    "safety_status_bits",
    "runtime_state",
    "speed_scaling",
    "target_speed_fraction",
]


def classify_fault(safety_bits: int, robot_mode: int, reduced_is_fault: bool) -> str | None:
    """The fault a safety word and robot mode mean, or None when the arm may move."""
    for mask, name in FAULT_BITS:
        if safety_bits & mask:
            return name
    if reduced_is_fault and safety_bits & REDUCED:
        return "reduced mode"
    if robot_mode != RUNNING:
        return f"robot mode {ROBOT_MODES.get(robot_mode, robot_mode)} (not RUNNING)"
    return None


def condition_of(name: str) -> FaultCondition:
    """The typed condition of a :func:`classify_fault` name."""
    return CONDITIONS.get(name, "robot_mode")
