"""scanning: visit the planned viewpoints in order; at each, move, settle, capture, and hand
the image to the classifier in the background while the robot moves on (pipelining)."""

from __future__ import annotations

import numpy as np

from cellctl.bus import topics
from cellctl.errors import WorkerFailed
from cellctl.messages import (
    CaptureReply,
    CaptureRequest,
    ClassifyReply,
    ClassifyRequest,
    MoveReply,
    MoveRequest,
    PoseMsg,
    ViewpointResult,
)
from cellctl.recording import foxglove
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import Step
from cellctl.supervisor.steps.board_mask import mask_board
from cellctl.supervisor.steps.identifying import captured_image


def classify_image(run: StepRun, index: int, image: bytes, fmt: str, surface: str) -> ClassifyReply:
    reply, _ = run.call(
        "classifier", "classify", ClassifyRequest(surface=surface, format=fmt), ClassifyReply, payload=image
    )
    return reply


class Scanning(Step):
    NAME = "scanning"
    OUTCOMES = ("succeeded", "failed")
    DESCRIPTION = "move → settle → capture per viewpoint; classification overlaps the next move"
    READS = ("plan", "params", "mode", "next_viewpoint", "viewpoints", "classifications")
    WRITES = ("viewpoints", "classifications", "next_viewpoint")

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        plan = ctx.plan
        assert plan is not None  # READS plan: the loader checked a step wrote it
        surface = ctx.surface
        collect = ctx.mode == "collect"
        settle = ctx.cfg.robot.settle_s
        perturb = ctx.params.perturb_m if collect else 0.0
        seed = ctx.params.seed
        bin_type = ctx.catalog.get(ctx.bin_type) if ctx.catalog is not None and ctx.bin_type else None
        # classifications run on past a Hold (the scanning activation is cancelled, the cycle is not)
        background = run.detached("classify_background")
        st = ctx.current_station()
        # whole-bin cycle: each view says where it was taken (viewpoint indices repeat across plans)
        where = {"station": st.station, "surface": surface} if st is not None else {}
        for k in range(ctx.next_viewpoint, len(plan.viewpoints)):
            vp = plan.viewpoints[k]
            if perturb > 0:
                # data collection: a seeded random offset of the camera position per viewpoint
                rng = np.random.default_rng([seed, vp.index])
                T = vp.camera_pose.matrix()
                T[:3, 3] += rng.uniform(-perturb, perturb, 3)
                move = MoveRequest(camera_pose=PoseMsg.from_matrix(T), settle_s=settle)
            else:
                move = MoveRequest(joints=vp.joints, settle_s=settle)
            try:
                moved, _ = run.call("robot", "move", move, MoveReply)
            except WorkerFailed as err:
                again = None
                if st is not None and move.joints is not None:
                    # whole-bin cycle: the planned joints may touch the bin where the park's error is not
                    # measured (a carried-over station); the camera pose lets the arm pick another IK solution
                    try:
                        again, _ = run.call(
                            "robot", "move", MoveRequest(camera_pose=vp.camera_pose, settle_s=settle), MoveReply
                        )
                        run.event(
                            "info",
                            f"station {st.station} {surface} viewpoint {vp.index}: joints refused "
                            f"({err}); reached by its camera pose",
                        )
                    except WorkerFailed as err2:
                        err = WorkerFailed(f"{err}; by its camera pose: {err2}", role="robot")
                if again is None:
                    # One refused viewpoint (e.g. newly in collision after adjustment) costs coverage,
                    # not the cycle; hangs and missing workers still abort.
                    ctx.viewpoints.append(
                        ViewpointResult(index=vp.index, camera_pose=vp.camera_pose, error=str(err), **where)
                    )
                    ctx.next_viewpoint = k + 1
                    continue
                moved = again
            cap, image = run.call("camera", "capture", CaptureRequest(format="png"), CaptureReply)
            data = captured_image(cap, image)
            ctx.log.image(topics.CAMERA_IMAGE, data, cap.format, "camera")
            ctx.log.write_json(
                topics.CAMERA_POSE, "foxglove.PoseInFrame", foxglove.pose_in_frame("base", moved.camera_pose.matrix())
            )
            result = ViewpointResult(index=vp.index, camera_pose=moved.camera_pose, **where)
            if collect:
                from cellctl.classify.collect import store_image

                store_image(ctx.cfg, ctx.params.as_params(), surface, ctx.cycle_id, vp.index, data)
                result = result.model_copy(update={"label": ctx.params.label})
            else:
                image = data
                if bin_type is not None and ctx.T_base_bin is not None:
                    image = mask_board(data, bin_type, ctx.T_base_bin, moved.camera_pose.matrix(), cap.intrinsics)
                ctx.classifications[len(ctx.viewpoints)] = ctx.pool.submit(
                    classify_image, background, vp.index, image, "png" if image is not data else cap.format, surface
                )
            ctx.viewpoints.append(result)
            ctx.next_viewpoint = k + 1
        mine = [v for v in ctx.viewpoints if (v.station, v.surface) == (where.get("station"), where.get("surface"))]
        if not any(v.error is None for v in mine):
            first = mine[0].error if mine else "the plan has none"
            at = f" at station {st.station} ({surface})" if st is not None else ""
            raise WorkerFailed(
                f"robot reached none of the {len(plan.viewpoints)} planned viewpoints{at} (first: {first})",
                role="robot",
            )
        return "succeeded"
