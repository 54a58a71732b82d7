"""Camera worker: ``cellctl worker camera --backend sim|opencv|folder``.

Serves ``cell/<id>/camera/capture``: :class:`~cellctl.messages.CaptureRequest` → the encoded
image as the reply payload with :class:`~cellctl.messages.CaptureReply` (format, intrinsics,
camera pose in the robot base frame when known) as the attachment.

Backends: ``sim`` renders the twin (needs the sim robot worker, which owns the world),
``opencv`` reads a device index or stream URL, ``folder`` replays a directory of images.
A camera that cannot be opened does not stop the worker: each capture retries the
connection and, failing, replies with a CameraError naming the device.
"""

from __future__ import annotations

import logging
import threading

from cellctl.config import CellConfig
from cellctl.errors import CameraError, ConfigError
from cellctl.messages import CaptureReply, CaptureRequest
from cellctl.workers.camera._port import Camera

__all__ = [
    "BACKENDS",
    "Camera",
    "make_camera",
    "run_worker",
    "serve_camera",
]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

BACKENDS = ("sim", "opencv", "folder")


def make_camera(cfg: CellConfig, backend: str | None = None, session=None) -> Camera:
    """Build the camera backend (default ``cfg.camera.backend``); ``session`` feeds the sim its world.

    Raises:
        ConfigError: unknown backend, or the sim backend without a session.
    """
    name = backend or cfg.camera.backend
    if name == "sim":
        if session is None:
            raise ConfigError("the sim camera needs a bus session to read the sim robot's world")
        from cellctl.bus import keys
        from cellctl.bus.rpc import request
        from cellctl.messages import SimState, SimStateRequest
        from cellctl.workers.camera._sim import SimCamera

        def state(washes: bool = False) -> SimState:
            return request(
                session,
                keys.sim_state(cfg.cell_id),
                SimStateRequest(washes=washes),
                SimState,
                timeout=5.0,
                role="robot",
            )[0]

        return SimCamera(cfg, state)
    if name == "opencv":
        from cellctl.workers.camera._opencv import OpenCVCamera

        return OpenCVCamera(cfg)
    if name == "folder":
        from cellctl.workers.camera._folder import FolderCamera

        return FolderCamera(cfg)
    raise ConfigError(f"camera backend {name!r} is unknown; expected one of {list(BACKENDS)}")


def serve_camera(session, cfg: CellConfig, camera: Camera, stop: threading.Event) -> None:
    """Serve ``camera`` on ``session`` until ``stop`` is set (blocking)."""
    from cellctl.workers._server import WorkerServer

    lock = threading.Lock()

    def capture(req: CaptureRequest, _raw: bytes | None) -> tuple[CaptureReply, bytes]:
        with lock:
            if not camera.is_connected:
                try:
                    camera.connect()
                except CameraError as err:
                    raise CameraError(f"camera {camera.name!r} is not connected: {err}") from err
            return camera.capture(req.format)

    try:
        camera.connect()
    except CameraError as err:
        log.warning("camera not connected at start (will retry on capture): %s", err)
    with WorkerServer(session, cfg.cell_id, "camera") as server:
        server.serve("capture", CaptureRequest, capture)
        server.announce()
        log.info("camera worker (%s) serving cell %s", camera.name, cfg.cell_id)
        stop.wait()


def run_worker(cfg: CellConfig, backend: str | None, stop: threading.Event) -> None:
    """Entry point of ``cellctl worker camera``."""
    from cellctl.bus.session import open_session

    session = open_session(cfg, "client")
    try:
        with make_camera(cfg, backend, session) as camera:
            serve_camera(session, cfg, camera, stop)
    finally:
        session.close()
