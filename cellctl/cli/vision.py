"""``cellctl identify`` and ``cellctl calibrate {hand-eye,intrinsics}``: the vision verbs.

``identify`` runs the cycle's identification on an image file (debugging); ``calibrate``
produces the camera intrinsics and the hand–eye transform ``T_flange_cam`` as JSON files.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from cellctl.cli import add_config_arguments, config_from_args
from cellctl.errors import CellError

DEFAULT_HAND_EYE = "models/calibration/hand_eye.json"
DEFAULT_INTRINSICS = "models/calibration/intrinsics.json"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("identify", help="identify the bin type and pose in an image file (ChArUco)")
    p.add_argument("image", help="image file (PNG/JPEG)")
    p.add_argument(
        "--intrinsics",
        required=True,
        help="JSON/YAML file (Intrinsics fields, or the output of `cellctl calibrate intrinsics`) "
        "or 'fx,fy,cx,cy' in pixels",
    )
    p.add_argument(
        "--camera-pose",
        default=None,
        metavar='"x y z qx qy qz qw"',
        help="camera optical frame in the robot base frame (m, quaternion xyzw); default identity",
    )
    p.add_argument("--catalog", default=None, help="bin catalog YAML (default: the config's catalog)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--draw", default=None, metavar="PNG", help="write the image with corners and board axes")
    add_config_arguments(p)
    p.set_defaults(func=run_identify)

    c = sub.add_parser("calibrate", help="camera calibration: hand-eye (over the bus) and intrinsics (from images)")
    csub = c.add_subparsers(dest="what", metavar="WHAT", required=True)
    he = csub.add_parser("hand-eye", help="move the arm around the board in view and solve T_flange_cam")
    he.add_argument("--views", type=int, default=12, help="arm poses to try (default 12)")
    he.add_argument("--distance", type=float, default=None, help="camera-board distance in m (default: current)")
    he.add_argument("--seed", type=int, default=0)
    he.add_argument("--catalog", default=None, help="bin catalog YAML (default: the config's catalog)")
    he.add_argument("--out", default=DEFAULT_HAND_EYE, help=f"result JSON (default {DEFAULT_HAND_EYE})")
    add_config_arguments(he)
    he.set_defaults(func=run_hand_eye)
    it = csub.add_parser("intrinsics", help="calibrate the camera from a folder of board images")
    it.add_argument("--images", required=True, help="folder of PNG/JPEG board views (≥ 6, varied angles)")
    it.add_argument("--catalog", default=None, help="bin catalog YAML (default: the config's catalog)")
    it.add_argument("--out", default=DEFAULT_INTRINSICS, help=f"result JSON (default {DEFAULT_INTRINSICS})")
    add_config_arguments(it)
    it.set_defaults(func=run_intrinsics)


def parse_intrinsics(text: str, width: int, height: int) -> Any:
    """``fx,fy,cx,cy`` or a JSON/YAML file → :class:`cellctl.messages.Intrinsics`.

    Raises:
        CellError: neither four numbers nor a readable file with intrinsics fields.
    """
    from pydantic import ValidationError

    from cellctl.config import safe_yaml_load
    from cellctl.messages import Intrinsics

    path = Path(text)
    if path.is_file():
        data = safe_yaml_load(path.read_text(), str(path))
        if isinstance(data, dict) and "intrinsics" in data:
            data = data["intrinsics"]
        if not isinstance(data, dict):
            raise CellError(f"--intrinsics file {text!r} holds {type(data).__name__}, expected a mapping")
        data = {"width": width, "height": height, **data}
        try:
            return Intrinsics.model_validate(data)
        except ValidationError as err:
            raise CellError(f"--intrinsics file {text!r} is not valid intrinsics: {err}") from None
    parts = text.replace(" ", "").split(",")
    try:
        fx, fy, cx, cy = (float(x) for x in parts)
    except ValueError:
        raise CellError(
            f"--intrinsics {text!r} is neither an existing file nor four numbers 'fx,fy,cx,cy' (pixels)"
        ) from None
    if fx <= 0 or fy <= 0:
        raise CellError(f"--intrinsics {text!r}: fx and fy must be positive pixels")
    return Intrinsics(width=width, height=height, fx=fx, fy=fy, cx=cx, cy=cy)


def parse_camera_pose(text: str | None) -> Any:
    """``"x y z qx qy qz qw"`` (m, xyzw) → 4×4 ``T_base_cam``; ``None`` → identity."""
    import numpy as np

    from cellctl.geometry.transforms import transform_from_pose

    if text is None:
        return np.eye(4)
    try:
        v = [float(x) for x in text.replace(",", " ").split()]
    except ValueError:
        v = []
    if len(v) != 7:
        raise CellError(f"--camera-pose {text!r}: expected 7 numbers 'x y z qx qy qz qw' (metres, quaternion xyzw)")
    q = np.asarray(v[3:])
    if not np.isfinite(v).all() or np.linalg.norm(q) < 1e-9:
        raise CellError(f"--camera-pose {text!r}: the quaternion {v[3:]} is not a rotation")
    return transform_from_pose((v[:3], v[3:]))


def _catalog(args: argparse.Namespace, cfg: Any) -> Any:
    from cellctl.geometry.catalog import load_catalog

    path = Path(args.catalog) if args.catalog else cfg.path(cfg.catalog)
    return load_catalog(path, root=cfg.root, verify_meshes=False)


def _draw(path: str, image: Any, intr: Any, ident: Any) -> None:
    import cv2
    import numpy as np

    out = image.copy()
    pts = ident.image_points.reshape(-1, 1, 2).astype(np.float32)
    ids = np.asarray(ident.corner_ids, dtype=np.int32).reshape(-1, 1)
    cv2.aruco.drawDetectedCornersCharuco(out, pts, ids, (0, 255, 0))
    rvec = cv2.Rodrigues(ident.T_cam_board[:3, :3])[0]
    length = 0.5 * min(ident.board_size_m)
    cv2.drawFrameAxes(out, intr.K(), np.asarray(intr.dist, float), rvec, ident.T_cam_board[:3, 3], length, 2)
    cv2.putText(
        out,
        f"{ident.bin_type}  {ident.n_corners} corners  {ident.reproj_rms_px:.2f} px",
        (10, 30),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.8,
        (0, 255, 255),
        2,
    )
    if not cv2.imwrite(path, out):
        raise CellError(f"--draw {path!r}: cannot write the image there")


def run_identify(args: argparse.Namespace) -> int:
    from cellctl.errors import IdentificationError
    from cellctl.images import decode_image
    from cellctl.vision import identify

    cfg = config_from_args(args)
    if not Path(args.image).is_file():
        raise CellError(f"image {args.image!r} does not exist")
    # the shared decoder: the header's size is checked against the budget before any pixel is decoded
    image = decode_image(
        Path(args.image).read_bytes(), repr(args.image), order="bgr", max_pixels=cfg.camera.max_image_pixels
    )
    intr = parse_intrinsics(args.intrinsics, image.shape[1], image.shape[0])
    T_base_cam = parse_camera_pose(args.camera_pose)
    catalog = _catalog(args, cfg)
    try:
        ident = identify(image, intr, T_base_cam, catalog)
    except IdentificationError as err:
        if args.json:
            print(json.dumps({"identified": False, "code": getattr(err, "code", None), "reason": str(err)}))
            return 1
        raise
    if args.draw:
        _draw(args.draw, image, intr, ident)
    d = ident.to_dict()
    if args.json:
        print(json.dumps({"identified": True, **d}, indent=2))
        return 0
    p, q = d["T_base_bin"]["position"], d["T_base_bin"]["orientation"]
    print(f"bin type      {ident.bin_type}")
    print(
        f"T_base_bin    xyz {p[0]:+.4f} {p[1]:+.4f} {p[2]:+.4f} m   "
        f"q(xyzw) {q[0]:+.5f} {q[1]:+.5f} {q[2]:+.5f} {q[3]:+.5f}"
    )
    print(f"distance      {ident.distance_m:.3f} m")
    print(f"corners       {ident.n_corners} (markers {ident.marker_ids})")
    print(f"reprojection  {ident.reproj_rms_px:.3f} px RMS, {ident.reproj_max_px:.3f} px max")
    print(f"ambiguity     {ident.ambiguity_ratio:.3f} (IPPE solutions {ident.ippe_gap_deg:.1f}° apart)")
    print(f"1-σ           {ident.sigma_trans_mm:.2f} mm, {ident.sigma_rot_deg:.3f}° (pixel noise only)")
    return 0


def _write_json(path: str, cfg: Any, data: dict[str, Any]) -> Path:
    out = cfg.path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    tmp.replace(out)  # atomic: a crash never leaves half a calibration
    return out


def run_hand_eye(args: argparse.Namespace) -> int:
    from cellctl.bus.session import open_session
    from cellctl.messages import now_iso
    from cellctl.vision.collect import collect_hand_eye

    if args.views < 3:
        raise CellError(f"--views {args.views}: hand-eye needs at least 3 views")
    cfg = config_from_args(args)
    catalog = _catalog(args, cfg)
    with open_session(cfg, "client") as session:
        result, views, skipped = collect_hand_eye(session, cfg, catalog, args.views, args.distance, args.seed)
    data = {
        "type": "cellctl/HandEyeCalibration",
        "stamp": now_iso(),
        "method": "park-martin",
        **result.to_dict(),
        "views": [v.index for v in views],
        "skipped": skipped,
    }
    out = _write_json(args.out, cfg, data)
    r = result.to_dict()
    print(json.dumps({k: r[k] for k in ("T_flange_cam", "n_views", "residual_mm", "residual_deg")}, indent=2))
    print(f"wrote {out}", file=sys.stderr)
    return 0


def run_intrinsics(args: argparse.Namespace) -> int:
    from cellctl.messages import now_iso
    from cellctl.vision.intrinsics import calibrate_intrinsics, load_images

    cfg = config_from_args(args)
    catalog = _catalog(args, cfg)
    res = calibrate_intrinsics(load_images(args.images), catalog, progress=True)
    data = {"type": "cellctl/IntrinsicsCalibration", "stamp": now_iso(), **res.to_dict()}
    out = _write_json(args.out, cfg, data)
    print(json.dumps({k: data[k] for k in ("intrinsics", "rms_px", "fx_rel_std_pct")}, indent=2))
    print(f"wrote {out}", file=sys.stderr)
    k = res.intrinsics
    print(
        "to use it, set in the cell config: "
        f"camera: {{fx: {k.fx:.3f}, fy: {k.fy:.3f}, cx: {k.cx:.3f}, cy: {k.cy:.3f}}}"
        + (f"  (distortion {[round(x, 5) for x in k.dist]} is in the file)" if any(k.dist) else ""),
        file=sys.stderr,
    )
    return 0
