"""Loading a state-machine YAML that does not match the code fails at start with a clear error."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.config import project_root
from cellctl.errors import ConfigError
from cellctl.supervisor.definition import load_cycle, load_packml, mermaid
from cellctl.supervisor.steps import STEPS
from cellctl.supervisor.supervisor import BEHAVIOURS, load_definitions

STEP_OUTCOMES = {k: v.OUTCOMES for k, v in STEPS.items()}


def _edit(tmp_path: Path, name: str, old: str, new: str) -> Path:
    text = (project_root() / "states" / name).read_text()
    assert old in text
    p = tmp_path / name
    p.write_text(text.replace(old, new, 1))
    return p


def test_shipped_machines_load() -> None:
    packml, cycle = load_definitions()
    assert len(packml.states) == 17
    assert cycle.initial == "approaching"


@pytest.mark.parametrize(
    "old, new, message",
    [
        (
            "behaviour: clear_faults",
            "behaviour: wipe_floor",
            "behaviour 'wipe_floor' of state 'Clearing' is not provided",
        ),
        ("{name: Idle,         code: 4,", "{name: Idle,         code: 5,", "has code 5; TR88 says 4"),
        ("  - {name: Held,         code: 11, kind: wait}\n", "", "TR88 states missing: ['Held']"),
        ("{command: clear,", "{command: wipe,", "command 'wipe' is unknown"),
        ("  Holding: Held\n", "", "acting state 'Holding' has no state_complete"),
        ("initial: Stopped", "initial: Idle", "only 'Stopped' or 'Aborted'"),
    ],
)
def test_bad_packml_yaml_is_rejected(tmp_path: Path, old: str, new: str, message: str) -> None:
    path = _edit(tmp_path, "packml.yaml", old, new)
    with pytest.raises(ConfigError, match=None) as exc:
        load_packml(path, BEHAVIOURS)
    assert message in str(exc.value)
    assert str(path) in str(exc.value)


@pytest.mark.parametrize(
    "old, new, message",
    [
        ("step: scanning", "step: dancing", "step 'dancing' is not provided by the code"),
        ("      retry: approaching\n", "", "outcomes ['retry'] of step 'identifying' are not mapped"),
        ("      hit: scanning", "      hit: scanning\n      maybe: scanning", "outcome 'maybe' is not declared"),
        ("succeeded: classifying", "succeeded: polishing", "goes to unknown state 'polishing'"),
        ("      miss: replanning", "      miss: scanning", "states ['replanning'] cannot be reached"),
        (
            "failed: {exit: abort}\n  scanning",
            "failed: {exit: explode}\n  scanning",
            "must be {exit: complete|abort|hold}",
        ),
    ],
)
def test_bad_cycle_yaml_is_rejected(tmp_path: Path, old: str, new: str, message: str) -> None:
    path = _edit(tmp_path, "cycle.yaml", old, new)
    with pytest.raises(ConfigError) as exc:
        load_cycle(path, STEP_OUTCOMES)
    assert message in str(exc.value)


def test_mermaid_draws_both_machines() -> None:
    text = mermaid(*load_definitions())
    assert text.startswith("stateDiagram-v2")
    assert "Idle --> Starting: start" in text
    assert "state Execute {" in text and "checking_cache --> replanning: miss" in text


def test_step_rejects_undeclared_outcome() -> None:
    from cellctl.supervisor.context import CycleContext, StepRun
    from cellctl.supervisor.recorder import NullRecorder
    from cellctl.supervisor.steps import Step

    class Bad(Step):
        NAME = "bad"
        OUTCOMES = ("succeeded",)

        def execute(self, run):
            return "exploded"

    with pytest.raises(ValueError, match="outcome 'exploded' does not belong"):
        Bad()(StepRun(CycleContext(cycle_id="c", cfg=None, session=None, log=NullRecorder()), 1, "bad"))  # type: ignore[arg-type]
