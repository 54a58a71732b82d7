"""``cellctl bench pose``: board-pose accuracy against ground truth at 0.5–2 m.

For each distance, ``n`` seeded views of the configured bin type's board are rendered
(exact pinhole homography of the board texture, 3× supersampled, lighting gradient, optical
blur 0.4–0.9 px, Gaussian noise σ 1–3 grey levels; tilt 0–40° about a random in-plane axis,
roll ±15°, board centre anywhere in the central 30 % of the image) with the configured
camera intrinsics, and identified with :func:`cellctl.vision.identify`. The same images are
identified again with fx, fy 0.5 % too large (a focal-length calibration error).

Errors: ``trans_mm`` is the board-centre position error (the point the camera measures);
``bin_origin_mm`` the error at the bin origin (adds the lever arm of the rotation error);
``rot_deg`` the rotation error. Percentiles are over identified views only;
``identified`` counts them.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from cellctl.errors import IdentificationError
from cellctl.geometry.transforms import invert, pose_error
from cellctl.messages import Intrinsics
from cellctl.vision.board import BoardSpec, board_centre
from cellctl.vision.identify import identify
from cellctl.vision.render import RenderSettings, random_view, render_boards

__all__ = ["DISTANCES_M", "bench_pose", "configured_intrinsics", "measure"]

DISTANCES_M = (0.5, 1.0, 1.5, 2.0)
D435_FX_PER_WIDTH = 910.0 / 1280.0
"""RealSense D435 colour stream: fx ≈ fy ≈ 910 px at 1280×720 (≈ 70° horizontal field)."""


def configured_intrinsics(cfg: Any) -> Intrinsics:
    """Camera intrinsics from the config's camera section.

    Uses ``camera.fx/fy/cx/cy`` (or ``camera.intrinsics``) when the section has them,
    otherwise a D435 colour model scaled to ``camera.width × camera.height``.
    """
    cam = cfg.camera
    intr = getattr(cam, "intrinsics", None)
    if intr is not None:
        return intr if isinstance(intr, Intrinsics) else Intrinsics.model_validate(intr)
    w, h = int(cam.width), int(cam.height)
    fx = float(getattr(cam, "fx", None) or D435_FX_PER_WIDTH * w)
    fy = float(getattr(cam, "fy", None) or fx)
    cx = float(getattr(cam, "cx", None) or w / 2.0)
    cy = float(getattr(cam, "cy", None) or h / 2.0)
    return Intrinsics(width=w, height=h, fx=fx, fy=fy, cx=cx, cy=cy)


def _pct(x: list[float]) -> dict[str, float | None]:
    if not x:
        return {"p50": None, "p95": None, "max": None}
    a = np.asarray(x)
    return {"p50": round(float(np.percentile(a, 50)), 4), "p95": round(float(np.percentile(a, 95)), 4),
            "max": round(float(a.max()), 4)}


def _errors(spec: Any, T_true: np.ndarray, T_est: np.ndarray) -> tuple[float, float, float]:
    c = board_centre(spec)
    dt = float(np.linalg.norm((T_true[:3, :3] @ c + T_true[:3, 3]) - (T_est[:3, :3] @ c + T_est[:3, 3]))) * 1000
    T_board_bin = invert(np.asarray(getattr(spec, "T_bin_board", np.eye(4)), dtype=np.float64))
    db = pose_error(T_true @ T_board_bin, T_est @ T_board_bin)[0] * 1000
    dr = float(np.degrees(pose_error(T_true, T_est)[1]))
    return dt, dr, db


def measure(
    spec: Any, intr: Intrinsics, n: int, seed: int, distances: tuple[float, ...] = DISTANCES_M,
    focal_error: float = 0.005, progress: bool = True,
) -> dict[str, Any]:
    """Render and identify ``n`` views per distance; percentiles of the errors.

    Args:
        spec: the board spec (catalog ``BoardSpec`` or :class:`cellctl.vision.board.BoardSpec`).
        intr: the true camera intrinsics (used to render and to identify).
        n: views per distance.
        seed: RNG seed (views, lighting, noise).
        distances: camera-to-board-centre distances, metres.
        focal_error: relative focal-length error for the second identification pass.
        progress: tqdm bar on stderr.
    """
    from tqdm import tqdm

    catalog = {"bench": spec}
    biased = intr.model_copy(update={"fx": intr.fx * (1 + focal_error), "fy": intr.fy * (1 + focal_error)})
    rng = np.random.default_rng(seed)
    rows, rows_f = [], []
    times: list[float] = []
    bar = tqdm(total=n * len(distances), desc="bench pose", unit="view", disable=not progress)
    for d in distances:
        acc: dict[str, list[float]] = {"t": [], "r": [], "b": [], "tf": [], "rf": [], "bf": []}
        fails: dict[str, int] = {}
        fails_f: dict[str, int] = {}
        for _ in range(n):
            T = random_view(spec, intr, d, rng)
            st = RenderSettings(noise_sigma=float(rng.uniform(1.0, 3.0)), blur_sigma=float(rng.uniform(0.4, 0.9)))
            img = render_boards([(spec, T)], intr, st, rng)
            t0 = time.perf_counter()
            try:
                ident = identify(img, intr, None, catalog)
                times.append((time.perf_counter() - t0) * 1000)
                dt, dr, db = _errors(spec, T, ident.T_cam_board)
                acc["t"].append(dt)
                acc["r"].append(dr)
                acc["b"].append(db)
            except IdentificationError as err:
                code = getattr(err, "code", "error")
                fails[code] = fails.get(code, 0) + 1
            try:
                ident_f = identify(img, biased, None, catalog)
                dt, dr, db = _errors(spec, T, ident_f.T_cam_board)
                acc["tf"].append(dt)
                acc["rf"].append(dr)
                acc["bf"].append(db)
            except IdentificationError as err:
                code = getattr(err, "code", "error")
                fails_f[code] = fails_f.get(code, 0) + 1
            bar.update(1)
        rows.append({"distance_m": d, "n": n, "identified": len(acc["t"]), "trans_mm": _pct(acc["t"]),
                     "rot_deg": _pct(acc["r"]), "bin_origin_mm": _pct(acc["b"]), "not_identified": fails})
        rows_f.append({"distance_m": d, "n": n, "identified": len(acc["tf"]), "trans_mm": _pct(acc["tf"]),
                       "rot_deg": _pct(acc["rf"]), "bin_origin_mm": _pct(acc["bf"]), "not_identified": fails_f})
    bar.close()
    return {"distances": rows, "focal_error_0_5pct": {"distances": rows_f},
            "ms_per_identification": round(float(np.mean(times)), 2) if times else None}


def _targets(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The issue's targets: ≤ 2 mm and ≤ 0.2° p95 at ≤ 1 m; ≤ 5 mm p95 at 2 m (all views identified)."""
    def ok(r: dict[str, Any], mm: float, deg: float | None) -> bool:
        if r["identified"] < r["n"] or r["trans_mm"]["p95"] is None:
            return False
        return r["trans_mm"]["p95"] <= mm and (deg is None or r["rot_deg"]["p95"] <= deg)

    near = [r for r in rows if r["distance_m"] <= 1.0]
    far = [r for r in rows if abs(r["distance_m"] - 2.0) < 1e-9]
    return {
        "le_1m_2mm_0.2deg_p95": all(ok(r, 2.0, 0.2) for r in near),
        "at_2m_5mm_p95": all(ok(r, 5.0, None) for r in far),
    }


def _spec_dict(spec: Any) -> dict[str, Any]:
    return {"squares": [int(spec.squares_x), int(spec.squares_y)], "square_m": float(spec.square_m),
            "marker_m": float(spec.marker_m), "dictionary": str(spec.dictionary),
            "size_m": [round(spec.squares_x * spec.square_m, 4), round(spec.squares_y * spec.square_m, 4)]}


def bench_pose(args: argparse.Namespace) -> dict[str, Any]:
    """``cellctl bench pose``: see the module docstring. ``args.n`` views per distance (default 40)."""
    from cellctl.cli import config_from_args
    from cellctl.geometry.catalog import load_catalog

    cfg = config_from_args(args)
    n = int(args.n or 40)
    seed = int(args.seed)
    intr = configured_intrinsics(cfg)
    catalog = load_catalog(cfg.path(cfg.catalog), root=cfg.root, verify_meshes=False)
    bin_type = cfg.sim.bin_type if cfg.sim.bin_type in catalog else catalog.names[0]
    spec = catalog.get(bin_type).board
    t0 = time.perf_counter()
    main = measure(spec, intr, n, seed)
    out: dict[str, Any] = {
        "distances": main["distances"],
        "ms_per_identification": main["ms_per_identification"],
        "focal_error_0_5pct": main["focal_error_0_5pct"],
        "mode": "single_view",
        "seed": seed,
        "bin_type": bin_type,
        "board": _spec_dict(spec),
        "intrinsics": intr.model_dump(),
        "renderer": "pinhole homography of the board texture, 3x supersampled (cellctl.vision.render)",
        "targets_met": _targets(main["distances"]),
    }
    # The board size decides the 2 m result: also measure the board the vision notes recommend.
    big = BoardSpec(squares_x=7, squares_y=5, square_m=0.06, marker_m=0.045, dictionary=str(spec.dictionary),
                    first_id=int(spec.first_id), T_bin_board=np.asarray(spec.T_bin_board, dtype=np.float64))
    if abs(float(spec.square_m) - big.square_m) > 1e-9:
        alt = measure(big, intr, n, seed)
        out["alternative_board"] = {"board": _spec_dict(big), "distances": alt["distances"],
                                    "focal_error_0_5pct": alt["focal_error_0_5pct"],
                                    "targets_met": _targets(alt["distances"])}
    out["wall_s"] = round(time.perf_counter() - t0, 1)
    return out
