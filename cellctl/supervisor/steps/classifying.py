"""classifying: gather the classifier replies and decide the verdict."""

from __future__ import annotations

import concurrent.futures

from cellctl.errors import ClassifierError, WorkerError
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import Step


class Classifying(Step):
    NAME = "classifying"
    OUTCOMES = ("succeeded", "failed")
    DESCRIPTION = "wait for outstanding classifications; verdict = dirty if any viewpoint is dirty"
    READS = ("classifications", "viewpoints", "mode")
    WRITES = ("viewpoints", "verdict")

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        timeout = ctx.cfg.supervisor.timeouts.classify * max(1, len(ctx.classifications))
        for i, fut in sorted(ctx.classifications.items()):
            run.checkpoint()
            try:
                reply = fut.result(timeout=timeout)
            except concurrent.futures.TimeoutError as err:
                raise ClassifierError(
                    f"classification of viewpoint {ctx.viewpoints[i].index} not back in {timeout:g} s"
                ) from err
            except WorkerError as err:
                ctx.viewpoints[i] = ctx.viewpoints[i].model_copy(update={"error": str(err)})
                raise
            ctx.viewpoints[i] = ctx.viewpoints[i].model_copy(
                update={"label": reply.label, "p_dirty": reply.p_dirty, "uncertain": reply.uncertain}
            )
        ctx.classifications.clear()
        if ctx.mode == "collect":
            ctx.verdict = None
            return "succeeded"
        labels = [v.label for v in ctx.viewpoints if v.label is not None]
        if not labels:
            raise ClassifierError("no viewpoint was classified")
        ctx.verdict = "dirty" if "dirty" in labels else "clean"
        n_unc = sum(v.uncertain for v in ctx.viewpoints)
        run.event(
            "info", f"verdict {ctx.verdict}: {labels.count('dirty')}/{len(labels)} viewpoints dirty, {n_unc} uncertain"
        )
        return "succeeded"
