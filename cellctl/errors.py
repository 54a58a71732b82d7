"""The one exception family of cellctl.

Every error raised on purpose by cellctl derives from :class:`CellError`, and its message
names the offending value and what was expected::

    CellError
    ├── ConfigError            a config/catalog/state-machine file is wrong
    ├── ProtocolError          a wire payload cannot be decoded or is the wrong type/version
    ├── TransitionRejected     a PackML command is not allowed in the current state
    ├── WorkerError            a worker request failed
    │   ├── WorkerUnavailable  no worker answered (0 replies: nobody serves the key)
    │   ├── WorkerTimeout      a worker is there but did not answer in time (hung)
    │   └── WorkerFailed       the worker answered with an error reply
    ├── RobotError             a robot op was refused (unreachable target, collision, …)
    ├── CameraError            a capture failed (not connected, bad frame, …)
    ├── IdentificationError    no bin could be identified in an image
    ├── PlanningError          the offline planner cannot produce a plan
    ├── PlanCacheError         a plan file is missing, damaged or foreign
    ├── ClassifierError        a classifier model or image is unusable
    └── RecordingError         a log file cannot be written or read
"""

from __future__ import annotations

__all__ = [
    "CameraError",
    "CellError",
    "ClassifierError",
    "ConfigError",
    "IdentificationError",
    "PlanCacheError",
    "PlanningError",
    "ProtocolError",
    "RecordingError",
    "RobotError",
    "TransitionRejected",
    "UndeclaredAccess",
    "WorkerError",
    "WorkerFailed",
    "WorkerTimeout",
    "WorkerUnavailable",
]


class CellError(Exception):
    """Base of every error cellctl raises on purpose."""


class ConfigError(CellError):
    """A configuration, catalog or state-machine definition is invalid."""


class UndeclaredAccess(CellError):
    """A cycle step read or wrote a blackboard field its declaration does not name (the message names both)."""


class ProtocolError(CellError):
    """A payload on the bus is malformed, of the wrong type or of an unknown version."""


class TransitionRejected(CellError):
    """A PackML command is not allowed in the current state."""

    def __init__(self, command: str, state: str, allowed: list[str]) -> None:
        self.command = command
        self.state = state
        self.allowed = allowed
        super().__init__(f"command {command!r} is not allowed in state {state!r}; allowed: {sorted(allowed) or 'none'}")


class WorkerError(CellError):
    """A request to a worker did not produce a usable reply."""

    def __init__(self, message: str, *, role: str | None = None, op: str | None = None) -> None:
        self.role = role
        self.op = op
        super().__init__(message)


class WorkerUnavailable(WorkerError):
    """Nobody serves the key: zero replies came back."""


class WorkerTimeout(WorkerError):
    """A worker serves the key but did not reply within the timeout (hung or overloaded)."""


class WorkerFailed(WorkerError):
    """The worker replied with an error."""


class RobotError(CellError):
    """A robot operation was refused or failed."""


class CameraError(CellError):
    """A camera capture failed."""


class IdentificationError(CellError):
    """The bin could not be identified from the image (the message says why)."""


class PlanningError(CellError):
    """The offline planner cannot produce a plan (the message says which stage and why)."""


class PlanCacheError(CellError):
    """A plan file is missing, damaged or was made for something else."""


class ClassifierError(CellError):
    """A classifier model, image or dataset is unusable."""


class RecordingError(CellError):
    """A cycle log or the cycle index cannot be written or read."""
