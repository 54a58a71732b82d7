"""The inspection-cycle steps, one module per state of ``states/cycle.yaml``."""

from cellctl.supervisor.steps._base import Step
from cellctl.supervisor.steps.approaching import Approaching
from cellctl.supervisor.steps.checking_cache import CheckingCache
from cellctl.supervisor.steps.classifying import Classifying
from cellctl.supervisor.steps.identifying import Identifying
from cellctl.supervisor.steps.next_station import NextStation
from cellctl.supervisor.steps.references import References
from cellctl.supervisor.steps.replanning import Replanning
from cellctl.supervisor.steps.reporting import Reporting
from cellctl.supervisor.steps.scanning import Scanning
from cellctl.supervisor.steps.verifying import Verifying
from cellctl.supervisor.steps.washing import WashCheck, Washing, WashStation

STEPS: dict[str, type[Step]] = {
    s.NAME: s
    for s in (
        Approaching,
        Identifying,
        CheckingCache,
        Replanning,
        Scanning,
        Classifying,
        NextStation,
        References,
        Reporting,
        WashCheck,
        WashStation,
        Washing,
        Verifying,
    )
}
"""Step name → class; the cycle YAML may name only these."""

__all__ = ["STEPS", "Step"]
