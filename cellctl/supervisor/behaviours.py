"""The PackML behaviours: the work of the acting states outside Execute, one class each.

``states/packml.yaml`` names a behaviour per acting state; only those registered here with
:func:`behaviour` exist (:data:`BEHAVIOURS` is derived from the registry). A behaviour runs
on an activation thread; it raises a CellError to fail (the dispatcher then aborts).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar, Protocol, TypeVar

from cellctl.errors import WorkerUnavailable
from cellctl.messages import CycleOutcome
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.cycles import CycleKeeper

__all__ = ["BEHAVIOURS", "BEHAVIOUR_CLASSES", "Behaviour", "BehaviourHost", "behaviour"]


class BehaviourHost(Protocol):
    """What behaviours need of the supervisor."""

    cycles: CycleKeeper

    def missing_workers(self) -> list[str]:
        """Required roles with no live token, asked from the router now."""
        ...

    def reset_cell(self) -> None:
        """Forget the last error and the finished cycle."""
        ...


class Behaviour(ABC):
    """The work of one PackML acting state."""

    NAME: ClassVar[str]
    DESCRIPTION: ClassVar[str] = ""

    @abstractmethod
    def execute(self, run: StepRun, cell: BehaviourHost) -> None:
        """Do the work; return to signal State Complete, raise a CellError to fail."""


BEHAVIOUR_CLASSES: dict[str, type[Behaviour]] = {}
"""Behaviour name → class, filled by :func:`behaviour`."""

B = TypeVar("B", bound=type[Behaviour])


def behaviour(cls: B) -> B:
    """Register a behaviour class under its ``NAME`` (once)."""
    if cls.NAME in BEHAVIOUR_CLASSES:
        raise ValueError(f"behaviour {cls.NAME!r} is registered twice ({BEHAVIOUR_CLASSES[cls.NAME].__name__})")
    BEHAVIOUR_CLASSES[cls.NAME] = cls
    return cls


@behaviour
class ClearFaults(Behaviour):
    NAME = "clear_faults"
    DESCRIPTION = "Clearing: nothing to clear in software; the operator cleared the cause"

    def execute(self, run: StepRun, cell: BehaviourHost) -> None:
        return None


@behaviour
class ResetCell(Behaviour):
    NAME = "reset_cell"
    DESCRIPTION = "Resetting: forget the last error and the finished cycle"

    def execute(self, run: StepRun, cell: BehaviourHost) -> None:
        cell.reset_cell()


@behaviour
class OpenCycle(Behaviour):
    NAME = "open_cycle"
    DESCRIPTION = "Starting: every required worker alive (asked from the router), else fail"

    def execute(self, run: StepRun, cell: BehaviourHost) -> None:
        missing = cell.missing_workers()
        if missing:
            raise WorkerUnavailable(f"no {', '.join(missing)} worker alive (liveliness); start the workers and retry")


@behaviour
class ResumeCheck(Behaviour):
    NAME = "resume_check"
    DESCRIPTION = "Unholding/Unsuspending: every required worker alive again, else fail"

    def execute(self, run: StepRun, cell: BehaviourHost) -> None:
        missing = cell.missing_workers()
        if missing:
            raise WorkerUnavailable(f"cannot resume: no {', '.join(missing)} worker alive")


@behaviour
class PauseCycle(Behaviour):
    NAME = "pause_cycle"
    DESCRIPTION = "Holding/Suspending: stop the robot, keep the cycle open"

    def execute(self, run: StepRun, cell: BehaviourHost) -> None:
        cell.cycles.stop_robot("hold")


@behaviour
class StopCycle(Behaviour):
    NAME = "stop_cycle"
    DESCRIPTION = "Stopping: stop the robot, close the cycle as aborted"

    def execute(self, run: StepRun, cell: BehaviourHost) -> None:
        cell.cycles.stop_robot("stop")
        cell.cycles.finalize(CycleOutcome.aborted)


@behaviour
class AbortCycle(Behaviour):
    NAME = "abort_cycle"
    DESCRIPTION = "Aborting: stop the robot, close the cycle as aborted (or failed, when it failed)"

    def execute(self, run: StepRun, cell: BehaviourHost) -> None:
        cell.cycles.stop_robot("abort")
        cell.cycles.finalize(CycleOutcome.aborted)


@behaviour
class FinishCycle(Behaviour):
    NAME = "finish_cycle"
    DESCRIPTION = "Completing: close the cycle with its outcome (aborted when Complete was commanded early)"

    def execute(self, run: StepRun, cell: BehaviourHost) -> None:
        ctx = cell.cycles.ctx
        if ctx is not None and ctx.result.outcome is None:
            ctx.result.outcome = CycleOutcome.aborted
            ctx.result.reason = ctx.result.reason or "completed by command before the cycle ended"
        cell.cycles.finalize(CycleOutcome.completed)


BEHAVIOURS: tuple[str, ...] = tuple(BEHAVIOUR_CLASSES)
"""PackML behaviours this code provides; ``states/packml.yaml`` may name only these."""
