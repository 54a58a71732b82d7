"""The unseen site: steel, light and camera that no model here was trained or calibrated on.

A plant has its own steel finish, its own lamps and its own camera. This generator stands in for
one (``cellctl dataset contam --site unseen``); it is used only to *test* enrollment
(:mod:`cellctl.classify.proof`) and never trains a model. What differs from the training
generator (:func:`~cellctl.classify.contamination.closeup_steel`, :class:`~cellctl.classify.contamination.Optics`)
and from the held-out shifted one (:mod:`cellctl.classify.shifted`), *in kind* rather than in range:

* **finish** — external: *bead-blasted* (an isotropic, directionless matte grain with mottling;
  training's external steel is brushed, with a grain direction) or *orbital-sanded* (overlapping
  circular swirl marks); internal: *electropolished* mirror reflecting a tube-lit ceiling (long
  parallel bright bars, slightly bent by the sheet's curvature) and a ring light (a bright
  annulus), over a darker, cooler base (training's polished steel reflects blurred blobs, dark
  silhouettes and rectangular window panels);
* **light geometry** — an on-axis ring light (a round hot spot on matte steel) and raking light
  from one side (a strong one-sided fall-off); training lights with an anisotropic lobe;
* **camera** — a lamp colour cast (cool LED, sodium-warm or fluorescent-green, a fixed per-site
  cast, not a per-image white-balance jitter), off-centre cos⁴ vignetting, barrel distortion,
  rolling-shutter row banding, and JPEG at quality 30–60 on every image (training: 60–95 on half).

The dirt is the training families plus the held-out ones (:data:`SITE_FAMILIES`), labelled by the
one visibility rule (:func:`~cellctl.classify.contamination.visible_mask` at the model's input,
:func:`~cellctl.classify.sample.label_from_mask`); the geometric optics warp the opacity with the
image so the mask stays where the dirt is. Same layout as ``cellctl dataset contam``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.classify.collect import LABELS, check_surface
from cellctl.classify.contam_dataset import append_provenance, write_draws
from cellctl.classify.contamination import (
    F32,
    FAMILIES,
    MODEL_INPUT_PX,
    VISIBLE_ALPHA,
    composite,
    draw_family,
    visible_mask,
)
from cellctl.classify.sample import label_from_mask
from cellctl.classify.shifted import HELD_OUT_FAMILIES
from cellctl.classify.texture import fbm
from cellctl.errors import ClassifierError

__all__ = ["SITE_FAMILIES", "SITE_GENERATOR", "SITES", "SiteOptics", "site_dataset", "site_draw", "site_steel"]

SITE_GENERATOR = "cellctl-site/1"
"""Version of this generator (``synth.json``)."""
SITES = ("unseen",)
"""Site variants this module draws."""
SITE_FAMILIES = {**FAMILIES, **HELD_OUT_FAMILIES}
"""Dirt at the unseen site: whatever the last product left, known families or not."""
LAMP_CASTS = {
    "led_cool": (0.88, 1.0, 1.18),
    "sodium_warm": (1.2, 1.0, 0.72),
    "fluorescent_green": (0.92, 1.12, 0.95),
}
"""Per-site lamp colour casts (RGB gains); one is drawn per image, jittered by ±3 %."""


def _norm(x: F32) -> F32:
    return ((x - x.mean()) / (x.std() + 1e-6)).astype(np.float32)


def _bead_blasted(h: int, w: int, rng: np.random.Generator) -> F32:
    """Isotropic matte grain: blurred white noise (no direction) plus low-frequency mottling."""
    grain = _norm(cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), float(rng.uniform(0.6, 1.1))))
    mottle = fbm((h, w), rng, 4, 6) - 0.5
    return float(rng.uniform(0.5, 0.64)) + float(rng.uniform(0.04, 0.07)) * grain + 0.08 * mottle


def _orbital(h: int, w: int, rng: np.random.Generator) -> F32:
    """Orbital-sanded: many overlapping circular scratch arcs on a fine isotropic ground."""
    marks = np.zeros((h, w), np.float32)
    for _ in range(int(rng.integers(80, 180))):
        c = (int(rng.uniform(-0.1, 1.1) * w), int(rng.uniform(-0.1, 1.1) * h))
        r = int(rng.uniform(0.04, 0.25) * max(h, w)) + 3
        a0 = float(rng.uniform(0, 360))
        cv2.ellipse(marks, c, (r, r), 0, a0, a0 + float(rng.uniform(60, 300)), float(rng.uniform(0.3, 1.0)), 1)
    ground = _norm(cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 0.7))
    return (
        float(rng.uniform(0.52, 0.66))
        + 0.025 * ground
        + float(rng.uniform(0.025, 0.05)) * _norm(cv2.GaussianBlur(marks, (0, 0), 0.5))
        + 0.06 * (fbm((h, w), rng, 3, 3) - 0.5)
    )


def _electropolished(h: int, w: int, rng: np.random.Generator) -> F32:
    """A dark cool mirror reflecting ceiling tubes (long parallel bars) and a ring light (annulus)."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    env = cv2.GaussianBlur(fbm((h, w), rng, 2, 2), (0, 0), max(h, w) / 16)
    base = float(rng.uniform(0.1, 0.2)) + 0.15 * env
    ang = float(rng.uniform(0, np.pi))
    d = np.array([np.cos(ang), np.sin(ang)], np.float32)
    across = -d[1] * (xx - w / 2) + d[0] * (yy - h / 2)
    along = d[0] * (xx - w / 2) + d[1] * (yy - h / 2)
    across = across - float(rng.uniform(-0.0008, 0.0008)) * along * along  # curvature bends the bars
    spacing = float(rng.uniform(0.15, 0.35) * max(h, w))
    width = float(rng.uniform(2.0, 6.0))
    offset = float(rng.uniform(0, spacing))
    bars = np.zeros((h, w), np.float32)
    for k in range(-4, 5):
        centre = offset + k * spacing
        bars = np.maximum(bars, (np.abs(across - centre) < width).astype(np.float32))
    base = base + float(rng.uniform(0.5, 0.8)) * cv2.GaussianBlur(bars, (0, 0), 0.8)
    if rng.random() < 0.7:
        ring = np.zeros((h, w), np.float32)
        c = (int(rng.uniform(0.2, 0.8) * w), int(rng.uniform(0.2, 0.8) * h))
        cv2.circle(ring, c, int(rng.uniform(0.06, 0.2) * max(h, w)) + 4, 1.0, int(rng.integers(2, 5)))
        base = base + float(rng.uniform(0.5, 0.8)) * cv2.GaussianBlur(ring, (0, 0), 0.8)
    return base + 0.01 * (rng.random((h, w)).astype(np.float32) - 0.5)


def site_steel(surface: str, h: int, w: int, rng: np.random.Generator) -> tuple[F32, str]:
    """A clean close-up of the unseen site's steel under its light: ``(RGB (H, W, 3) in [0, 1], finish)``."""
    check_surface(surface)
    if surface == "external":
        finish = "bead_blasted" if rng.random() < 0.6 else "orbital"
        grey = _bead_blasted(h, w, rng) if finish == "bead_blasted" else _orbital(h, w, rng)
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        # on-axis ring light: a broad round hot spot on the matte finish
        c = rng.uniform([0.25 * w, 0.25 * h], [0.75 * w, 0.75 * h])
        r2 = ((xx - c[0]) ** 2 + (yy - c[1]) ** 2) / (float(rng.uniform(0.25, 0.5)) * max(h, w)) ** 2
        grey = grey * (1.0 + float(rng.uniform(0.15, 0.4)) * np.exp(-r2))
        tint = np.array([1.0, 1.0, 1.0], np.float32)
    else:
        finish = "electropolished"
        grey = _electropolished(h, w, rng)
        tint = np.array([0.94, 0.98, 1.06], np.float32)  # a cool mirror
    # raking light from one side: one-sided fall-off across the frame
    ang = float(rng.uniform(0, 2 * np.pi))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    t = (np.cos(ang) * (xx / w - 0.5) + np.sin(ang) * (yy / h - 0.5)) + 0.5
    grey = grey * (float(rng.uniform(0.55, 0.8)) + float(rng.uniform(0.3, 0.6)) * np.clip(t, 0, 1))
    return np.clip(grey[..., None] * tint, 0, 1).astype(np.float32), finish


@dataclass(frozen=True)
class SiteOptics:
    """The site camera (drawn per image, applied to a draw's clean and dirty versions alike)."""

    lamp: str
    cast: tuple[float, float, float]
    vignette: float
    vignette_centre: tuple[float, float]
    barrel_k1: float
    banding: float
    banding_period: float
    noise_sigma: float
    jpeg_quality: int
    noise_seed: int

    @staticmethod
    def draw(rng: np.random.Generator) -> SiteOptics:
        lamp = str(rng.choice(list(LAMP_CASTS)))
        return SiteOptics(
            lamp=lamp,
            cast=tuple(float(c * rng.uniform(0.97, 1.03)) for c in LAMP_CASTS[lamp]),  # type: ignore[arg-type]
            vignette=float(rng.uniform(0.3, 0.6)),
            vignette_centre=(float(rng.uniform(-0.2, 0.2)), float(rng.uniform(-0.2, 0.2))),
            barrel_k1=float(rng.uniform(0.04, 0.12)),
            banding=float(rng.uniform(0.01, 0.025)),
            banding_period=float(rng.uniform(6, 24)),
            noise_sigma=float(rng.uniform(2.0, 6.0)),
            jpeg_quality=int(rng.integers(30, 61)),
            noise_seed=int(rng.integers(2**31)),
        )

    def warp(self, x: np.ndarray) -> np.ndarray:
        """Barrel distortion (applied to the image and to the contamination's opacity alike)."""
        h, w = x.shape[:2]
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        u, v = (xx - w / 2) / (w / 2), (yy - h / 2) / (h / 2)
        # scaled so the corners sample the frame's own corners (no border reflections)
        f = (1.0 + self.barrel_k1 * (u * u + v * v)) / (1.0 + 2.0 * self.barrel_k1)
        mx, my = (u * f) * (w / 2) + w / 2, (v * f) * (h / 2) + h / 2
        return cv2.remap(x.astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)

    def apply(self, img: F32) -> NDArray[np.uint8]:
        h, w = img.shape[:2]
        x = self.warp(img)
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        cu, cv_ = self.vignette_centre
        r2 = ((xx / w - 0.5 - cu) * 2) ** 2 + ((yy / h - 0.5 - cv_) * 2) ** 2
        cos4 = 1.0 / (1.0 + 0.5 * r2) ** 2  # cos⁴ of the field angle, off the optical axis
        x = x * (1.0 - self.vignette * (1.0 - cos4))[..., None]
        rows = 1.0 + self.banding * np.sin(2 * np.pi * np.arange(h, dtype=np.float32) / self.banding_period)
        x = np.clip(x * rows[:, None, None] * np.asarray(self.cast, np.float32), 0, 1) * 255.0
        x = x + np.random.default_rng(self.noise_seed).normal(0, self.noise_sigma, x.shape).astype(np.float32)
        out = np.clip(x + 0.5, 0, 255).astype(np.uint8)
        ok, buf = cv2.imencode(
            ".jpg", cv2.cvtColor(out, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality]
        )
        if not ok:
            raise ClassifierError(f"JPEG encoding at quality {self.jpeg_quality} failed")
        return cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def site_draw(
    dirty: bool, surface: str, size: int, rng: np.random.Generator, families: dict | None = None
) -> tuple[NDArray[np.uint8], F32, str, dict[str, Any]] | None:
    """One labelled image of the unseen site ``(rgb, visible mask, label, info)``, None when ambiguous."""
    table = SITE_FAMILIES if families is None else families
    opt = SiteOptics.draw(rng)
    h = size if surface == "internal" or rng.random() < 0.5 else int(size * 9 / 16)
    base, finish = site_steel(surface, h, size, rng)
    clean_img = opt.apply(base)
    info: dict[str, Any] = {"base": finish, "params": {"lamp": opt.lamp, "jpeg": opt.jpeg_quality}}
    if not dirty:
        return clean_img, np.zeros((h, size), np.float32), "clean", {**info, "family": "none"}
    names = list(table)
    picks = [names[int(rng.integers(len(names)))] for _ in range(1 + int(rng.random() < 0.2))]
    img, alpha = base, np.zeros((h, size), np.float32)
    for name in picks:
        img, a = composite(img, draw_family(name, h, size, rng, table))
        alpha = np.maximum(alpha, a)
    dirty_img = opt.apply(img)
    alpha = np.clip(opt.warp(alpha), 0, 1)
    seen = visible_mask(dirty_img, clean_img, alpha, at_px=MODEL_INPUT_PX)
    if label_from_mask(seen, present=float((alpha >= VISIBLE_ALPHA).mean())) != "dirty":
        return None
    vis = (cv2.resize(seen, (size, h), interpolation=cv2.INTER_NEAREST) > 0) & (alpha >= VISIBLE_ALPHA)
    return dirty_img, vis.astype(np.float32), "dirty", {**info, "family": "+".join(picks)}


def site_dataset(
    out: Path | str,
    surface: str,
    n_clean: int,
    n_dirty: int,
    *,
    seed: int = 0,
    site: str = "unseen",
    size: int = 256,
    max_tries: int = 20,
) -> dict[str, Any]:
    """Write ``n_clean`` clean and ``n_dirty`` dirty images of the site into ``out/<surface>/``
    (the ``cellctl dataset contam`` layout); returns the provenance summary (also in ``synth.json``).

    Raises:
        ClassifierError: unknown site, negative counts, or a generator that keeps drawing ambiguous images.
    """
    check_surface(surface)
    if site not in SITES:
        raise ClassifierError(f"site {site!r} is unknown; expected one of {list(SITES)}")
    if n_clean < 0 or n_dirty < 0 or n_clean + n_dirty == 0:
        raise ClassifierError(f"counts clean={n_clean} dirty={n_dirty} must be >= 0 and not both 0")
    rng = np.random.default_rng([seed, 3, 0 if surface == "external" else 1, 91])
    base_dir = Path(out) / surface
    for sub in (*LABELS, "masks"):
        (base_dir / sub).mkdir(parents=True, exist_ok=True)
    intents = np.r_[np.zeros(n_clean, bool), np.ones(n_dirty, bool)]
    rng.shuffle(intents)
    t0 = time.perf_counter()

    def draw(dirty: bool) -> tuple[NDArray[np.uint8], F32, str, dict[str, Any]] | None:
        return site_draw(dirty, surface, size, rng)

    stem = f"site_{surface}_{seed}"
    drawn = write_draws(base_dir, stem, intents, draw, max_tries, f"site {site} {surface}")
    summary = {
        "generator": SITE_GENERATOR,
        "site": site,
        "out": str(base_dir),
        "surface": surface,
        "seed": seed,
        "size": size,
        "n": n_clean + n_dirty,
        "families": sorted(SITE_FAMILIES),
        **drawn,
        "seconds": round(time.perf_counter() - t0, 1),
    }
    append_provenance(base_dir, summary)
    return summary
