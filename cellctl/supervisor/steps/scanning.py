"""scanning: visit the planned viewpoints in order; at each, move, settle, capture, and hand
the image to the classifier in the background while the robot moves on (pipelining)."""

from __future__ import annotations

from typing import Any

import numpy as np

from cellctl.bus import topics
from cellctl.errors import WorkerFailed
from cellctl.images import MAX_IMAGE_PIXELS, ImageFormat
from cellctl.messages import (
    CaptureReply,
    CaptureRequest,
    ClassifyReference,
    ClassifyReply,
    ClassifyRequest,
    Intrinsics,
    MoveReply,
    MoveRequest,
    PoseMsg,
    ViewpointResult,
)
from cellctl.recording import foxglove
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import AT_STATION, Step
from cellctl.supervisor.steps.board_mask import mask_board
from cellctl.supervisor.steps.identifying import captured_image
from cellctl.supervisor.steps.references import reference_query, reference_state, store_reference
from cellctl.surface import Surface

NEAR_M = 0.02
"""Faces are clipped at this distance in front of the camera before they are drawn."""


def _clip_near(P: np.ndarray) -> np.ndarray:
    """Polygon ``P`` (k, 3), camera frame, clipped to z >= NEAR_M (Sutherland–Hodgman, one plane)."""
    out = []
    for a, b in zip(P, np.roll(P, -1, axis=0), strict=True):
        if a[2] >= NEAR_M:
            out.append(a)
        if (a[2] >= NEAR_M) != (b[2] >= NEAR_M):
            out.append(a + (b - a) * (NEAR_M - a[2]) / (b[2] - a[2]))
    return np.array(out).reshape(-1, 3)


def cabin_pixels(
    mesh: Any, T_base_bin: np.ndarray, T_base_cam: np.ndarray, intr: Intrinsics, scale: float = 0.25
) -> np.ndarray:
    """(H, W) bool at ``scale``: the pixels no face of the bin covers (the cabin past it)."""
    import cv2

    from cellctl.geometry.transforms import invert

    w, h = max(1, round(intr.width * scale)), max(1, round(intr.height * scale))
    K = intr.K() * np.array([[scale], [scale], [1.0]])
    T = invert(T_base_cam) @ np.asarray(T_base_bin)
    V = mesh.vertices @ T[:3, :3].T + T[:3, 3]
    tri = V[mesh.faces]  # (F, 3, 3)
    near = tri[:, :, 2] >= NEAR_M

    def pixels(P: np.ndarray) -> np.ndarray:
        px: np.ndarray = np.round(P[:, :2] / P[:, 2:3] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]).astype(np.int32)
        return px

    on = np.zeros((h, w), np.uint8)
    front = np.flatnonzero(near.all(axis=1))
    uv = tri[front, :, :2] / tri[front, :, 2:3] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    lo, hi = uv.min(axis=1), uv.max(axis=1)
    inside = (hi[:, 0] >= 0) & (lo[:, 0] < w) & (hi[:, 1] >= 0) & (lo[:, 1] < h)
    for f in front[inside]:  # coverage only: no depth order needed
        cv2.fillConvexPoly(on, pixels(tri[f]), 1)
    for f in np.flatnonzero(near.any(axis=1) & ~near.all(axis=1)):  # a face reaching behind the camera
        P = _clip_near(tri[f])
        if len(P) >= 3:
            cv2.fillConvexPoly(on, np.clip(pixels(P), -(1 << 20), 1 << 20), 1)
    off: np.ndarray = on == 0
    return off


def mask_cabin(
    png: bytes,
    mesh: Any,
    T_base_bin: np.ndarray,
    T_base_cam: np.ndarray,
    intr: Intrinsics,
    max_pixels: int = MAX_IMAGE_PIXELS,
) -> bytes:
    """The image with the pixels off the bin filled with the median colour of the bin's, or the same
    bytes when the view is all bin or all cabin. Like the board mask: the recorded image stays
    untouched, and it is decoded under the cell's pixel budget ``max_pixels``."""
    import cv2

    from cellctl.errors import CellError
    from cellctl.images import decode_image

    off = cabin_pixels(mesh, T_base_bin, T_base_cam, intr)
    if not off.any() or off.all():
        return png
    try:
        img = decode_image(png, "to mask", order="bgr", max_pixels=max_pixels)
    except CellError:
        return png  # the classifier refuses what it cannot decode
    off = cv2.resize(off.astype(np.uint8), (img.shape[1], img.shape[0]), interpolation=cv2.INTER_NEAREST) > 0
    img[off] = np.median(img[~off], axis=0)
    ok, out = cv2.imencode(".png", img)
    return out.tobytes() if ok else png


def classifier_input(
    run: StepRun,
    data: bytes,
    fmt: ImageFormat,
    T_base_cam: np.ndarray,
    intr: Intrinsics,
    surface: Surface | None = None,
) -> tuple[bytes, ImageFormat]:
    """What the classifier gets for a captured view of ``surface`` (default: the cycle's current one): the board
    filled in, and for the surfaces of ``classifier.mask_cabin`` the cabin past the bin too (the recorded image
    stays as captured)."""
    ctx = run.ctx
    if ctx.catalog is None or not ctx.identity.bin_type or ctx.identity.T_base_bin is None:
        return data, fmt
    bt = ctx.catalog.get(ctx.identity.bin_type)
    budget = ctx.cfg.camera.max_image_pixels
    image = mask_board(data, bt, ctx.identity.T_base_bin, T_base_cam, intr, budget)
    if (surface or ctx.surface) in ctx.cfg.classifier.mask_cabin:
        image = mask_cabin(
            image, ctx.catalog.load_mesh(ctx.identity.bin_type), ctx.identity.T_base_bin, T_base_cam, intr, budget
        )
    return (image, "png") if image is not data else (data, fmt)


def classify_image(
    run: StepRun,
    index: int,
    image: bytes,
    fmt: ImageFormat,
    surface: Surface,
    reference: ClassifyReference | None = None,
) -> ClassifyReply:
    req = ClassifyRequest(surface=surface, format=fmt, reference=reference)
    reply, _ = run.call("classifier", "classify", req, ClassifyReply, payload=image)
    return reply


class Scanning(Step):
    NAME = "scanning"
    OUTCOMES = ("succeeded", "failed")
    DESCRIPTION = "move → settle → capture per viewpoint; classification overlaps the next move"
    READS = (
        "scan.plan",
        "scan.next_viewpoint",
        "scan.viewpoints",
        "scan.classifications",
        "identity.bin_type",
        "identity.T_base_bin",
        "refs.sets",
    )
    CONSULTS = (*AT_STATION, "refs.writer", "refs.caster")
    WRITES = (
        "scan.viewpoints",
        "scan.classifications",
        "scan.next_viewpoint",
        "refs.writer",
        "refs.sets",
        "refs.caster",
    )

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        plan = ctx.scan.plan
        assert plan is not None  # READS plan: the loader checked a step wrote it
        surface = ctx.surface
        collect = ctx.mode == "collect"
        settle = ctx.cfg.robot.settle_s
        perturb = ctx.params.perturb_m if collect else 0.0
        seed = ctx.params.seed
        # classifications run on past a Hold (the scanning activation is cancelled, the cycle is not)
        background = run.detached("classify_background")
        st = ctx.stations.current_station()
        # whole-bin cycle: each view says where it was taken (viewpoint indices repeat across plans)
        where: dict[str, Any] = {"station": st.station, "surface": surface} if st is not None else {}
        for k in range(ctx.scan.next_viewpoint, len(plan.viewpoints)):
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
                        # a tolerated parking error can still bring the bin's rim onto every IK
                        # solution of the pose: nearby poses with the same view (backed off, rolled)
                        from cellctl.planning.adjust import NEARBY_VIEWS, nearby_views

                        for (back, roll), T in zip(NEARBY_VIEWS, nearby_views(vp.camera_pose.matrix()), strict=True):
                            try:
                                again, _ = run.call(
                                    "robot",
                                    "move",
                                    MoveRequest(camera_pose=PoseMsg.from_matrix(T), settle_s=settle),
                                    MoveReply,
                                )
                            except WorkerFailed:
                                continue
                            run.event(
                                "info",
                                f"station {st.station} {surface} viewpoint {vp.index}: refused ({err}); reached "
                                f"{back * 1000:.0f} mm further back, rolled {roll:+.0f} deg",
                            )
                            break
                if again is None:
                    # One refused viewpoint (e.g. newly in collision after adjustment) costs coverage,
                    # not the cycle; hangs and missing workers still abort.
                    ctx.scan.viewpoints.append(
                        ViewpointResult(index=vp.index, camera_pose=vp.camera_pose, error=str(err), **where)
                    )
                    ctx.scan.next_viewpoint = k + 1
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
                image, fmt = classifier_input(run, data, cap.format, moved.camera_pose.matrix(), cap.intrinsics)
                reference = None
                if ctx.mode == "commission":  # the bin is declared clean: this view is its viewpoint's reference
                    store_reference(ctx, vp.index, image, fmt, moved.camera_pose.matrix(), cap.intrinsics)
                else:  # a commissioned plan: the classifier compares the view with its viewpoint's reference
                    reference = reference_query(ctx, vp.index, moved.camera_pose.matrix())
                    if reference is None:
                        result = result.model_copy(update={"reference_reason": reference_state(ctx)})
                ctx.scan.classifications[len(ctx.scan.viewpoints)] = ctx.pool.submit(
                    classify_image, background, vp.index, image, fmt, surface, reference
                )
            ctx.scan.viewpoints.append(result)
            ctx.scan.next_viewpoint = k + 1
        mine = [
            v for v in ctx.scan.viewpoints if (v.station, v.surface) == (where.get("station"), where.get("surface"))
        ]
        if not any(v.error is None for v in mine):
            first = mine[0].error if mine else "the plan has none"
            at = f" at station {st.station} ({surface})" if st is not None else ""
            raise WorkerFailed(
                f"robot reached none of the {len(plan.viewpoints)} planned viewpoints{at} (first: {first})",
                role="robot",
            )
        return "succeeded"
