"""A cycle resolves the reference set of a plan once, into its blackboard (no module-level cache)."""

from __future__ import annotations

import numpy as np

from cellctl.messages import PlanLookupReply
from cellctl.supervisor.context.identity import Identity
from cellctl.supervisor.context.scan import Scan
from cellctl.supervisor.steps import references
from tests.supervisor._scripted import context


def test_the_set_of_a_plan_is_read_once_per_cycle(cfg, monkeypatch) -> None:
    asked: list[str] = []

    def latest_set(root, bin_type, plan_id):
        asked.append(plan_id)
        return None

    monkeypatch.setattr(references, "latest_set", latest_set)
    ctx = context(
        cfg,
        identity=Identity(bin_type="case_study", T_base_bin=np.eye(4)),
        scan=Scan(plan=PlanLookupReply(hit=True, plan_id="plan-1")),
    )
    assert [references.reference_state(ctx) for _ in range(3)] == [None, None, None]
    ctx.scan.plan = PlanLookupReply(hit=True, plan_id="plan-2")  # the next station's plan
    references.reference_state(ctx)
    references.reference_state(ctx)
    assert asked == ["plan-1", "plan-2"] and ctx.refs.sets == {"plan-1": None, "plan-2": None}
    assert not any(k.isupper() and isinstance(v, dict) for k, v in vars(references).items())  # no global cache
