"""Bin identification from ChArUco boards, multi-view fusion and camera calibration.

Light package (numpy + cv2 only): the supervisor daemon imports it. The API the cycle uses::

    from cellctl.vision import identify, fuse
    ident = identify(image_bgr, capture.intrinsics, T_base_cam, catalog)   # or IdentificationError
    fused = fuse([ident1, ident2, ident3])                                   # optional, 2-3 views

``ident.bin_type``, ``ident.T_base_bin`` (4×4, bin → base), ``ident.to_dict()`` for the log.
"""

from cellctl.vision.board import BoardSpec, KnownBoard, boards_from_catalog, make_board
from cellctl.vision.fuse import FusedIdentification, FuseSettings, fuse
from cellctl.vision.handeye import HandEyeResult, solve_hand_eye
from cellctl.vision.identify import Identification, IdentifySettings, identify

__all__ = [
    "BoardSpec",
    "FuseSettings",
    "FusedIdentification",
    "HandEyeResult",
    "Identification",
    "IdentifySettings",
    "KnownBoard",
    "boards_from_catalog",
    "fuse",
    "identify",
    "make_board",
    "solve_hand_eye",
]
