"""classifying: gather the classifier replies, re-look at uncertain viewpoints, decide the verdict.

Re-look (``classifier.relook``): a viewpoint whose decision is uncertain is imaged again, in
the same cycle, from a nearby pose — the camera swings by ``glance_deg`` about the point it
looks at and shifts ``offset_m`` sideways (:func:`cellctl.classify.heatmap.relook_pose`), so a
highlight or shadow that made the view ambiguous moves. Up to ``max_views`` re-looks per
cycle, the most ambiguous views first (closest to the threshold); a re-look that is itself
uncertain may be re-looked again while the budget lasts. Each re-look is one more
:class:`~cellctl.messages.ViewpointResult` (``relook_of`` = the viewpoint's index); its
evidence is fused with the original's: here by averaging the views' logits for the
any-view rule, in reporting per face.

Confirming a dirty view (``classifier.relook.confirm_dirty``, default in whole-bin cycles): a
view called dirty *with certainty* is re-looked once too (after the uncertain ones, within the
same budget); a re-look that is certain clean overrules it, any other keeps it dirty. Reason: the
any-view rule over a whole-bin cycle's ~100 views turns a 0.7 % false-dirty rate per view (the
shipped models' test figure) into a false-dirty bin in about half of the clean cycles (seen in the
demo: a bright rim in an internal view), while a dirt patch seen from 3 cm and 12° away stays dirty.

The verdict set here is the any-view rule; with ``classifier.verdict.rule: faces`` reporting
replaces it by the per-face verdict.
"""

from __future__ import annotations

import concurrent.futures
import math
from typing import cast

from cellctl.bus import topics
from cellctl.errors import ClassifierError, WorkerError, WorkerFailed
from cellctl.messages import (
    CaptureReply,
    CaptureRequest,
    ClassifyReply,
    MoveReply,
    MoveRequest,
    PoseMsg,
    ViewpointResult,
)
from cellctl.supervisor.context import CycleContext, StepRun
from cellctl.supervisor.steps._base import AT_STATION, Step

RELOOK_POSES = 4
"""Re-look poses per viewpoint (:func:`~cellctl.classify.heatmap.relook_pose` swings about ±x, ±y)."""


def _logit(p: float) -> float:
    q = min(max(p, 1e-6), 1 - 1e-6)
    return math.log(q / (1 - q))


def _mean_label(vs: list[ViewpointResult]) -> str:
    """The views' mean logit against the threshold estimated as logit 0 (p 0.5) clipped into what
    the labels allow (above every clean view's logit, at most every dirty view's).

    "The label of the view nearest the mean" is a coin flip for two views that disagree (the mean is
    halfway between them): a clean re-look at p 0.002 lost to its uncertain original at p 0.78.
    """
    logits = [_logit(v.p_dirty) for v in vs]  # type: ignore[arg-type]
    clean = [x for x, v in zip(logits, vs, strict=True) if v.label == "clean"]
    dirty = [x for x, v in zip(logits, vs, strict=True) if v.label == "dirty"]
    if not clean or not dirty:
        return vs[0].label  # type: ignore[return-value]
    t = min(max(0.0, max(clean)), min(dirty))
    return "dirty" if sum(logits) / len(logits) >= t else "clean"


def view_key(v: ViewpointResult) -> tuple[int | None, str | None, int]:
    """Which planned viewpoint a view is of: (station, surface, index); station and surface are None
    in a single-station cycle (indices repeat across a whole-bin cycle's plans)."""
    return (v.station, v.surface, v.index)


def with_reply(v: ViewpointResult, reply: ClassifyReply) -> ViewpointResult:
    """The viewpoint result updated with a ClassifyReply's decision and scores."""
    return v.model_copy(
        update={
            "label": reply.label,
            "p_dirty": reply.p_dirty,
            "uncertain": reply.uncertain,
            "p_supervised": reply.p_supervised,
            "anomaly_z": reply.anomaly_z,
            "model_id": reply.model_id,
            "heatmap": reply.heatmap,
            "heat_grid": reply.heat_grid,
            "decided_by": reply.decided_by,
            # the scan's own reason (the plan's set has no reference for the viewpoint) unless the worker has one
            "reference_reason": reply.reference_reason or v.reference_reason,
        }
    )


def record_heat(run: StepRun, reply: ClassifyReply) -> None:
    """The reply's heat map as a colour image on :data:`~cellctl.bus.topics.HEATMAP`."""
    if not reply.heatmap or not reply.heat_grid:
        return
    from cellctl.classify.heatmap import decode_heat, heat_png

    cam = run.ctx.cfg.camera
    w = 256  # the heat map has 16 patches a side: a small image shows it all
    h = max(16, round(w * cam.height / cam.width))
    run.ctx.log.image(topics.HEATMAP, heat_png(decode_heat(reply.heatmap, reply.heat_grid), w, h), "png", "camera")


class Classifying(Step):
    NAME = "classifying"
    OUTCOMES = ("succeeded", "failed")
    DESCRIPTION = "wait for classifications; re-look at uncertain viewpoints; verdict = dirty if any view is dirty"
    READS = ("scan.classifications", "scan.viewpoints", "identity.bin_type", "identity.T_base_bin")
    CONSULTS = AT_STATION
    WRITES = ("scan.viewpoints", "scan.classifications", "result.verdict")

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        timeout = ctx.cfg.supervisor.timeouts.classify * max(1, len(ctx.scan.classifications))
        for i, fut in sorted(ctx.scan.classifications.items()):
            run.checkpoint()
            try:
                reply = fut.result(timeout=timeout)
            except concurrent.futures.TimeoutError as err:
                raise ClassifierError(
                    f"classification of viewpoint {ctx.scan.viewpoints[i].index} not back in {timeout:g} s"
                ) from err
            except WorkerError as err:
                ctx.scan.viewpoints[i] = ctx.scan.viewpoints[i].model_copy(update={"error": str(err)})
                raise
            ctx.scan.viewpoints[i] = with_reply(ctx.scan.viewpoints[i], reply)
            record_heat(run, reply)
        ctx.scan.classifications.clear()
        if ctx.mode == "collect":
            ctx.result.verdict = None
            return "succeeded"
        n_relook = self._relook(run)
        labels = self._view_labels(ctx.scan.viewpoints, self._confirming(ctx))
        if not labels:
            raise ClassifierError("no viewpoint was classified")
        ctx.result.verdict = "dirty" if "dirty" in labels.values() else "clean"
        n_unc = sum(v.uncertain for v in ctx.scan.viewpoints if v.relook_of is None)
        run.event(
            "info",
            f"verdict {ctx.result.verdict}: {list(labels.values()).count('dirty')}/{len(labels)} viewpoints dirty, "
            f"{n_unc} uncertain, {n_relook} re-looks",
        )
        return "succeeded"

    @staticmethod
    def _confirmed_dirty(viewpoints: list[ViewpointResult]) -> bool:
        """Some certain-dirty view was re-looked and not overruled by a certain-clean re-look."""
        groups: dict[tuple[int | None, str | None, int], list[ViewpointResult]] = {}
        for v in viewpoints:
            if v.label is not None:
                groups.setdefault(view_key(v), []).append(v)
        return any(
            len(vs) > 1
            and vs[0].relook_of is None
            and vs[0].label == "dirty"
            and not vs[0].uncertain
            and not any(w.label == "clean" and not w.uncertain for w in vs[1:])
            for vs in groups.values()
        )

    @staticmethod
    def _confirming(ctx: CycleContext) -> bool:
        mode = ctx.cfg.classifier.relook.confirm_dirty
        return mode == "on" or (mode == "whole_bin" and ctx.whole)

    @staticmethod
    def _view_labels(
        viewpoints: list[ViewpointResult], confirm: bool = False
    ) -> dict[tuple[int | None, str | None, int], str]:
        """Label per viewpoint index, a re-looked viewpoint's views fused (mean logit vs its threshold).

        The threshold is not on the wire; a view's own label and ``p_dirty`` bound it: fused
        views keep the label of the one whose logit is nearest the mean. With ``confirm`` (whole-bin
        cycles by default): a certain-dirty view re-looked to confirm it is clean only if a re-look
        is certain clean, and disagreeing views are decided by :func:`_mean_label`.
        """
        groups: dict[tuple[int | None, str | None, int], list[ViewpointResult]] = {}
        for v in viewpoints:
            if v.label is not None and v.p_dirty is not None:
                groups.setdefault(view_key(v), []).append(v)
        out: dict[tuple[int | None, str | None, int], str] = {}
        for idx, vs in groups.items():
            if len(vs) == 1:
                out[idx] = cast(str, vs[0].label)  # grouped only when labelled
                continue
            first = vs[0]
            if confirm and first.relook_of is None and first.label == "dirty" and not first.uncertain:
                overruled = any(w.label == "clean" and not w.uncertain for w in vs[1:])
                out[idx] = "clean" if overruled else "dirty"
                continue
            if confirm:
                out[idx] = _mean_label(vs)
                continue
            mean = sum(_logit(cast(float, v.p_dirty)) for v in vs) / len(vs)
            out[idx] = cast(str, min(vs, key=lambda v: abs(_logit(cast(float, v.p_dirty)) - mean)).label)
        return out

    def _relook(self, run: StepRun) -> int:
        """Re-image uncertain (and, confirming, certain-dirty) viewpoints from nearby poses (module doc); how many."""
        ctx = run.ctx
        rc = ctx.cfg.classifier.relook
        if rc.max_views <= 0:
            return 0
        from cellctl.classify.heatmap import relook_pose
        from cellctl.supervisor.steps.identifying import captured_image
        from cellctl.supervisor.steps.scanning import classifier_input, classify_image

        confirming = self._confirming(ctx)
        st = ctx.stations.current_station()
        # a re-look moves the arm by a camera pose in this base frame: only this station's views, this surface
        here = (st.station, ctx.surface) if st is not None else (None, None)
        done = 0
        tried: dict[tuple[int | None, str | None, int], int] = {}
        seen = {view_key(w) for w in ctx.scan.viewpoints if w.relook_of is not None and w.error is None}
        while done < rc.max_views:
            # once one dirty view is confirmed the bin is dirty: more confirmations would only cost moves
            confirm = confirming and not self._confirmed_dirty(ctx.scan.viewpoints)
            pending = [
                v
                for v in ctx.scan.viewpoints
                # uncertain, or certain dirty and not yet confirmed (see module doc)
                if (v.uncertain or (confirm and v.relook_of is None and v.label == "dirty" and view_key(v) not in seen))
                and v.camera_pose is not None
                and v.error is None
                and v.p_dirty is not None
                and (v.station, v.surface) == here
                # a refused re-look pose costs no budget, but each viewpoint has RELOOK_POSES of them
                and tried.get(view_key(v), 0) < RELOOK_POSES
                # the latest view of its viewpoint decides whether to look again (a refused move is no view)
                and v is [w for w in ctx.scan.viewpoints if view_key(w) == view_key(v) and w.error is None][-1]
            ]
            if not pending:
                break
            v = min(pending, key=lambda w: (not w.uncertain, abs(_logit(w.p_dirty))))  # type: ignore[arg-type]
            run.checkpoint()
            k = tried.get(view_key(v), 0)
            tried[view_key(v)] = k + 1
            base = next(w for w in ctx.scan.viewpoints if view_key(w) == view_key(v) and w.relook_of is None)
            T = relook_pose(base.camera_pose.matrix(), k, rc.offset_m, rc.glance_deg, rc.depth_m)  # type: ignore[union-attr]
            try:
                moved, _ = run.call(
                    "robot",
                    "move",
                    MoveRequest(camera_pose=PoseMsg.from_matrix(T), settle_s=ctx.cfg.robot.settle_s),
                    MoveReply,
                )
            except WorkerFailed as err:
                ctx.scan.viewpoints.append(
                    ViewpointResult(
                        index=v.index,
                        camera_pose=PoseMsg.from_matrix(T),
                        error=str(err),
                        relook_of=v.index,
                        station=v.station,
                        surface=v.surface,
                    )
                )
                # near a rim a swing can touch the bin where the planned pose did not: the next pose
                # swings the other way; left unconfirmed, one certain-dirty view would decide the bin
                continue
            done += 1
            seen.add(view_key(v))
            cap, image = run.call("camera", "capture", CaptureRequest(format="png"), CaptureReply)
            data = captured_image(cap, image)
            ctx.log.image(topics.CAMERA_IMAGE, data, cap.format, "camera")
            img, fmt = classifier_input(run, data, cap.format, moved.camera_pose.matrix(), cap.intrinsics)
            reply = classify_image(run, v.index, img, fmt, ctx.surface)
            record_heat(run, reply)
            ctx.scan.viewpoints.append(
                with_reply(
                    ViewpointResult(
                        index=v.index,
                        camera_pose=moved.camera_pose,
                        relook_of=v.index,
                        station=v.station,
                        surface=v.surface,
                    ),
                    reply,
                )
            )
        return done
