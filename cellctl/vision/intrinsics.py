"""Camera-intrinsics calibration from ChArUco board views (``cv2.calibrateCamera``).

Pose accuracy is dominated by the focal length: a 0.5 % fx error moves the board by ~0.5 %
of its distance (5 mm at 1 m), so the cell calibrates its own camera from many board views
rather than trusting factory intrinsics. Any catalog board may be used, even several.

Light module (numpy + cv2).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.errors import CellError, IdentificationError
from cellctl.messages import Intrinsics
from cellctl.vision.board import boards_from_catalog, get_dictionary
from cellctl.vision.identify import detector_parameters

__all__ = ["BoardView", "IntrinsicsResult", "calibrate_intrinsics", "detect_board_corners", "load_images"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass(frozen=True)
class BoardView:
    """ChArUco corners of one image: object points (N, 3) m and image points (N, 2) px."""

    name: str
    bin_type: str
    obj: NDArray[np.float32]
    img: NDArray[np.float32]


@dataclass(frozen=True)
class IntrinsicsResult:
    """A calibration: intrinsics, fit quality and the 1-σ uncertainty of the parameters.

    Attributes:
        intrinsics: the calibrated pinhole + distortion model.
        rms_px: overall RMS reprojection error, pixels.
        per_view_rms_px: RMS reprojection error per used view, pixels.
        views: names of the used views; skipped: ``name: reason`` of the others.
        std_fx, std_fy, std_cx, std_cy: 1-σ of the parameters, pixels.
    """

    intrinsics: Intrinsics
    rms_px: float
    per_view_rms_px: list[float]
    views: list[str]
    skipped: list[str]
    std_fx: float
    std_fy: float
    std_cx: float
    std_cy: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "intrinsics": self.intrinsics.model_dump(),
            "rms_px": round(self.rms_px, 4),
            "per_view_rms_px": [round(x, 4) for x in self.per_view_rms_px],
            "std_px": {"fx": self.std_fx, "fy": self.std_fy, "cx": self.std_cx, "cy": self.std_cy},
            "fx_rel_std_pct": round(100.0 * self.std_fx / self.intrinsics.fx, 4),
            "views": self.views,
            "skipped": self.skipped,
        }


def detect_board_corners(gray: NDArray[np.uint8], catalog: Any, min_corners: int = 8) -> tuple[str, Any, Any]:
    """ChArUco corners of the (single) catalog board most present in ``gray``.

    Returns:
        ``(bin_type, obj_points (N, 3), img_points (N, 2))``.

    Raises:
        IdentificationError: no markers, no catalog board, too few or collinear corners.
    """
    boards = boards_from_catalog(catalog)
    dp = detector_parameters()
    mc, mids, _ = cv2.aruco.ArucoDetector(get_dictionary(boards[0].spec.dictionary), dp).detectMarkers(gray)
    if mids is None or len(mids) == 0:  # OpenCV returns None or an empty array for no markers
        raise IdentificationError("no markers detected")
    ids = mids.ravel()
    counts = [int(np.sum((ids >= k.id_range[0]) & (ids <= k.id_range[1]))) for k in boards]
    kb = boards[int(np.argmax(counts))]
    if max(counts) < 2:
        raise IdentificationError(f"no catalog board in view: marker ids {sorted(ids.tolist())}")
    sel = [j for j, i in enumerate(ids) if kb.id_range[0] <= i <= kb.id_range[1]]
    det = cv2.aruco.CharucoDetector(kb.board, cv2.aruco.CharucoParameters(), dp)
    cc, cids, _, _ = det.detectBoard(gray, markerCorners=tuple(mc[j] for j in sel), markerIds=mids[sel])
    n = 0 if cids is None else len(cids)
    if n < min_corners:
        raise IdentificationError(f"only {n} corners (need ≥ {min_corners})")
    if kb.board.checkCharucoCornersCollinear(cids):
        raise IdentificationError(f"collinear corners: ids {sorted(cids.ravel().tolist())}")
    obj, img = kb.board.matchImagePoints(cc, cids)
    return kb.bin_type, obj.reshape(-1, 3).astype(np.float32), img.reshape(-1, 2).astype(np.float32)


def load_images(folder: Path | str) -> list[tuple[str, NDArray[np.uint8]]]:
    """Grey images of a folder (sorted by name).

    Raises:
        CellError: the folder does not exist or holds no readable image.
    """
    p = Path(folder)
    if not p.is_dir():
        raise CellError(f"image folder {str(p)!r} does not exist")
    out = []
    for f in sorted(p.iterdir()):
        if f.suffix.lower() in IMAGE_SUFFIXES:
            img = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
            if img is not None:
                out.append((f.name, img))
    if not out:
        raise CellError(f"image folder {str(p)!r} holds no readable images ({', '.join(IMAGE_SUFFIXES)})")
    return out


def calibrate_intrinsics(
    images: Iterable[tuple[str, NDArray[np.uint8]]],
    catalog: Any,
    *,
    min_views: int = 6,
    fix_k3: bool = True,
    progress: bool = False,
) -> IntrinsicsResult:
    """Calibrate a camera from ChArUco board views.

    Args:
        images: ``(name, grey or BGR uint8 image)`` pairs, all the same size.
        catalog: the bin catalog (its boards are detected; views may show different boards).
        min_views: fewest usable views accepted.
        fix_k3: keep k3 = 0 (the sixth-order term overfits with few views).
        progress: show a tqdm bar on stderr.

    Returns:
        The calibration with per-view errors and parameter standard deviations.

    Raises:
        CellError: images of different sizes, or fewer than ``min_views`` usable views (the
            message lists why each skipped view was skipped).
    """
    views: list[BoardView] = []
    skipped: list[str] = []
    size: tuple[int, int] | None = None
    items: Sequence[tuple[str, NDArray[np.uint8]]] = list(images)
    it: Iterable[tuple[str, NDArray[np.uint8]]] = items
    if progress:
        from tqdm import tqdm

        it = tqdm(items, desc="detect boards", unit="img")
    for name, im in it:
        gray = cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) if im.ndim == 3 else im
        s = (gray.shape[1], gray.shape[0])
        if size is None:
            size = s
        elif s != size:
            raise CellError(f"image {name!r} is {s[0]}×{s[1]} px; the first image was {size[0]}×{size[1]} px")
        try:
            bt, obj, img = detect_board_corners(gray, catalog)
        except IdentificationError as err:
            skipped.append(f"{name}: {err}")
            continue
        views.append(BoardView(name, bt, obj, img))
    if len(views) < min_views or size is None:
        raise CellError(
            f"intrinsics calibration needs ≥ {min_views} usable board views, got {len(views)}"
            + (f"; skipped: {skipped}" if skipped else "")
        )
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    rms, K, dist, _r, _t, std_in, _std_ex, per_view = cv2.calibrateCameraExtended(
        [v.obj for v in views], [v.img for v in views], size, None, None, flags=flags
    )
    d = [float(x) for x in np.asarray(dist).ravel()[:5]]
    intr = Intrinsics(
        width=size[0],
        height=size[1],
        fx=float(K[0, 0]),
        fy=float(K[1, 1]),
        cx=float(K[0, 2]),
        cy=float(K[1, 2]),
        dist=d + [0.0] * (5 - len(d)),
    )
    sd = np.asarray(std_in).ravel()
    return IntrinsicsResult(
        intrinsics=intr,
        rms_px=float(rms),
        per_view_rms_px=[float(x) for x in np.asarray(per_view).ravel()],
        views=[v.name for v in views],
        skipped=skipped,
        std_fx=float(sd[0]),
        std_fy=float(sd[1]),
        std_cx=float(sd[2]),
        std_cy=float(sd[3]),
    )
