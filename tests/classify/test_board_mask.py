"""The ID-board mask on real twin renders: filled where the camera sees the board's face, left
alone where the board's outline projects into the frame but the camera is behind its plane."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.config import project_root
from cellctl.geometry.camera import D435_COLOR
from cellctl.geometry.catalog import load_catalog
from cellctl.geometry.transforms import invert, look_at
from cellctl.images import decode_image, encode_image
from cellctl.sim import scene
from cellctl.sim.render import RenderParams, SimRenderer
from cellctl.supervisor.steps.board_mask import MARGIN_M, mask_board

CAM = D435_COLOR.scaled(0.2)  # 256 x 144: the bench's render size
QUIET = RenderParams(noise_sigma=0.0)


@pytest.fixture(scope="module")
def renderer() -> SimRenderer:
    return SimRenderer(load_catalog(project_root() / "config" / "bins.yaml"))


def _markers(rgb: np.ndarray, bt) -> int:
    import cv2

    from cellctl.geometry.boards import make_charuco_board

    det = cv2.aruco.ArucoDetector(make_charuco_board(bt.board).getDictionary(), cv2.aruco.DetectorParameters())
    _, ids, _ = det.detectMarkers(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))
    return 0 if ids is None else len(ids)


def _outline_in_frame(bt, T_bin_cam: np.ndarray) -> bool:
    """Whether the board's outline (with its margin) lies in front of the camera and inside the
    frame: what the mask used to fill regardless of which side of the board the camera was on."""
    w, h = bt.board.size_m
    m = MARGIN_M
    c = np.array([[-m, -m, 0, 1], [w + m, -m, 0, 1], [w + m, h + m, 0, 1], [-m, h + m, 0, 1]], float)
    p = (invert(T_bin_cam) @ bt.T_bin_board() @ c.T)[:3]
    if np.any(p[2] <= 0.01):
        return False
    uv = (CAM.intrinsics().K() @ (p / p[2]))[:2]
    return bool(((uv[0] > 0) & (uv[0] < CAM.width) & (uv[1] > 0) & (uv[1] < CAM.height)).any())


def test_the_board_is_filled_when_the_camera_faces_it(renderer: SimRenderer) -> None:
    bt = renderer.catalog.get("case_study")
    T = scene.observation_T_bin_cam(bt, 0)
    out = renderer.render_bin_view("case_study", T, CAM, dirty=False, params=QUIET)
    assert _markers(out.rgb, bt) >= 6  # the render shows the board
    png = encode_image(out.rgb, "png")
    masked = mask_board(png, bt, np.eye(4), T, CAM.intrinsics())
    assert masked != png
    assert _markers(decode_image(masked, "masked"), bt) == 0


@pytest.mark.parametrize(
    ("eye", "target"),
    [
        # outside the bin, beside the x-min wall: the board (on the -y wall) is behind that wall
        ((-0.8, -0.2, -0.1), (-0.3, -0.25, -0.15)),
        # inside the bin, looking at the board wall's inner face
        ((0.0, 0.15, -0.1), (-0.04, -0.38, -0.14)),
    ],
)
def test_a_board_seen_from_behind_its_plane_is_not_filled(renderer: SimRenderer, eye: tuple, target: tuple) -> None:
    """The bench's external false-dirty spot: a median-filled rectangle painted over grained steel
    the camera does see reads as a film to the detector."""
    bt = renderer.catalog.get("case_study")
    T = look_at(eye, target)
    assert _outline_in_frame(bt, T)  # the old mask would have filled it
    out = renderer.render_bin_view("case_study", T, CAM, dirty=False, params=QUIET)
    assert _markers(out.rgb, bt) == 0  # and indeed the pattern is not in the image
    png = encode_image(out.rgb, "png")
    assert mask_board(png, bt, np.eye(4), T, CAM.intrinsics()) is png


def test_the_bench_masks_views_as_the_scanning_step(renderer: SimRenderer) -> None:
    """``bench inspect`` hands the detector what ``classifier_input`` would: the cabin past the rim
    filled only for the surfaces of ``classifier.mask_cabin`` (internal by default)."""
    from cellctl.bench.classify.inspect import classifier_view
    from cellctl.supervisor.steps.scanning import mask_cabin

    bt = renderer.catalog.get("case_study")
    mesh = renderer.catalog.load_mesh("case_study")
    T = look_at((0.0, 0.9, 0.35), (0.0, 0.0, -0.2))  # into the bin over its rim: cabin past it (28 %)
    out = renderer.render_bin_view("case_study", T, CAM, dirty=False, params=QUIET)
    png = encode_image(out.rgb, "png")
    intr = CAM.intrinsics()
    assert classifier_view(png, False, bt, mesh, np.eye(4), T, intr) is png  # no board face, no cabin mask
    cabin = classifier_view(png, True, bt, mesh, np.eye(4), T, intr)
    assert cabin == mask_cabin(png, mesh, np.eye(4), T, intr) and cabin != png
