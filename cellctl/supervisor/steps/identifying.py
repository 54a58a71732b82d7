"""identifying: capture the board, decide the bin type and its pose in the robot base frame."""

from __future__ import annotations

import numpy as np

from cellctl.errors import CameraError, IdentificationError
from cellctl.messages import CaptureReply, CaptureRequest, EventLevel
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import Step


def decode_image(data: bytes) -> np.ndarray:
    """Decode PNG/JPEG bytes to a BGR image, or raise CameraError."""
    import cv2

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) if data else None
    if img is None:
        raise CameraError(f"camera returned {len(data)} bytes that are not a decodable image")
    return img


class Identifying(Step):
    NAME = "identifying"
    OUTCOMES = ("succeeded", "retry", "failed")
    DESCRIPTION = "ChArUco → bin type + T_base_bin; retries from the next observation pose"

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        reply, image = run.call("camera", "capture", CaptureRequest(format="png"), CaptureReply)
        data = image or b""
        ctx.log.image("/camera/image", data, reply.format, "camera")
        if ctx.identify is None:
            raise IdentificationError("no identifier is configured in this supervisor")
        assert ctx.approach is not None
        T_base_cam = ctx.approach.camera_pose.matrix()
        ctx.identify_attempts += 1
        try:
            ident = ctx.identify(decode_image(data), reply.intrinsics, T_base_cam, ctx.catalog)
        except IdentificationError as err:
            attempts = ctx.cfg.supervisor.identify_attempts
            if ctx.identify_attempts < attempts:
                run.event("warning", f"not identified from observation pose {ctx.observation_index}: {err}; retrying")
                ctx.log.event(int(EventLevel.warning), f"not identified: {err}")
                ctx.observation_index += 1
                return "retry"
            raise IdentificationError(f"bin not identified after {attempts} observation poses: {err}") from err
        ctx.identification = ident
        ctx.bin_type = ident.bin_type
        ctx.T_base_bin = np.asarray(ident.T_base_bin)
        from cellctl.recording import foxglove

        ctx.log.write_json("/bin/pose", "foxglove.PoseInFrame", foxglove.pose_in_frame("base", ctx.T_base_bin))
        ctx.log.write_json(
            "/tf", "foxglove.FrameTransform", foxglove.frame_transform("base", "bin", ctx.T_base_bin)
        )
        run.event("info", f"identified bin {ident.bin_type!r}")
        return "succeeded"
