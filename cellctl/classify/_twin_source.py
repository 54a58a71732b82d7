"""The twin's camera as a dataset source (:func:`make_twin_source`), used by ``synth``.

Viewpoints are sampled poses facing the requested surface (the paper's external
viewpoints look along −normal from 0.3–0.8 m; internal ones radiate from the top opening):

* external: a point on an external face (area-weighted), camera on its normal at
  0.3–0.8 m, tilted up to ~20°, random roll about the optical axis;
* internal: a point on an internal face, camera inside the top opening (within 60 % of the
  hole radius, 0–15 cm above the rim), looking at it, random roll.

A *dirty* draw seeds powder (amount U(0.2, 1)) and aims near one of its clumps on the
requested surface (offset up to 10 cm, so powder is not always centred); a *clean* draw seeds
none. A view is kept only if at least half of its pixels show the requested surface. The
label then comes from the rendered powder mask, restricted to pixels the powder visibly
changes (a second render of the dirty view without powder, same light and noise seed; see
:mod:`cellctl.classify.synth`).

Images are rendered at low resolution (``size`` px wide, the D435's 16:9 aspect): the
classifier input is 128 px and the ray-traced render at 256×144 takes ~25 ms instead of
~0.4 s at 1280×720. The classifier squashes every image to a square the same way at
inference, so training and deployment see the same geometry.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from cellctl.classify.sample import MIN_CONTRAST, MIN_VISIBLE_FRACTION, Sample
from cellctl.errors import ClassifierError

__all__ = ["make_twin_source"]

MIN_SURFACE_FRACTION = 0.5


PLANNED_FRACTION = 0.5
"""Share of images taken from planned viewpoints when plans exist in ``planner.plans_dir``; the
rest are sampled facing the surface, so the set also covers views a future plan may choose."""


def _planned_views(cfg: Any, names: list[str], surface: str) -> dict[str, list[np.ndarray]]:
    """``T_bin_cam`` of every reachable viewpoint of the cached plans, per bin type."""
    from cellctl.planning.planfile import list_plans

    out: dict[str, list[np.ndarray]] = {}
    for name in names:
        plans, _ = list_plans(cfg.path(cfg.planner.plans_dir), name, surface)
        views = [np.array(vp.T_bin_cam) for pl in plans for vp in (pl.reachable or pl.viewpoints)]
        if views:
            out[name] = views
    return out


def make_twin_source(surface: str, size: int, shifted: bool, seed: int, config: Any) -> Callable:
    """A ``draw(rng, dirty) -> Sample`` function rendering with :class:`cellctl.sim.render.SimRenderer`."""
    from cellctl.config import load_config
    from cellctl.geometry.camera import D435_COLOR
    from cellctl.geometry.catalog import load_catalog
    from cellctl.sim.render import SimRenderer
    from cellctl.surface import FACE_TAG, check_surface

    cfg = config if config is not None else load_config()
    catalog = load_catalog(cfg.path(cfg.catalog), cfg.root)
    names = list(catalog.names)
    if not names:
        raise ClassifierError(f"bin catalog {cfg.catalog} lists no bin types")
    renderer = SimRenderer(catalog)
    intr = D435_COLOR.scaled(size / D435_COLOR.width)
    tag = FACE_TAG[check_surface(surface, ClassifierError)]
    meshes = {}
    for name in names:
        mesh = catalog.load_mesh(name)
        faces = np.flatnonzero(mesh.surface == tag)
        if len(faces):
            areas = mesh.areas[faces]
            meshes[name] = (mesh, faces, areas / areas.sum())
    if not meshes:
        raise ClassifierError(f"no bin type in the catalog has {surface} faces")
    usable = sorted(meshes)
    planned = _planned_views(cfg, usable, surface)
    return _TwinSource(surface, shifted, catalog, renderer, intr, tag, meshes, usable, planned)


def _render_params(rng: np.random.Generator, shifted: bool) -> tuple[Any, dict[str, Any]]:
    """Light, exposure, powder colour and noise of one render (wider and warmer when ``shifted``); as recorded."""
    from cellctl.sim.render import RenderParams

    if not shifted:
        p = RenderParams(
            exposure=float(rng.uniform(0.75, 1.3)),
            light_scale=float(rng.uniform(0.75, 1.25)),
            light_offset=tuple(float(v) for v in rng.uniform([-0.4, -0.4, -0.3], [0.4, 0.4, 0.3])),
            powder_rgb=tuple(float(v) for v in rng.uniform(0.86, 0.96) * rng.uniform(0.98, 1.0, 3)),
            noise_sigma=float(rng.uniform(0.5, 3.0)),
            ambient=float(rng.uniform(0.12, 0.2)),
        )
    else:
        # Shifted: warm yellowish powder, harsher light, more sensor noise.
        p = RenderParams(
            exposure=float(rng.uniform(0.55, 1.6)),
            light_scale=float(rng.uniform(0.5, 1.6)),
            light_offset=tuple(float(v) for v in rng.uniform([-1.0, -1.0, -0.8], [1.0, 1.0, 0.5])),
            powder_rgb=tuple(float(v) for v in np.array([0.95, 0.86, 0.58]) * rng.uniform(0.9, 1.0)),
            noise_sigma=float(rng.uniform(4.0, 8.0)),
            ambient=float(rng.uniform(0.06, 0.3)),
        )
    return p, {k: (list(v) if isinstance(v, tuple) else round(v, 4)) for k, v in p.__dict__.items()}


def _point_on(mesh: Any, face: int, rng: np.random.Generator) -> np.ndarray:
    """A uniform random point of triangle ``face``."""
    tri = mesh.vertices[mesh.faces[face]]
    u, v = rng.uniform(size=2)
    if u + v > 1:
        u, v = 1 - u, 1 - v
    return tri[0] + u * (tri[1] - tri[0]) + v * (tri[2] - tri[0])


def _camera(
    catalog: Any, surface: str, name: str, target: np.ndarray, normal: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """``T_bin_cam`` of a sampled view of ``target``: on its normal (external) or from the top opening (internal)."""
    from cellctl.geometry.transforms import look_at, rotation_about, transform_from

    bt = catalog.get(name)
    if surface == "external":
        n = normal / np.linalg.norm(normal)
        tilt = rng.normal(0, 0.2, 3)
        d = n + tilt - (tilt @ n) * n
        eye = target + rng.uniform(0.3, 0.8) * d / np.linalg.norm(d)
    else:
        r = bt.top_hole_radius_m * 0.6 * np.sqrt(rng.uniform())
        a = rng.uniform(0, 2 * np.pi)
        eye = np.array([r * np.cos(a), r * np.sin(a), rng.uniform(0.0, 0.15)])
    up = (0.0, 0.0, 1.0) if abs((target - eye)[2]) < 0.95 * np.linalg.norm(target - eye) else (1.0, 0.0, 0.0)
    T = look_at(eye, target, up)
    roll = rotation_about((0.0, 0.0, 1.0), float(rng.uniform(-np.pi, np.pi)))
    return T @ transform_from(roll, np.zeros(3))


@dataclass
class _TwinSource:
    """The ``draw(rng, dirty) -> Sample`` of :func:`make_twin_source`: the catalog's meshes, rendered."""

    surface: str
    shifted: bool
    catalog: Any
    renderer: Any
    intr: Any
    tag: int
    meshes: dict[str, tuple[Any, np.ndarray, np.ndarray]]
    """Per usable bin type: its mesh, the faces of the surface, their area weights."""
    usable: list[str]
    planned: dict[str, list[np.ndarray]]

    def __call__(self, rng: np.random.Generator, dirty: bool) -> Sample:
        for _ in range(30):
            sample = self._try(rng, dirty)
            if sample is not None:
                return sample
        raise ClassifierError(
            f"30 sampled {self.surface} viewpoints in a row did not show the surface; check the catalog"
        )

    def _target(
        self, name: str, dirty: bool, amount: float, pseed: int, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The point a view aims at and its normal: near a powder clump (dirty) or anywhere on the surface."""
        mesh, faces, w = self.meshes[name]
        normals = mesh.normals
        if dirty:
            field = self.renderer.powder(name, True, amount, pseed)
            mine = np.flatnonzero(field.surface == self.tag)
            if len(mine) == 0:
                return None
            k = int(rng.choice(mine))
            off = rng.normal(0, 0.05, 3)
            n = field.normals[k]
            return field.centres[k] + off - (off @ n) * n, n
        face = int(rng.choice(faces, p=w))
        return _point_on(mesh, face, rng), normals[face]

    def _view(
        self, name: str, target: np.ndarray, normal: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, str]:
        """``T_bin_cam`` and where it came from: sampled, or (sometimes) a cached plan's viewpoint, jittered."""
        from cellctl.geometry.transforms import rotation_about, transform_from

        T_bin_cam = _camera(self.catalog, self.surface, name, target, normal, rng)
        if self.planned.get(name) and rng.uniform() < PLANNED_FRACTION:
            # a planned viewpoint of the cached plans, jittered as a parked robot would see it
            views = self.planned[name]
            T_bin_cam = views[int(rng.integers(len(views)))].copy()
            T_bin_cam[:3, 3] += rng.uniform(-0.02, 0.02, 3)
            T_bin_cam = T_bin_cam @ transform_from(
                rotation_about((0.0, 0.0, 1.0), float(rng.uniform(-0.3, 0.3))), np.zeros(3)
            )
            return T_bin_cam, "planned"
        return T_bin_cam, "sampled"

    def _try(self, rng: np.random.Generator, dirty: bool) -> Sample | None:
        """One drawn view, or None when it does not show enough surface (or, planned, the powder)."""
        name = self.usable[int(rng.integers(len(self.usable)))]
        pseed = int(rng.integers(2**31))
        amount = float(rng.uniform(0.2, 1.0)) if dirty else 0.0
        aim = self._target(name, dirty, amount, pseed, rng)
        if aim is None:
            return None
        T_bin_cam, source = self._view(name, *aim, rng)
        rp, pdict = _render_params(rng, self.shifted)
        out = self.renderer.render_bin_view(
            name, T_bin_cam, self.intr, dirty=dirty, powder_amount=amount, seed=pseed, params=rp
        )
        if float((out.surface == self.tag).mean()) < MIN_SURFACE_FRACTION:
            return None
        visible = out.powder_mask.copy()
        if dirty and visible.any():
            # Same view, light and sensor-noise seed without powder: the difference is
            # exactly what the powder does to the image.
            bare = self.renderer.render_bin_view(
                name, T_bin_cam, self.intr, dirty=False, powder_amount=0.0, seed=pseed, params=rp
            )
            diff = np.abs(out.rgb.astype(np.int16) - bare.rgb.astype(np.int16)).max(axis=2)
            visible &= diff >= MIN_CONTRAST
        if dirty and source == "planned" and visible.mean() < MIN_VISIBLE_FRACTION:
            return None  # the powder is not where this planned view looks; draw again
        return Sample(
            out.rgb,
            visible.astype(np.float32),
            {
                "bin": name,
                "powder_amount": round(amount, 3),
                "powder_seed": pseed,
                "powder_in_view": round(float(out.powder_mask.mean()), 5),
                **pdict,
                "eye_bin": [round(float(v), 3) for v in T_bin_cam[:3, 3]],
                "viewpoint": source,
            },
            surface=out.surface == self.tag,
        )
