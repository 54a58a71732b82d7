"""identifying: capture the board, decide the bin type and its pose in the robot base frame."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cellctl.bus import topics
from cellctl.errors import CameraError, IdentificationError, WorkerFailed
from cellctl.images import IMAGE_MAGIC, decode_image
from cellctl.messages import ApproachReply, CaptureReply, CaptureRequest, EventLevel, StationInfo
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import AT_STATION, Step
from cellctl.supervisor.steps.approaching import approach_request

if TYPE_CHECKING:
    from cellctl.vision.identify import Identification


def captured_image(reply: CaptureReply, image: bytes | None) -> bytes:
    """The image of a capture reply, checked against the format the reply declares, or CameraError.

    A signature check, not a decode: scanning hands the bytes on to the classifier without decoding.
    """
    data = image or b""
    if not data.startswith(IMAGE_MAGIC[reply.format]):
        raise CameraError(
            f"camera answered capture with {len(data)} bytes that are not a {reply.format} image (starts {data[:8]!r})"
        )
    return data


class Identifying(Step):
    NAME = "identifying"
    OUTCOMES = ("succeeded", "retry", "failed")
    DESCRIPTION = "ChArUco → bin type + T_base_bin; fuses several views if configured; retries from the next pose"
    READS = (
        "identity.approach",
        "identity.observation_index",
        "identity.identify_attempts",
        "stations.bin_poses",
        "stations.pose_source",
    )
    CONSULTS = (*AT_STATION, "identity.bin_type", "stations.T_map_base", "stations.T_map_bin")
    WRITES = (
        "identity.identify_attempts",
        "identity.observation_index",
        "identity.identification",
        "identity.bin_type",
        "identity.T_base_bin",
        "stations.T_map_bin",
        "stations.bin_poses",
        "stations.pose_source",
    )

    def _view(self, run: StepRun, T_base_cam: np.ndarray) -> Identification:
        ctx = run.ctx
        reply, image = run.call("camera", "capture", CaptureRequest(format="png"), CaptureReply)
        data = captured_image(reply, image)
        ctx.log.image(topics.CAMERA_IMAGE, data, reply.format, "camera")
        if ctx.identify is None:
            raise IdentificationError("no identifier is configured in this supervisor")
        bgr = decode_image(
            data,
            f"from the camera ({reply.format})",
            order="bgr",
            error=CameraError,
            max_pixels=ctx.cfg.camera.max_image_pixels,
        )
        ident = ctx.identify(bgr, reply.intrinsics, T_base_cam, ctx.catalog)
        record = ident.to_dict() if hasattr(ident, "to_dict") else {"bin_type": ident.bin_type}
        ctx.log.write_json(topics.BIN_IDENTIFICATION, "cellctl.Identification", record)
        return ident

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        assert ctx.identity.approach is not None
        st = ctx.stations.current_station()
        if st is not None and st.observation_index is None:
            return self._carry_over(run, st)
        ctx.identity.identify_attempts += 1
        try:
            ident = self._view(run, ctx.identity.approach.camera_pose.matrix())
        except IdentificationError as err:
            attempts = ctx.cfg.supervisor.identify_attempts
            if ctx.identity.identify_attempts < attempts:
                run.event(
                    "warning", f"not identified from observation pose {ctx.identity.observation_index}: {err}; retrying"
                )
                ctx.log.event(int(EventLevel.warning), f"not identified: {err}")
                ctx.identity.observation_index += 1
                return "retry"
            raise IdentificationError(f"bin not identified after {attempts} observation poses: {err}") from err
        views: list[Identification] = [ident]
        for k in range(1, ctx.cfg.supervisor.identify_views):
            # Extra views from the next observation poses; a view that fails is skipped, the
            # fused estimate uses the ones that worked.
            idx = ctx.identity.observation_index + k
            try:
                moved, _ = run.call("robot", "approach", approach_request(run, idx, False), ApproachReply)
                views.append(self._view(run, moved.camera_pose.matrix()))
            except (IdentificationError, WorkerFailed) as err:
                run.event("warning", f"extra view from observation pose {idx} skipped: {err}")
        if len(views) > 1:
            from cellctl.vision import fuse

            fused = fuse(views)
            ctx.log.write_json(topics.BIN_IDENTIFICATION_FUSED, "cellctl.FusedIdentification", fused.to_dict())
            bin_type, T_base_bin = fused.bin_type, np.asarray(fused.T_base_bin)
            note = f" from {len(fused.used)} fused views (±{fused.sigma_bin_origin_mm:.1f} mm)"
            ctx.identity.identification = fused
        else:
            bin_type, T_base_bin = ident.bin_type, np.asarray(ident.T_base_bin)
            note = ""
            ctx.identity.identification = ident
        if T_base_bin.shape != (4, 4) or not np.isfinite(T_base_bin).all():
            raise IdentificationError(f"identification of bin {bin_type!r} gave no finite 4x4 pose")
        if st is not None and ctx.identity.bin_type is not None and bin_type != ctx.identity.bin_type:
            raise IdentificationError(
                f"station {st.station} identified bin {bin_type!r}, "
                f"but this cycle inspects bin {ctx.identity.bin_type!r}"
            )
        if st is not None:
            ctx.stations.bin_poses[st.station] = T_base_bin
            ctx.stations.pose_source[st.station] = "measured"
        ctx.identity.bin_type = bin_type
        ctx.identity.T_base_bin = T_base_bin
        # where the bin stands in the base's map: what a station without the board is told (base_odometry)
        ctx.stations.T_map_bin = ctx.stations.T_map_base @ T_base_bin if ctx.stations.T_map_base is not None else None
        from cellctl.recording import foxglove

        ctx.log.write_json(topics.BIN_POSE, "foxglove.PoseInFrame", foxglove.pose_in_frame("base", T_base_bin))
        ctx.log.write_json(topics.TF, "foxglove.FrameTransform", foxglove.frame_transform("base", "bin", T_base_bin))
        run.event("info", f"identified bin {bin_type!r}{note}")
        return "succeeded"

    @staticmethod
    def _carry_over(run: StepRun, st: StationInfo) -> str:
        """A station that cannot see the board: the bin pose measured at an earlier station, carried
        through the base's reported motion since (``base_odometry``); the planned station pose when the
        base reports no pose (``carried_over``). See decisions.md."""
        from cellctl.geometry.transforms import invert, pose_error
        from cellctl.recording import foxglove

        ctx = run.ctx
        if ctx.identity.bin_type is None:
            raise IdentificationError(
                f"station {st.station} cannot see the board ({st.identify_reason}) and no earlier station "
                "identified the bin"
            )
        planned = invert(st.base_pose.matrix())
        if ctx.stations.T_map_bin is not None and ctx.stations.T_map_base is not None:
            ctx.identity.T_base_bin = invert(ctx.stations.T_map_base) @ ctx.stations.T_map_bin
            source = "base_odometry"
            dt, dr = pose_error(planned, ctx.identity.T_base_bin)
            how = (
                f"carried from the last measured station by the base's reported motion "
                f"({dt * 1000:.1f} mm / {np.degrees(dr):.2f} deg from the planned station pose)"
            )
        else:
            ctx.identity.T_base_bin = planned
            source = "carried_over"
            how = "carried over (planned station pose: the base reports no pose)"
        ctx.stations.bin_poses[st.station] = ctx.identity.T_base_bin
        ctx.stations.pose_source[st.station] = source
        ctx.log.write_json(
            topics.BIN_POSE, "foxglove.PoseInFrame", foxglove.pose_in_frame("base", ctx.identity.T_base_bin)
        )
        run.event("info", f"station {st.station}: board not visible, bin pose {how}")
        return "succeeded"
