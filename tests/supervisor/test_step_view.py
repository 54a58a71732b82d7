"""A step sees the blackboard through a view that refuses what it did not declare (issue 33 item 2)."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.errors import ConfigError, UndeclaredAccess
from cellctl.messages import PlanLookupReply, ViewpointResult
from cellctl.supervisor.context import INITIAL_CONTEXT
from cellctl.supervisor.context.identity import Identity
from cellctl.supervisor.context.scan import Scan
from cellctl.supervisor.definition import load_cycle
from cellctl.supervisor.registry import STEP_IO
from cellctl.supervisor.steps import STEPS, Step
from cellctl.supervisor.steps._base import AT_STATION
from tests.supervisor._scripted import ScriptedRun, context


def _step(name: str, body, *, reads=(), consults=(), writes=()) -> Step:
    """A step named ``name`` whose work is ``body(run.ctx)``, with the given declaration."""

    def execute(self, run) -> str:
        body(run.ctx)
        return "succeeded"

    cls = type(
        name.title(),
        (Step,),
        {
            "NAME": name,
            "OUTCOMES": ("succeeded",),
            "READS": tuple(reads),
            "CONSULTS": tuple(consults),
            "WRITES": tuple(writes),
            "execute": execute,
        },
    )
    return cls()


def _run(cfg, **records) -> ScriptedRun:
    return ScriptedRun(context(cfg, **records), {})


def test_an_undeclared_write_fails_naming_the_step_and_the_field(cfg) -> None:
    def body(ctx):
        ctx.scan.plan = PlanLookupReply(hit=True, plan_id="p")

    run = _run(cfg)
    with pytest.raises(UndeclaredAccess, match=r"step 'sneaky' writes scan\.plan, which it does not declare in WRITES"):
        _step("sneaky", body)(run)
    assert run.ctx.scan.plan is None  # nothing written


def test_an_undeclared_read_fails_naming_the_step_and_the_field(cfg) -> None:
    run = _run(cfg, identity=Identity(bin_type="case_study"))
    with pytest.raises(UndeclaredAccess, match=r"step 'peek' reads identity\.bin_type, which it does not declare"):
        _step("peek", lambda ctx: ctx.identity.bin_type)(run)


def test_declared_reads_consults_and_writes_pass_and_reach_the_context(cfg) -> None:
    seen = []

    def body(ctx):
        seen.append((ctx.identity.bin_type, ctx.identity.T_base_bin))  # read, consulted (None)
        ctx.scan.plan = PlanLookupReply(hit=True, plan_id="p")
        seen.append(ctx.scan.plan.plan_id)  # its own write, read back
        ctx.scan.viewpoints.append(ViewpointResult(index=0))  # read and written: the list itself

    run = _run(cfg, identity=Identity(bin_type="case_study"))
    step = _step(
        "fine",
        body,
        reads=("identity.bin_type", "scan.viewpoints"),
        consults=("identity.T_base_bin",),
        writes=("scan.plan", "scan.viewpoints"),
    )
    assert step(run) == "succeeded"
    assert seen == [("case_study", None), "p"]
    assert run.ctx.scan.plan is not None and [v.index for v in run.ctx.scan.viewpoints] == [0]


def test_mutating_a_field_only_read_is_an_undeclared_write(cfg) -> None:
    run = _run(cfg, scan=Scan(viewpoints=[ViewpointResult(index=0)]))
    step = _step(
        "appender", lambda ctx: ctx.scan.viewpoints.append(ViewpointResult(index=1)), reads=("scan.viewpoints",)
    )
    with pytest.raises(UndeclaredAccess, match=r"step 'appender' changes scan\.viewpoints"):
        step(run)
    assert len(run.ctx.scan.viewpoints) == 1
    popper = _step("popper", lambda ctx: ctx.stations.bin_poses.pop(0, None), reads=("stations.bin_poses",))
    with pytest.raises(UndeclaredAccess, match=r"step 'popper' changes stations\.bin_poses"):
        popper(run)


def test_what_a_property_or_method_reads_counts_as_the_steps_read(cfg) -> None:
    """``ctx.surface`` in a whole-bin cycle asks the station loop where it is: the step must consult it."""
    cfg.planner.whole.enabled = True
    run = _run(cfg)
    with pytest.raises(UndeclaredAccess, match=r"step 'where' reads stations\.planned"):
        _step("where", lambda ctx: ctx.surface)(run)
    assert _step("there", lambda ctx: ctx.surface, consults=AT_STATION)(run) == "succeeded"


def test_the_records_and_the_start_inputs_cannot_be_replaced(cfg) -> None:
    def body(ctx):
        ctx.mode = "commission"

    with pytest.raises(UndeclaredAccess, match=r"step 'usurper' replaces the cycle's mode"):
        _step("usurper", body)(_run(cfg))


def test_a_declaration_of_an_unknown_field_is_refused_at_definition() -> None:
    with pytest.raises(ConfigError, match=r"step 'typo' declares READS \['scan\.plans'\], not blackboard fields"):
        _step("typo", lambda ctx: None, reads=("scan.plans",))


def test_every_shipped_step_declares_blackboard_fields_only() -> None:
    for name, step in STEPS.items():
        assert step.READS or step.WRITES or step.CONSULTS, name


def test_the_loader_refuses_a_step_reading_what_no_earlier_step_writes(tmp_path: Path) -> None:
    """With the steps' true reads: reporting right after identifying finds no plan and no verdict."""
    path = tmp_path / "cycle.yaml"
    path.write_text(
        "initial: approaching\nstates:\n"
        "  approaching: {step: approaching, on: {succeeded: identifying, failed: {exit: abort}}}\n"
        "  identifying: {step: identifying, on: {succeeded: reporting, retry: approaching, failed: {exit: abort}}}\n"
        "  reporting: {step: reporting, on: {succeeded: {exit: complete}, failed: {exit: abort}}}\n"
    )
    outcomes = {k: v.OUTCOMES for k, v in STEPS.items()}
    with pytest.raises(
        ConfigError, match=r"states\.reporting: step 'reporting' reads \['result\.verdict', 'scan\.plan'\]"
    ):
        load_cycle(path, outcomes, STEP_IO, INITIAL_CONTEXT)
