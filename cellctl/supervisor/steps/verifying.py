"""verifying: re-inspect what the round washed, and the neighbours the jet may have splashed.

The faces to look at again are the round's targets and every face its jet sprayed, dilated by
``wash.splash_m``; the inspection plan's viewpoints that see any of them are visited again in
plan order (move → capture → classify, each a :class:`~cellctl.messages.ViewpointResult` with
``wash_round``, kept in ``wash_views``, not in the CycleResult's ``viewpoints``: the MCAP has
them, the round their count). Their evidence alone gives the faces they see a new state (the views before
the wash saw powder that is gone); faces they do not see keep theirs. The merged map becomes
the cycle's dirt map, the round is recorded (:data:`~cellctl.bus.topics.WASH_ROUND`, the
CycleResult's ``wash.rounds``) and ``wash_check`` decides again.

A whole-bin cycle re-inspects station by station (``wash_station`` parks the base): at each,
the viewpoints of that station's plans (both surfaces) that see the faces to look at, each
classified by its surface's network. Where the base parked again since the scan, a view goes
to its planned camera pose relative to the bin, carried into the new park (the bin pose
measured there), not to the planned joints.

A re-inspection view is decided as the scan's views are (:mod:`cellctl.supervisor.steps.classifying`):
an uncertain one, and with ``classifier.relook.confirm_dirty`` (whole-bin cycles by default) a
certain-dirty one, is imaged again once from a nearby pose (up to ``classifier.relook.max_views``
per station visit), and a certain-dirty view stays dirty unless its re-look is certain clean.
Reason: a dirty view after the wash paints faces for the next round, and the whole-image
classifier's false-dirty views (0.7 % per view) otherwise kept a washed bin dirty through every
round; real dirt left is seen from 3 cm and 12° away too, so it stays dirty.

With whole-image classifiers (no heat map, the coarse map) a dirty re-inspection view is laid
on what the round did not wash: it marks dirty the faces it sees that were dirty before the
round and got no sweep, when it sees any; only a view that sees nothing but washed or clean
faces marks them all dirty again. Without this, one unwashable spot in a view would keep every
washed face of that view dirty round after round; a bin with such a spot still ends ``dirty``,
by that spot's faces.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cellctl.bus import topics
from cellctl.errors import WorkerFailed
from cellctl.messages import (
    CaptureReply,
    CaptureRequest,
    MoveReply,
    MoveRequest,
    PoseMsg,
    ViewpointResult,
    WashResult,
    WashRound,
)
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import AT_STATION, Step
from cellctl.supervisor.steps.washing import face_mask, face_state, picture_dir, views_at, wash_mesh, washed_faces
from cellctl.surface import Surface

__all__ = ["Verifying", "imaged_faces", "merge_dirt_maps"]


def merge_dirt_maps(old: dict[str, Any], new: dict[str, Any], mesh: Any) -> dict[str, Any]:
    """``old`` with every face ``new`` saw replaced by what ``new`` says (a dirt map with ``face_p``)."""
    from cellctl.classify.heatmap import FaceMap

    n = mesh.n_faces
    p0, s0, d0 = face_state(old, n)
    p1, s1, d1 = face_state(new, n)
    dirty = np.where(s1, d1, d0)
    fm = FaceMap(p=np.where(s1, p1, p0), seen=s0 | s1, dirty=dirty, dirty_area_m2=float(mesh.areas[dirty].sum()))
    return fm.as_json()


IMAGED_GRID = (64, 36)
"""Rays across the frame (columns, rows) that find the faces a re-inspection view images: a face of
the case-study bin's legs (145 cm²) spans tens of them at the camera's far depth of view."""
IMAGED_DEPTH_FACTOR = 1.5
"""Faces imaged up to this many times the camera's far depth of view count (the whole-image
classifier sees a large clump beyond the measuring range; the cabin far behind the bin it ignores)."""


def imaged_faces(ctx: Any, mesh: Any, v: ViewpointResult) -> set[int]:
    """Faces of the bin a view's image shows (first hits of a ray grid across the frame, within
    ``IMAGED_DEPTH_FACTOR`` × the far depth of view), not only the faces its plan counts as measured.

    The twin's evidence (docs/washing/README.md): a dirty re-inspection view whose planned faces
    were all washed saw powder on faces no plan lists (large leg faces only part of which is in any
    frame), so re-painting its own faces washed them again, round after round. The ray caster is
    imported here, in a round's re-inspection only (the daemon's import graph stays light).
    """
    from cellctl.geometry.camera import CameraModel
    from cellctl.geometry.transforms import invert
    from cellctl.planning.raycast import RayCaster

    if v.camera_pose is None:
        return set()
    T_base_bin = ctx.stations.bin_poses.get(v.station) if v.station is not None else None
    T_base_bin = ctx.identity.T_base_bin if T_base_bin is None else T_base_bin
    if T_base_bin is None:
        return set()
    cam = CameraModel.from_config(ctx.cfg.camera)
    T = invert(np.asarray(T_base_bin)) @ v.camera_pose.matrix()
    nx, ny = IMAGED_GRID
    u, w = np.meshgrid((np.arange(nx) + 0.5) * cam.width / nx, (np.arange(ny) + 0.5) * cam.height / ny)
    d = np.stack([(u.ravel() - cam.cx) / cam.fx, (w.ravel() - cam.cy) / cam.fy, np.ones(u.size)], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    dirs = d @ T[:3, :3].T
    # built per view (a few ms for a bin mesh): only dirty views whose planned faces were all washed ask
    face, dist = RayCaster(mesh.vertices, mesh.faces).first_hit(np.broadcast_to(T[:3, 3], dirs.shape), dirs)
    depth = dist * d[:, 2]
    ok = (face >= 0) & (depth <= IMAGED_DEPTH_FACTOR * cam.dov[1])
    return {int(x) for x in np.unique(face[ok])}


class Verifying(Step):
    NAME = "verifying"
    OUTCOMES = ("succeeded", "next", "failed")
    DESCRIPTION = "re-inspect the washed regions and their splash neighbours; merge into the dirt map; record the round"
    READS = (
        "wash.plan",
        "wash.run",
        "wash.rounds",
        "wash.verify_queue",
        "wash.next_view",
        "wash.views",
        "wash.scan_poses",
        "scan.plan",
        "result.dirt_map",
        "stations.plans",
        "stations.bin_poses",
        "stations.station_order",
        "identity.bin_type",
        "identity.T_base_bin",
    )
    CONSULTS = AT_STATION
    WRITES = (
        "result.dirt_map",
        "wash.views",
        "wash.rounds",
        "wash.result",
        "wash.plan",
        "wash.next_view",
        "wash.verify_queue",
    )

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        wplan, iplan = ctx.wash.plan, ctx.scan.plan
        assert wplan is not None and iplan is not None  # READS
        mesh = wash_mesh(ctx)
        r = len(ctx.wash.rounds) + 1
        n = mesh.n_faces
        if ctx.wash.verify_queue:
            rank = ctx.wash.verify_queue[0]
            views = views_at(ctx, mesh, rank)
            for k in range(ctx.wash.next_view, len(views)):
                surf, vp = views[k]
                self._look(run, vp, r, surf, rank)
                ctx.wash.next_view = k + 1
            self._relook(run, r, rank)
            ctx.wash.verify_queue.pop(0)
            ctx.wash.next_view = 0
            if ctx.wash.verify_queue:
                return "next"
        washed, covered = face_mask(wplan.washed, n) | washed_faces(ctx, n), face_mask(wplan.covered, n)
        mine = [v for v in ctx.wash.views if v.wash_round == r]
        before = face_mask(wplan.dirty, n)
        new_map = self._dirt_map(ctx, mesh, mine, before, washed_faces(ctx, n))
        ctx.result.dirt_map = merge_dirt_maps(ctx.result.dirt_map or {}, new_map, mesh)
        # the heat maps are in the MCAP (topics.HEATMAP); the round's dirt map keeps the fused face_p
        ctx.wash.views = [v.model_copy(update={"heatmap": None}) if v.wash_round == r else v for v in ctx.wash.views]
        from cellctl.washing.targets import dirty_from_map

        after, _ = dirty_from_map(ctx.result.dirt_map, mesh.n_faces, ctx.cfg.wash.threshold)
        stats = ctx.wash.run
        pictures = list(stats.get("pictures", []))
        folder = picture_dir(ctx)
        if folder is not None:
            from cellctl.recording.dirt_map import draw_dirt_map

            png = draw_dirt_map(
                mesh, ctx.result.dirt_map, folder / f"r{r}_after.png", f"{ctx.identity.bin_type} round {r}: after"
            )
            pictures.append(png.name)
        a = mesh.areas
        rec = WashRound(
            round=r,
            dirty_faces_before=int(before.sum()),
            dirty_m2_before=round(float(a[before].sum()), 6),
            sweeps_planned=len(wplan.sweeps),
            sweeps_run=int(stats.get("sweeps_run", 0)),
            passes_run=int(stats.get("passes_run", 0)),
            washed_m2=round(float(a[washed].sum()), 6),
            covered_m2=round(float(a[covered].sum()), 6),
            unwashable=list(wplan.summary.get("unwashable", [])),
            sweeps_refused=list(stats.get("refused", [])),
            reinspected_views=len(mine),
            dirty_faces_after=int(after.sum()),
            dirty_m2_after=round(float(a[after].sum()), 6),
            plan_s=wplan.plan_s + sum(float(x.get("plan_s", 0.0)) for x in stats.get("replanned", [])),
            plan_cpu_s=wplan.cpu_s,
            pictures=pictures,
        )
        ctx.log.write_json(topics.WASH_ROUND, "cellctl.WashRound", rec.model_dump(mode="json"))
        ctx.wash.rounds.append(rec)
        ctx.wash.result = WashResult(rounds=list(ctx.wash.rounds))  # the verdict is wash_check's
        ctx.wash.plan = None
        ctx.wash.next_view = 0
        run.event(
            "info",
            f"wash round {r} re-inspected with {len(mine)} views: {int(after.sum())} dirty faces "
            f"({float(a[after].sum()) * 1e4:.0f} cm²) left, were {int(before.sum())}",
        )
        return "succeeded"

    @staticmethod
    def _look(run: StepRun, vp: Any, r: int, surface: Surface, rank: int | None) -> None:
        from cellctl.geometry.transforms import invert

        ctx = run.ctx
        where = {"station": rank, "surface": surface} if rank is not None else {}
        settle = ctx.cfg.robot.settle_s
        move = MoveRequest(joints=vp.joints, settle_s=settle)
        T_then, T_now = ctx.wash.scan_poses.get(rank), ctx.stations.bin_poses.get(rank)  # type: ignore[arg-type]
        if T_then is not None and T_now is not None and not np.allclose(T_then, T_now, atol=1e-9):
            # parked again since the scan: the same view of the bin, from the new park
            T = T_now @ invert(T_then) @ vp.camera_pose.matrix()
            carried = MoveRequest(camera_pose=PoseMsg.from_matrix(T, vp.camera_pose.frame_id), settle_s=settle)
            if Verifying._view(run, vp.index, carried, vp.camera_pose, surface, {**where, "wash_round": r}, False):
                return
            # the carried pose is out of the arm's reach or in collision from this park: the planned
            # joints see nearly the same faces (off by the park's error, 2-3 cm). A refused view left
            # its faces as they were: on the twin the only view of 2 dirty faces was refused so, and
            # their dirt took a round more (528 -> 2 -> 2 -> 0)
            run.event("info", f"re-inspection view {vp.index} ({surface}): carried pose refused, the planned joints")
        Verifying._view(run, vp.index, move, vp.camera_pose, surface, {**where, "wash_round": r})

    @staticmethod
    def _view(
        run: StepRun,
        index: int,
        move: MoveRequest,
        pose: PoseMsg,
        surface: Surface,
        where: dict[str, Any],
        record_refusal: bool = True,
    ) -> bool:
        """Move, capture, classify one re-inspection view into ``wash_views`` (a refused move: a view
        with the error at ``pose``, unless ``record_refusal`` is False); whether a view was taken."""
        from cellctl.supervisor.steps.classifying import record_heat, with_reply
        from cellctl.supervisor.steps.identifying import captured_image
        from cellctl.supervisor.steps.scanning import classifier_input, classify_image

        ctx = run.ctx
        try:
            moved, _ = run.call("robot", "move", move, MoveReply)
        except WorkerFailed as err:
            run.checkpoint()
            if record_refusal:
                ctx.wash.views.append(ViewpointResult(index=index, camera_pose=pose, error=str(err), **where))
            return False
        cap, image = run.call("camera", "capture", CaptureRequest(format="png"), CaptureReply)
        data = captured_image(cap, image)
        ctx.log.image(topics.CAMERA_IMAGE, data, cap.format, "camera")
        # the same input as the scan's views (board, and the cabin past the rim for internal views, filled in)
        img, fmt = classifier_input(run, data, cap.format, moved.camera_pose.matrix(), cap.intrinsics, surface)
        reply = classify_image(run, index, img, fmt, surface)
        record_heat(run, reply)
        ctx.wash.views.append(with_reply(ViewpointResult(index=index, camera_pose=moved.camera_pose, **where), reply))
        return True

    @staticmethod
    def _relook(run: StepRun, r: int, rank: int | None) -> int:
        """Re-image this station's uncertain re-inspection views of round ``r`` (and, confirming, its
        certain-dirty ones) once each from a nearby pose, the most ambiguous first, at most
        ``classifier.relook.max_views``; how many views were taken.

        The scan's rule (:mod:`cellctl.supervisor.steps.classifying`): a certain-dirty view is clean
        only if its re-look is certain clean. A dirty re-inspection view paints faces for the next
        round, so each is confirmed on its own (the scan stops at the first confirmed one: the bin
        is dirty by then). Idempotent: a view already re-looked this round is not looked at again
        (a Hold resumes here).
        """
        from cellctl.classify.heatmap import relook_pose
        from cellctl.supervisor.steps.classifying import RELOOK_POSES, Classifying, _logit, view_key

        ctx = run.ctx
        rc = ctx.cfg.classifier.relook
        if rc.max_views <= 0:
            return 0
        confirm = Classifying._confirming(ctx)
        here = [v for v in ctx.wash.views if v.wash_round == r and v.station == rank]
        looked = {view_key(v) for v in here if v.relook_of is not None and v.error is None}
        tried = {view_key(v): 0 for v in here}
        for v in here:
            if v.relook_of is not None:
                tried[view_key(v)] += 1
        firsts = [
            v
            for v in here
            if v.relook_of is None
            and v.error is None
            and v.p_dirty is not None
            and v.camera_pose is not None
            and (v.uncertain or (confirm and v.label == "dirty"))
            and view_key(v) not in looked
        ]
        done = 0
        for v in sorted(firsts, key=lambda w: (not w.uncertain, abs(_logit(w.p_dirty)))):  # type: ignore[arg-type]
            if done + len(looked) >= rc.max_views:
                break
            surface = v.surface or ctx.surface
            # a refused pose (near a rim a swing can touch the bin) tries the next one
            while tried[view_key(v)] < RELOOK_POSES:
                run.checkpoint()
                k = tried[view_key(v)]
                tried[view_key(v)] = k + 1
                T = relook_pose(v.camera_pose.matrix(), k, rc.offset_m, rc.glance_deg, rc.depth_m)  # type: ignore[union-attr]
                where = {"station": v.station, "surface": v.surface, "wash_round": r, "relook_of": v.index}
                move = MoveRequest(camera_pose=PoseMsg.from_matrix(T), settle_s=ctx.cfg.robot.settle_s)
                if Verifying._view(run, v.index, move, PoseMsg.from_matrix(T), surface, where):
                    done += 1
                    break
        return done

    @staticmethod
    def _dirt_map(
        ctx: Any,
        mesh: Any,
        views: list[ViewpointResult],
        before: np.ndarray,
        washed: np.ndarray,
    ) -> dict[str, Any]:
        """The re-inspection's own map: heat maps fused per face, else each view's label laid on its faces
        (a dirty view on the faces it sees that were dirty and not washed, when it sees any)."""
        from cellctl.supervisor.steps.reporting import _bin_type, _faces_by_view, view_evidence

        whole = ctx.whole and bool(ctx.stations.station_order)
        plans = ctx.stations.plans if whole else None
        if any(v.heatmap for v in views):
            from cellctl.classify.heatmap import fuse_config
            from cellctl.geometry.camera import CameraModel

            # the scan's own fusion settings (projection, board occluder), so the re-inspection map and
            # the scan's map judge a face the same way
            fm = fuse_config(
                view_evidence(
                    ctx.scan.plan, views, ctx.identity.T_base_bin, plans, ctx.stations.bin_poses if whole else None
                ),
                mesh,
                CameraModel.from_config(ctx.cfg.camera),
                ctx.cfg.classifier.verdict,
                _bin_type(ctx),
            )
            return fm.as_json()
        from cellctl.supervisor.steps.classifying import Classifying, view_key

        n = mesh.n_faces
        faces_by = _faces_by_view(ctx.scan.plan, plans)
        seen: set[int] = set()
        dirty: set[int] = set()
        # a viewpoint's views (its re-looks with it) decide together, as in the scan (classifying)
        labels = Classifying._view_labels([v for v in views if v.error is None], Classifying._confirming(ctx))
        for key, label in labels.items():
            f = {int(x) for x in faces_by.get(key, []) if 0 <= int(x) < n}
            seen |= f
            if label == "dirty":
                unwashed = {x for x in f if before[x] and not washed[x]}
                if not unwashed:
                    # every face in its list was washed or clean: the powder it sees lies in the image
                    # beyond the planned list (a face too large or oblique to count as measured)
                    imaged: set[int] = set()
                    for v in views:
                        if view_key(v) == key and v.error is None and v.label == "dirty":
                            imaged |= imaged_faces(ctx, mesh, v)
                    unwashed = {x for x in imaged - f if not washed[x]}
                dirty |= unwashed or f
        return {
            "faces_total": n,
            "seen_dirty": sorted(dirty),
            "seen_clean": sorted(seen - dirty),
            "unseen_count": n - len(seen),
        }
