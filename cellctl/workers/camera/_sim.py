"""The simulated camera: renders the twin from the arm's current camera pose.

The world (scenario, parked base, joints) comes from the sim robot worker's
:class:`~cellctl.messages.SimState`, fetched fresh for every capture, so an image always
shows the arm where the last ``move`` left it.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import numpy as np

from cellctl.config import CellConfig
from cellctl.errors import CameraError, CellError
from cellctl.geometry import robot_model as rm
from cellctl.geometry.camera import CameraModel
from cellctl.images import encode_image
from cellctl.messages import CaptureReply, PoseMsg, SimState
from cellctl.workers.camera._port import Camera

__all__ = ["SimCamera"]


class SimCamera(Camera):
    """Sim backend of the camera role.

    Args:
        cfg: the cell config (``camera``, ``catalog``).
        state_fn: returns the current :class:`SimState` (the worker asks the robot worker);
            ``state_fn(True)`` also carries the spray passes run over the bin.
    """

    name = "sim"

    def __init__(self, cfg: CellConfig, state_fn: Callable[..., SimState]) -> None:
        self.cfg = cfg
        self.state_fn = state_fn
        self.intrinsics = CameraModel.from_config(cfg.camera).intrinsics()
        self._renderer = None
        self._frames = itertools.count()
        self._washes: tuple[int, list] = (0, [])  # (passes the robot reported, SprayPass list)

    def connect(self) -> None:
        from cellctl.geometry.catalog import load_catalog
        from cellctl.sim.render import SimRenderer

        self._renderer = SimRenderer(load_catalog(self.cfg.path(self.cfg.catalog)))

    @property
    def is_connected(self) -> bool:
        return self._renderer is not None

    def capture(self, fmt: str) -> tuple[CaptureReply, bytes]:
        from cellctl.sim.render import RenderParams
        from cellctl.sim.scene import Scenario

        self._require_connected()
        try:
            st = self.state_fn()
        except CellError as err:
            raise CameraError(f"sim camera cannot see the world: {err}") from err
        T_world_base = st.world_T_base.matrix()
        sc = Scenario(
            bin_type=st.bin_type,
            bin_xyz_yaw=st.bin_xyz_yaw,
            dirty=st.dirty,
            powder_amount=st.powder_amount,
            seed=st.seed,
        ).with_base(T_world_base)
        q = np.asarray(st.joints)
        T_base_cam = rm.camera_pose(q)
        washes = self._spray_passes(st)
        out = self._renderer.render(  # type: ignore[union-attr]
            sc,
            T_world_base @ T_base_cam,
            self.intrinsics,
            joints=q,
            params=RenderParams(noise_sigma=self.cfg.camera.noise_sigma),
            seed=next(self._frames),
            washes=washes,
        )
        data = encode_image(out.rgb, fmt, CameraError)
        # the camera pose is reported in the robot base frame, as the robot knows it (FK)
        return CaptureReply(format=fmt, intrinsics=self.intrinsics, camera_pose=PoseMsg.from_matrix(T_base_cam)), data

    def _spray_passes(self, st: SimState) -> list:
        """The washes run over the bin (fetched again only when the robot reports more or fewer)."""
        from cellctl.sim.ground_truth import SprayPass

        if st.wash_passes == 0:
            self._washes = (0, [])
        elif st.wash_passes != self._washes[0]:
            try:
                full = self.state_fn(True)
            except CellError as err:
                raise CameraError(f"sim camera cannot read the washes run over the bin: {err}") from err
            passes = [
                SprayPass(np.asarray(m.spots), np.asarray(m.axes), m.radius, m.cos_incidence, m.removal)
                for m in full.washes or []
            ]
            self._washes = (full.wash_passes, passes)
        return self._washes[1]
