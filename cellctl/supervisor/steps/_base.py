"""The step contract: a class per cycle state with declared outcomes."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

from cellctl.supervisor.context import StepRun

__all__ = ["Step"]


class Step(ABC):
    """One state of the inspection cycle.

    A step declares every outcome it can return in ``OUTCOMES``; ``states/cycle.yaml`` must
    map each of them. It declares the :class:`CycleContext` fields it ``READS`` and ``WRITES``;
    a field it only consults when set (``approach`` in approaching) is not a read. ``execute``
    runs on a step thread, never on the dispatcher; it raises a CellError to fail (the runner
    turns that into outcome ``failed`` with the reason).
    """

    NAME: ClassVar[str]
    OUTCOMES: ClassVar[tuple[str, ...]]
    DESCRIPTION: ClassVar[str] = ""
    READS: ClassVar[tuple[str, ...]] = ()
    """Blackboard fields this step needs set (FlexBE input keys); the loader checks a writer precedes it."""
    WRITES: ClassVar[tuple[str, ...]] = ()
    """Blackboard fields this step sets for the steps after it (output keys)."""

    @abstractmethod
    def execute(self, run: StepRun) -> str:
        """Do the step's work and return one of ``OUTCOMES``."""

    def __call__(self, run: StepRun) -> str:
        outcome = self.execute(run)
        if outcome not in self.OUTCOMES:
            raise ValueError(
                f"outcome {outcome!r} does not belong to the outcomes of step {self.NAME!r}: {self.OUTCOMES}"
            )
        return outcome
