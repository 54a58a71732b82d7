"""Bin identification from one image: ChArUco markers → bin type, board pose → bin pose.

Pipeline (see docs/decisions.md, "## Vision"):

1. ArUco markers of the catalog's shared dictionary (sub-pixel corner refinement);
2. bin type from the marker-id ranges (every type owns a disjoint range);
3. ChArUco corners of that board only (foreign markers are not passed on);
4. checks: enough corners, not collinear;
5. IPPE (``solvePnPGeneric``, both planar solutions) → ambiguity ratio, then LM refinement;
6. ``T_base_bin = T_base_cam · T_cam_board · T_board_bin``.

Any failure raises :class:`~cellctl.errors.IdentificationError` whose message starts with a
reason (``no markers``, ``markers from two boards``, ``unknown id range``, ``only N corners``,
``collinear corners``, ``ambiguous IPPE solution``, ``reprojection error``) and names the
offending values; ``err.code`` holds the reason as a short identifier.

Light module (numpy + cv2): the supervisor imports it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.errors import IdentificationError
from cellctl.geometry.transforms import check_transform, invert, pose_from_transform, transform_from
from cellctl.messages import Intrinsics
from cellctl.vision.board import KnownBoard, board_centre, boards_from_catalog, get_dictionary

__all__ = ["IdentifySettings", "Identification", "detector_parameters", "identify", "not_identified"]


@dataclass(frozen=True)
class IdentifySettings:
    """Thresholds of :func:`identify` (defaults justified in docs/decisions.md).

    Attributes:
        min_corners: fewest ChArUco corners accepted for a pose (≥ 4 for IPPE; 6 for margin).
        min_board_markers: markers a board needs to count as "in view" (one stray marker from
            another range is noise, two are a second board).
        max_ambiguity_ratio: reject when IPPE's best/second reprojection error ratio exceeds this
            *and* the two solutions differ by more than ``ambiguity_gap_deg``.
        ambiguity_gap_deg: below this rotation difference both IPPE solutions are equivalent.
        max_reproj_px: reject a refined pose whose RMS reprojection error exceeds this (pixels).
        pixel_sigma_floor_px: lower bound of the per-corner noise used for the pose covariance.
    """

    min_corners: int = 6
    min_board_markers: int = 2
    max_ambiguity_ratio: float = 0.5
    ambiguity_gap_deg: float = 2.0
    max_reproj_px: float = 1.5
    pixel_sigma_floor_px: float = 0.05


@dataclass(frozen=True)
class Identification:
    """One view's identification: bin type and pose, with the evidence behind them.

    Attributes:
        bin_type: catalog name of the identified bin type.
        T_base_bin: 4×4, bin mesh frame → robot base frame (metres).
        T_cam_board: 4×4, board frame → camera optical frame.
        T_base_cam: 4×4 camera pose used (robot FK · hand-eye).
        T_bin_board: 4×4 from the catalog.
        marker_ids: ids of the board's markers that were detected.
        ignored_ids: detected ids not used (stray markers of other ranges).
        corner_ids: ChArUco corner ids used for the pose.
        image_points: (N, 2) pixel positions of those corners.
        reproj_rms_px: RMS reprojection error of the refined pose, pixels.
        reproj_max_px: largest single-corner reprojection error, pixels.
        ambiguity_ratio: IPPE best / second-best reprojection error (0 = unambiguous, 1 = tie).
        ippe_gap_deg: rotation between the two IPPE solutions, degrees.
        sigma_trans_mm: 1-σ position uncertainty of the board centre from the pose covariance, mm.
        sigma_rot_deg: 1-σ rotation uncertainty (largest axis), degrees.
        distance_m: camera-to-board-centre distance, metres.
        elapsed_ms: wall time of the identification, milliseconds.
        image_size: (width, height) in pixels.
    """

    bin_type: str
    T_base_bin: NDArray[np.float64]
    T_cam_board: NDArray[np.float64]
    T_base_cam: NDArray[np.float64]
    T_bin_board: NDArray[np.float64]
    marker_ids: list[int]
    ignored_ids: list[int]
    corner_ids: list[int]
    image_points: NDArray[np.float64]
    reproj_rms_px: float
    reproj_max_px: float
    ambiguity_ratio: float
    ippe_gap_deg: float
    sigma_trans_mm: float
    sigma_rot_deg: float
    distance_m: float
    elapsed_ms: float
    image_size: tuple[int, int]
    board_size_m: tuple[float, float] = (0.0, 0.0)
    """Chessboard width (x) and height (y) of the identified board, metres."""
    cov_board: NDArray[np.float64] = field(repr=False, default_factory=lambda: np.zeros((6, 6)))
    """6×6 covariance of (board-centre position in camera frame [m], rotation vector [rad])."""

    @property
    def n_corners(self) -> int:
        return len(self.corner_ids)

    @property
    def T_cam_bin(self) -> NDArray[np.float64]:
        return self.T_cam_board @ invert(self.T_bin_board)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (poses as ``{"position": [...], "orientation": [xyzw]}``)."""

        def pose(T: NDArray[np.float64]) -> dict[str, list[float]]:
            p, q = pose_from_transform(T)
            return {"position": list(p), "orientation": list(q)}

        return {
            "bin_type": self.bin_type,
            "T_base_bin": pose(self.T_base_bin),
            "T_cam_board": pose(self.T_cam_board),
            "T_base_cam": pose(self.T_base_cam),
            "marker_ids": self.marker_ids,
            "ignored_ids": self.ignored_ids,
            "n_corners": self.n_corners,
            "corner_ids": self.corner_ids,
            "reproj_rms_px": round(self.reproj_rms_px, 4),
            "reproj_max_px": round(self.reproj_max_px, 4),
            "ambiguity_ratio": round(self.ambiguity_ratio, 4),
            "ippe_gap_deg": round(self.ippe_gap_deg, 3),
            "sigma_trans_mm": round(self.sigma_trans_mm, 4),
            "sigma_rot_deg": round(self.sigma_rot_deg, 5),
            "distance_m": round(self.distance_m, 4),
            "elapsed_ms": round(self.elapsed_ms, 2),
            "image_size": list(self.image_size),
        }


def not_identified(code: str, message: str) -> IdentificationError:
    """An IdentificationError carrying a short reason code in ``.code``."""
    err = IdentificationError(message)
    err.code = code  # type: ignore[attr-defined]
    return err


def detector_parameters() -> Any:
    """ArUco detector parameters used everywhere (sub-pixel marker corners)."""
    dp = cv2.aruco.DetectorParameters()
    dp.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return dp


def _gray(image: Any, intr: Intrinsics) -> NDArray[np.uint8]:
    if not isinstance(image, np.ndarray):
        raise not_identified("bad image", f"image must be a numpy array (BGR or grey), got {type(image).__name__}")
    if image.ndim == 3 and image.shape[2] == 3:
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    elif image.ndim == 3 and image.shape[2] == 4:
        gray = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    elif image.ndim == 2:
        gray = image
    else:
        raise not_identified("bad image", f"image shape {image.shape} is not (H, W), (H, W, 3) or (H, W, 4)")
    if gray.dtype != np.uint8:
        if gray.dtype == np.uint16:
            gray = (gray >> 8).astype(np.uint8)
        else:
            raise not_identified("bad image", f"image dtype {gray.dtype} is not uint8 or uint16")
    h, w = gray.shape
    if (w, h) != (intr.width, intr.height):
        raise not_identified(
            "bad image", f"image is {w}×{h} px but the intrinsics are for {intr.width}×{intr.height} px"
        )
    return gray


def _quality_hint(gray: NDArray[np.uint8]) -> str:
    """Why a detector may have found nothing: saturation, darkness, blur (for the reason text)."""
    sat = float(np.mean(gray >= 250))
    dark = float(np.mean(gray <= 5))
    sharp = float(cv2.Laplacian(gray, cv2.CV_32F).var())
    hints = []
    if sat > 0.3:
        hints.append(f"{sat:.0%} of pixels saturated: overexposed?")
    if dark > 0.5:
        hints.append(f"{dark:.0%} of pixels black: underexposed or lens covered?")
    if sharp < 20.0:
        hints.append(f"sharpness (Laplacian variance) {sharp:.1f} < 20: blurred?")
    return f" ({'; '.join(hints)})" if hints else ""


def _rot_deg(R: NDArray[np.float64]) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def _pose_covariance(
    obj: NDArray[np.float64],
    img: NDArray[np.float64],
    rvec: NDArray[np.float64],
    tvec: NDArray[np.float64],
    K: NDArray[np.float64],
    dist: NDArray[np.float64],
    centre: NDArray[np.float64],
    sigma_floor: float,
) -> tuple[NDArray[np.float64], float, float]:
    """Covariance of (board-centre position, rotation vector) from the PnP Jacobian.

    σ² is the residual variance (2N − 6 degrees of freedom), floored at ``sigma_floor``² so a
    lucky near-zero residual does not claim impossible precision.
    """
    proj, J = cv2.projectPoints(obj, rvec, tvec, K, dist)
    res = (proj.reshape(-1, 2) - img).ravel()
    dof = max(1, res.size - 6)
    s2 = max(float(res @ res) / dof, sigma_floor**2)
    Jp = J[:, :6]
    try:
        cov_rt = s2 * np.linalg.inv(Jp.T @ Jp)
    except np.linalg.LinAlgError:
        cov_rt = np.full((6, 6), np.inf)
    # Board centre in the camera: p = R(r) c + t; Jacobian wrt (r, t) by central differences.
    Jc = np.zeros((3, 6))
    eps = 1e-6
    for i in range(3):
        d = np.zeros(3)
        d[i] = eps
        Rp = cv2.Rodrigues(rvec.ravel() + d)[0]
        Rm = cv2.Rodrigues(rvec.ravel() - d)[0]
        Jc[:, i] = (Rp @ centre - Rm @ centre) / (2 * eps)
    Jc[:, 3:] = np.eye(3)
    A = np.zeros((6, 6))
    A[:3] = Jc
    A[3:, :3] = np.eye(3)
    cov = A @ cov_rt @ A.T
    sig_t = float(np.sqrt(max(np.trace(cov[:3, :3]), 0.0))) * 1000.0
    sig_r = float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(cov[3:, 3:]).max(), 0.0))))
    return cov, sig_t, sig_r


@dataclass(frozen=True)
class _BoardCorners:
    """The ChArUco corners of the one board in view, matched to the board's points."""

    name: str
    kb: KnownBoard
    marker_ids: list[int]
    ignored_ids: list[int]
    corner_ids: list[int]
    obj: NDArray[np.float64]
    """Corner positions on the board (N, 3), metres."""
    img: NDArray[np.float64]
    """Corner positions in the image (N, 2), pixels."""


@dataclass(frozen=True)
class _PnP:
    """The refined board pose in the camera and how unique it is."""

    rms: float
    rvec: Any
    """Rotation vector (3, 1), as cv2 returns it (an array or a ``cv2.Mat``)."""
    tvec: Any
    """Translation (3, 1), metres."""
    ratio: float
    gap: float


def identify(
    image_bgr: NDArray[np.uint8],
    intrinsics: Intrinsics,
    T_base_cam: Any,
    catalog: Any,
    settings: IdentifySettings | None = None,
) -> Identification:
    """Identify the bin type and its pose from one camera image.

    Args:
        image_bgr: the image, BGR (H, W, 3) or grey (H, W), uint8; size must match ``intrinsics``.
        intrinsics: the camera's pinhole intrinsics and distortion (pixels).
        T_base_cam: 4×4 camera optical frame → robot base frame at capture time
            (``T_base_flange · T_flange_cam``); ``None`` means identity (poses in the camera frame).
        catalog: the bin catalog (see :func:`cellctl.vision.board.boards_from_catalog`).
        settings: thresholds; defaults to :class:`IdentifySettings`.

    Returns:
        The identification with ``T_base_bin`` and the evidence (ids, corners, errors).

    Raises:
        IdentificationError: the bin cannot be identified; the message says why and ``.code``
            is one of ``bad image``, ``no markers``, ``too few markers``, ``unknown id range``,
            ``two boards``, ``too few corners``, ``collinear``, ``ambiguous``, ``reprojection``.
    """
    t0 = time.perf_counter()
    st = settings or IdentifySettings()
    T_bc = np.eye(4) if T_base_cam is None else check_transform(T_base_cam, "T_base_cam")
    boards: list[KnownBoard] = boards_from_catalog(catalog)
    gray = _gray(image_bgr, intrinsics)
    K = intrinsics.K()
    dist = np.asarray(intrinsics.dist, dtype=np.float64)
    bc = _board_corners(gray, boards, st)
    pnp = _solve_pnp(bc, K, dist, st)
    kb, obj, img, rvec, tvec = bc.kb, bc.obj, bc.img, pnp.rvec, pnp.tvec
    proj = cv2.projectPoints(obj, rvec, tvec, K, dist)[0].reshape(-1, 2)
    res = np.linalg.norm(proj - img, axis=1)
    if pnp.rms > st.max_reproj_px:
        raise not_identified(
            "reprojection",
            f"reprojection error {pnp.rms:.2f} px RMS > {st.max_reproj_px} px over {len(obj)} corners "
            f"of board {bc.name!r}: "
            "wrong intrinsics, motion blur or a bent board?",
        )
    R = cv2.Rodrigues(rvec)[0]
    T_cam_board = transform_from(R, tvec.ravel())
    centre = board_centre(kb.spec)
    cov, sig_t, sig_r = _pose_covariance(obj, img, rvec, tvec, K, dist, centre, st.pixel_sigma_floor_px)
    T_base_bin = T_bc @ T_cam_board @ invert(kb.T_bin_board)
    return Identification(
        bin_type=bc.name,
        T_base_bin=T_base_bin,
        T_cam_board=T_cam_board,
        T_base_cam=T_bc,
        T_bin_board=kb.T_bin_board,
        marker_ids=bc.marker_ids,
        ignored_ids=bc.ignored_ids,
        corner_ids=bc.corner_ids,
        image_points=img,
        reproj_rms_px=pnp.rms,
        reproj_max_px=float(res.max()),
        ambiguity_ratio=pnp.ratio,
        ippe_gap_deg=pnp.gap,
        sigma_trans_mm=sig_t,
        sigma_rot_deg=sig_r,
        distance_m=float(np.linalg.norm(R @ centre + tvec.ravel())),
        elapsed_ms=(time.perf_counter() - t0) * 1000.0,
        image_size=(int(gray.shape[1]), int(gray.shape[0])),
        board_size_m=(
            float(kb.spec.squares_x * kb.spec.square_m),
            float(kb.spec.squares_y * kb.spec.square_m),
        ),
        cov_board=cov,
    )


def _board_corners(gray: NDArray[np.uint8], boards: list[KnownBoard], st: IdentifySettings) -> _BoardCorners:
    """Markers → the one board in view (by id range) → its ChArUco corners, checked (count, not collinear)."""
    dic = get_dictionary(boards[0].spec.dictionary)
    dp = detector_parameters()
    mcorners, mids, _rejected = cv2.aruco.ArucoDetector(dic, dp).detectMarkers(gray)
    if mids is None or len(mids) == 0:
        raise not_identified(
            "no markers",
            f"no markers detected in the {gray.shape[1]}×{gray.shape[0]} image" + _quality_hint(gray),
        )
    ids = [int(i) for i in mids.ravel()]
    name, kb = _board_in_view(ids, boards, st, gray)
    sel = [j for j, i in enumerate(ids) if kb.id_range[0] <= i <= kb.id_range[1]]
    ignored = sorted(int(ids[j]) for j in range(len(ids)) if j not in sel)

    # --- ChArUco corners of that board ------------------------------------------------------
    det = cv2.aruco.CharucoDetector(kb.board, cv2.aruco.CharucoParameters(), dp)
    mc_sel = tuple(mcorners[j] for j in sel)
    mi_sel = mids[sel].reshape(-1, 1)
    ccorners, cids, _, _ = det.detectBoard(gray, markerCorners=mc_sel, markerIds=mi_sel)
    n = 0 if cids is None else len(cids)
    if n < st.min_corners:
        raise not_identified(
            "too few corners",
            f"only {n} corners (need ≥ {st.min_corners}) of board {name!r} from markers "
            f"{sorted(int(ids[j]) for j in sel)}: partial board or occluded?",
        )
    cid = [int(i) for i in cids.ravel()]
    if kb.board.checkCharucoCornersCollinear(cids):
        raise not_identified(
            "collinear", f"collinear corners: ids {sorted(cid)} lie on one line; the pose is not determined"
        )
    obj, img = kb.board.matchImagePoints(ccorners, cids)
    obj = obj.reshape(-1, 3).astype(np.float64)
    img = img.reshape(-1, 2).astype(np.float64)
    return _BoardCorners(name, kb, sorted(int(ids[j]) for j in sel), ignored, cid, obj, img)


def _board_in_view(
    ids: list[int], boards: list[KnownBoard], st: IdentifySettings, gray: NDArray[np.uint8]
) -> tuple[str, KnownBoard]:
    """The bin type whose id range holds enough of the detected markers (exactly one may)."""
    per_board = {k.bin_type: [i for i in ids if k.id_range[0] <= i <= k.id_range[1]] for k in boards}
    known = {i for v in per_board.values() for i in v}
    unknown = sorted(int(i) for i in ids if i not in known)
    present = {name: v for name, v in per_board.items() if len(v) >= st.min_board_markers}
    if len(present) >= 2:
        desc = "; ".join(f"{n}: ids {sorted(v)}" for n, v in present.items())
        raise not_identified("two boards", f"markers from two boards in one image: {desc}")
    if not present:
        if unknown and not known:
            ranges = ", ".join(f"{k.bin_type} {k.id_range[0]}..{k.id_range[1]}" for k in boards)
            raise not_identified(
                "unknown id range",
                f"unknown id range: ids {unknown} belong to no catalog board (known: {ranges})",
            )
        raise not_identified(
            "too few markers",
            f"only {len(ids)} marker(s) detected (ids {sorted(ids)}); a board needs "
            f"≥ {st.min_board_markers} of its markers in view" + _quality_hint(gray),
        )
    name = next(iter(present))
    return name, next(k for k in boards if k.bin_type == name)


def _solve_pnp(bc: _BoardCorners, K: NDArray[np.float64], dist: NDArray[np.float64], st: IdentifySettings) -> _PnP:
    """IPPE (both planar solutions), each refined with LM; refused when the best is not unique."""
    obj, img, n, name = bc.obj, bc.img, len(bc.obj), bc.name
    nsol, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
    if nsol < 1:
        raise not_identified("ambiguous", f"IPPE found no pose for {n} corners of board {name!r}")
    # Refine every IPPE solution with LM: near head-on views both converge to the same pose
    # (no ambiguity); a genuine two-fold ambiguity keeps two distinct minima whose residuals
    # are compared.
    sols = []
    for k in range(nsol):
        rv, tv = cv2.solvePnPRefineLM(obj, img, K, dist, rvecs[k].copy(), tvecs[k].copy())
        pr = cv2.projectPoints(obj, rv, tv, K, dist)[0].reshape(-1, 2)
        sols.append((float(np.sqrt(np.mean(np.sum((pr - img) ** 2, axis=1)))), rv, tv))
    sols.sort(key=lambda x: x[0])
    rms, rvec, tvec = sols[0]
    if len(sols) >= 2:
        rms2, rvec2, _ = sols[1]
        gap = _rot_deg(cv2.Rodrigues(rvec)[0].T @ cv2.Rodrigues(rvec2)[0])
        ratio = rms / rms2 if rms2 > 0 else 1.0
        if gap <= st.ambiguity_gap_deg:  # both minima are the same pose
            ratio = 0.0
    else:
        ratio, gap = 0.0, 0.0
    if ratio > st.max_ambiguity_ratio:
        raise not_identified(
            "ambiguous",
            f"ambiguous IPPE solution ratio {ratio:.2f} > {st.max_ambiguity_ratio} (best {rms:.3f} px, "
            f"second {sols[1][0]:.3f} px RMS after refinement, solutions {gap:.1f}° apart): board too small "
            f"or too far for a unique pose ({n} corners)",
        )
    return _PnP(rms, rvec, tvec, ratio, gap)
