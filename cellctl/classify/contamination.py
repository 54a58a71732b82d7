"""Contamination that is not one powder model: families composited onto clean steel, with masks.

A plant's contamination is whatever the last product or the last wash left. Each *family*
draws an opacity map ``alpha`` (H, W) and the colour it lays down; :func:`composite` puts it on
a clean base image (a twin render or a close-up steel texture, :func:`closeup_steel`) the way
that material looks on steel:

================ ==========================================================================
family           what it draws
================ ==========================================================================
``powder``       clumps (thresholded fBm) + log-normal grains; colour white…cream…grey…
                 brown…pink…blue, fine or coarse grain, sparse or dense; matte, lit like
                 the surface under it
``film``         a thin haze/film over a large soft region: lowers contrast, blurs and dims
                 the reflections under it, slight tint
``streak``       wipe marks: a few parallel curved bands with brush texture along them
``droplet``      liquid droplets (dark rim, bright specular dot) and dried rings (whitish
                 mineral rim, clearer centre)
``fibre``        thin curved threads, 1–2 px, white / blue / dark / coloured
``fingerprint``  elliptical ridge patterns of skin oil: low-contrast, greasy
``soot``         a dark matte smudge (soot, carbon, ink, rubber): irregular fractal outline,
                 patchy opacity, neutral or blue-black
``tarnish``      a darker-than-steel translucent film (oily/wet patch, discolouration): the
                 steel under it times a transmission 0.35–0.8, large soft elongated region
================ ==========================================================================

Optics (:func:`optics`) then vary blur, exposure, white balance, sensor noise and JPEG for
the clean and the dirty version of a draw alike (same parameters, same noise seed), so that
the *visible* mask is exactly what contamination changes in the final image: a pixel shows
contamination when its opacity is ≥ :data:`VISIBLE_ALPHA` and the patch around it changes in
mean colour by ΔE*ab ≥ :data:`MIN_DELTA_E` or in RMS contrast by ≥ :data:`MIN_CONTRAST_L` L* and
a factor :data:`CONTRAST_RATIO`
— judged at the classifier's input size (:data:`MODEL_INPUT_PX`), where a hair-thin fibre
averages away.
Images are labelled by :func:`~cellctl.classify.sample.label_from_mask` on that visible map
(the twin's rule).

The held-out families and optics of the shifted generator live in
:mod:`cellctl.classify.shifted` and are never drawn here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.classify.texture import Look, fbm, steel_image
from cellctl.errors import ClassifierError

__all__ = [
    "FAMILIES",
    "VISIBLE_ALPHA",
    "Layer",
    "Optics",
    "closeup_steel",
    "composite",
    "draw_family",
    "optics",
    "visible_mask",
    "MODEL_INPUT_PX",
    "CONTRAST_RATIO",
    "MIN_CONTRAST_L",
    "MIN_DELTA_E",
    "PATCH_SIGMA",
    "CLUTTER_K",
    "RING_SIGMA",
    "local_variation",
]

VISIBLE_ALPHA = 0.1
"""Opacity from which a contaminated pixel can count as visible (films are thin: 0.3–0.65)."""
PATCH_SIGMA = 2.0
"""Gaussian window (px at the model input, ~5 px wide: a third of a detector patch) over which
:func:`visible_mask` compares the dirty and the clean image."""
MIN_DELTA_E = 5.0
"""Patch mean colour difference (CIELAB ΔE*ab) from which contamination counts as visible: about
two just-noticeable differences (JND ≈ 2.3), where an untrained observer calls two colours
different at a glance; well above the training optics' noise on a patch mean (σ ≤ 5 grey levels
over ~25 px: < 0.5 ΔE)."""
MIN_CONTRAST_L = 3.0
"""Smallest patch RMS-contrast change (L* units) that counts as visible texture change: about
the brushed grain's own RMS contrast at the model input (~3.5 L*; polished ~1.1)."""
CONTRAST_RATIO = 2.0
"""...and the change must also be by this factor (contrast halved or doubled). Contrast
discrimination on a visible texture follows Weber's law (a just-noticeable change is ~25 % of
the texture's own contrast, Legge & Foley 1980), so a fixed L* step is invisible on strong grain:
a factor 2 is about two such steps, the same margin as :data:`MIN_DELTA_E` over a colour JND.
Without it, a light film over coarse brushed grain (a σ 1.5 px veil: the grain drops by > 3 L*,
the picture barely changes) was labelled dirty and set the false-clean threshold."""
CLUTTER_K = 2.0
"""A patch change must also be ≥ this many times the natural variation of the same measure
(patch mean colour, patch RMS contrast) in the patch's own surroundings in the same image
(:data:`RING_SIGMA`, uncontaminated pixels only) to count as visible: a change smaller than
what the clean steel around it already varies by — a film lifting a dark mirror reflection of
the polished steel, where reflection brightness is random — looks like more of the same
surface in a single image. Chosen on a held-out draw of the training generator (seed 11, not
the shifted set): see ``docs/classifier/detector.md``, "Label rule, round 5"."""
RING_SIGMA = 6.0
"""Gaussian scale (px at the model input, ~1.5 detector patches) of the surroundings whose
natural variation :data:`CLUTTER_K` compares a change with."""
MODEL_INPUT_PX = 128
"""Side of the square the classifiers see; labels judge visibility there (:func:`visible_mask`)."""

F32 = NDArray[np.float32]


@dataclass(frozen=True)
class Layer:
    """One drawn contamination: opacity ``alpha`` (H, W), colour ``rgb`` (H, W, 3) in [0, 1].

    ``mode`` says how it meets the steel: ``matte`` (covers, lit like the surface under it),
    ``film`` (veils: lowers contrast and blurs reflections), ``absorb`` (a translucent dark film:
    the steel times the layer's transmission ``rgb``), ``gloss`` (liquid: darkens, adds
    a specular dot).
    """

    alpha: F32
    rgb: F32
    mode: str
    family: str
    params: dict


def _soft(x: F32, sigma: float) -> F32:
    return cv2.GaussianBlur(x.astype(np.float32), (0, 0), max(0.3, sigma))


def _const(h: int, w: int, c: NDArray) -> F32:
    return np.broadcast_to(np.asarray(c, np.float32), (h, w, 3)).copy()


POWDER_COLOURS = {
    "white": (0.93, 0.93, 0.91),
    "cream": (0.92, 0.87, 0.74),
    "grey": (0.62, 0.62, 0.62),
    "brown": (0.55, 0.40, 0.26),
    "pink": (0.90, 0.68, 0.72),
    "blue": (0.55, 0.66, 0.88),
    "dark": (0.22, 0.21, 0.20),
}
"""Powder albedos drawn from (another product's colour is what a plant sees)."""


def _powder(h: int, w: int, rng: np.random.Generator) -> Layer:
    name = str(rng.choice(list(POWDER_COLOURS)))
    coverage = float(rng.uniform(0.004, 0.08))
    field = fbm((h, w), rng, 4, int(rng.choice([2, 4, 8, 12])))
    thr = float(np.quantile(field, 1.0 - coverage))
    clumps = np.clip((field - thr) / float(rng.uniform(0.01, 0.05)), 0, 1)
    grain = float(rng.choice([0.6, 1.0, 1.8]))  # fine / medium / coarse
    density = float(rng.uniform(0.1, 0.6))
    n = int(coverage * h * w / (3 * grain * grain) * (1 + density)) + 5
    grains = np.zeros((h, w), np.float32)
    ys, xs = rng.integers(0, h, n), rng.integers(0, w, n)
    rad = np.clip(rng.lognormal(np.log(grain), 0.45, n), 0.5, 5.0)
    for y, x, r in zip(ys, xs, rad, strict=True):
        if clumps[y, x] > 0 or rng.random() < density * 0.3:
            cv2.circle(grains, (int(x), int(y)), max(1, int(round(r))), 1.0, -1)
    speckle = (rng.random((h, w)) < density).astype(np.float32)  # grainy interior, not a flat disc
    alpha = np.maximum(clumps * (0.6 + 0.4 * speckle), grains) * float(rng.uniform(0.6, 0.98))
    alpha = _soft(alpha, float(rng.uniform(0.4, 1.2)))
    rgb = np.asarray(POWDER_COLOURS[name], np.float32) * rng.uniform(0.9, 1.05, 3).astype(np.float32)
    return Layer(alpha, _const(h, w, np.clip(rgb, 0, 1)), "matte", "powder", {"colour": name, "grain": grain})


def _film(h: int, w: int, rng: np.random.Generator) -> Layer:
    field = _soft(fbm((h, w), rng, 3, 2), min(h, w) / 20)
    cover = float(rng.uniform(0.08, 0.45))
    thr = float(np.quantile(field, 1.0 - cover))
    region = np.clip((field - thr) / 0.08, 0, 1)
    strength = float(rng.uniform(0.3, 0.65))
    alpha = region * strength * (0.8 + 0.2 * fbm((h, w), rng, 2, 8))
    tint = np.array([0.85, 0.86, 0.88], np.float32) * rng.uniform(0.85, 1.1, 3).astype(np.float32)
    return Layer(
        alpha.astype(np.float32), _const(h, w, np.clip(tint, 0, 1)), "film", "film", {"cover": round(cover, 3)}
    )


def _streak(h: int, w: int, rng: np.random.Generator) -> Layer:
    alpha = np.zeros((h, w), np.float32)
    ang = float(rng.uniform(0, np.pi))
    d = np.array([np.cos(ang), np.sin(ang)])
    nrm = np.array([-d[1], d[0]])
    c = rng.uniform([0.2 * w, 0.2 * h], [0.8 * w, 0.8 * h])
    bands = int(rng.integers(1, 5))
    width = float(rng.uniform(2, 0.08 * min(h, w)))
    length = float(rng.uniform(0.3, 0.9) * max(h, w))
    bend = float(rng.uniform(-0.002, 0.002))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    rel = np.stack([xx - c[0], yy - c[1]], -1)
    s = rel @ d
    t = rel @ nrm - bend * s * s
    for b in range(bands):
        off = b * width * float(rng.uniform(1.3, 2.5))
        core = np.exp(-(((t - off) / width) ** 2)) * (np.abs(s) < length / 2)
        alpha = np.maximum(alpha, core.astype(np.float32))
    brush = cv2.resize(rng.random((1, max(8, int(length / 3)))).astype(np.float32), (w, h))
    alpha *= (0.5 + 0.5 * brush) * float(rng.uniform(0.45, 0.85))
    dark = rng.random() < 0.4
    col = np.array([0.35, 0.34, 0.32] if dark else [0.88, 0.88, 0.86], np.float32)
    return Layer(_soft(alpha, 1.0), _const(h, w, col), "film" if not dark else "matte", "streak", {"bands": bands})


def _droplet(h: int, w: int, rng: np.random.Generator) -> Layer:
    alpha = np.zeros((h, w), np.float32)
    rgb = np.zeros((h, w, 3), np.float32)
    dried = rng.random() < 0.5
    n = int(rng.integers(1, 9))
    for _ in range(n):
        cx, cy = float(rng.uniform(0, w)), float(rng.uniform(0, h))
        r = float(rng.uniform(2.5, 0.09 * min(h, w)))
        ax = (max(2, int(r)), max(2, int(r * rng.uniform(0.6, 1.0))))
        a = float(rng.uniform(0, 180))
        disc = np.zeros((h, w), np.float32)
        cv2.ellipse(disc, (int(cx), int(cy)), ax, a, 0, 360, 1.0, -1)
        rim = np.zeros((h, w), np.float32)
        cv2.ellipse(rim, (int(cx), int(cy)), ax, a, 0, 360, 1.0, max(1, int(r / 5)))
        if dried:
            # mineral ring, faint centre
            alpha = np.maximum(alpha, 0.85 * rim + 0.2 * disc)
            rgb[:] = np.float32(0.9)
        else:
            alpha = np.maximum(alpha, 0.55 * disc + 0.35 * rim)
            spot = np.zeros((h, w), np.float32)
            cv2.circle(spot, (int(cx - r / 3), int(cy - r / 3)), max(1, int(r / 5)), 1.0, -1)
            rgb += spot[..., None] * 1.0
    if not dried:
        rgb = np.clip(rgb + np.float32(0.18), 0, 1)
    return Layer(_soft(alpha, 0.7), rgb, "matte" if dried else "gloss", "droplet", {"dried": dried, "n": n})


def _fibre(h: int, w: int, rng: np.random.Generator) -> Layer:
    alpha = np.zeros((h, w), np.float32)
    n = int(rng.integers(1, 6))
    col = np.array(
        [(0.95, 0.95, 0.95), (0.2, 0.3, 0.75), (0.12, 0.12, 0.12), (0.8, 0.2, 0.2), (0.3, 0.6, 0.3)][
            int(rng.integers(5))
        ],
        np.float32,
    )
    for _ in range(n):
        p = rng.uniform([0, 0], [w, h])
        ang = float(rng.uniform(0, 2 * np.pi))
        pts = [p.copy()]
        length = float(rng.uniform(0.15, 0.6) * max(h, w))
        steps = 24
        for _ in range(steps):
            ang += float(rng.normal(0, 0.25))
            p = p + length / steps * np.array([np.cos(ang), np.sin(ang)])
            pts.append(p.copy())
        poly = np.round(np.array(pts)).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(alpha, [poly], False, 1.0, int(rng.choice([1, 1, 2])), lineType=cv2.LINE_AA)
    return Layer(alpha * float(rng.uniform(0.75, 1.0)), _const(h, w, col), "matte", "fibre", {"n": n})


def _fingerprint(h: int, w: int, rng: np.random.Generator) -> Layer:
    alpha = np.zeros((h, w), np.float32)
    n = int(rng.integers(1, 4))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    for _ in range(n):
        cx, cy = float(rng.uniform(0.1 * w, 0.9 * w)), float(rng.uniform(0.1 * h, 0.9 * h))
        rx = float(rng.uniform(0.06, 0.16) * min(h, w)) + 4
        ry = rx * float(rng.uniform(1.2, 1.6))
        th = float(rng.uniform(0, np.pi))
        dx, dy = xx - cx, yy - cy
        u = (np.cos(th) * dx + np.sin(th) * dy) / rx
        v = (-np.sin(th) * dx + np.cos(th) * dy) / ry
        r = np.sqrt(u * u + v * v)
        warp = 0.15 * fbm((h, w), rng, 2, 4)
        period = float(rng.uniform(3.0, 5.0)) / rx  # ridges 3-5 px apart
        ridges = 0.5 + 0.5 * np.cos(2 * np.pi * (r + warp) / period)
        env = np.clip((1.0 - r) / 0.25, 0, 1)
        alpha = np.maximum(alpha, (ridges * env).astype(np.float32))
    alpha *= float(rng.uniform(0.35, 0.6))
    col = np.array([0.72, 0.70, 0.66], np.float32) * rng.uniform(0.9, 1.1)
    return Layer(alpha, _const(h, w, np.clip(col, 0, 1)), "film", "fingerprint", {"n": n})


def _soot(h: int, w: int, rng: np.random.Generator) -> Layer:
    """A dark matte smudge: soot, carbon, ink or a black rubber mark.

    Unlike the held-out ``grease`` (an elliptical blob with a blurred tail, glossy, brown-black)
    its outline is an irregular fractal cloud, its opacity patchy, its material matte (it covers
    the steel and is lit like it) and its colour neutral or blue-black.
    """
    field = fbm((h, w), rng, 4, int(rng.choice([2, 3, 4, 6])))
    cover = float(rng.uniform(0.008, 0.1))
    thr = float(np.quantile(field, 1.0 - cover))
    region = np.clip((field - thr) / float(rng.uniform(0.01, 0.06)), 0, 1)
    patchy = 0.55 + 0.45 * fbm((h, w), rng, 3, int(rng.choice([8, 16])))
    alpha = _soft(region * patchy, float(rng.uniform(0.5, 2.0))) * float(rng.uniform(0.55, 0.95))
    grey = float(rng.uniform(0.05, 0.22))
    tint = np.array([1.0, 1.0, 1.0], np.float32) if rng.random() < 0.6 else np.array([0.85, 0.92, 1.15], np.float32)
    rgb = np.clip(grey * tint, 0, 1)
    return Layer(alpha.astype(np.float32), _const(h, w, rgb), "matte", "soot", {"cover": round(cover, 3)})


def _tarnish(h: int, w: int, rng: np.random.Generator) -> Layer:
    """A darker-than-steel translucent film: an oily or wet patch, a discoloured (tarnished) area.

    It absorbs light and keeps the texture and reflections under it (``absorb`` mode: the steel
    times a transmission 0.35-0.8), over a large, soft, often elongated region. Unlike the
    held-out ``grease`` there is no opaque core, no elliptical outline and no brown cast;
    unlike ``stain`` no tide mark and no orange-brown colour.
    """
    stretch = float(rng.uniform(1.0, 4.0))
    small = fbm((h, max(8, int(w / stretch))), rng, 3, 3)
    field = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    if rng.random() < 0.5:
        field = cv2.rotate(cv2.resize(field, (h, w)), cv2.ROTATE_90_CLOCKWISE)
    cover = float(rng.uniform(0.02, 0.3))
    thr = float(np.quantile(field, 1.0 - cover))
    region = np.clip((field - thr) / float(rng.uniform(0.02, 0.1)), 0, 1)
    alpha = _soft(region, float(rng.uniform(1.0, 4.0))) * (0.85 + 0.15 * fbm((h, w), rng, 2, 8))
    transmission = float(rng.uniform(0.35, 0.8))
    tint = np.clip(transmission * rng.uniform(0.92, 1.08, 3), 0, 1).astype(np.float32)
    return Layer(
        alpha.astype(np.float32), _const(h, w, tint), "absorb", "tarnish", {"transmission": round(transmission, 3)}
    )


FAMILIES: dict[str, Callable[[int, int, np.random.Generator], Layer]] = {
    "powder": _powder,
    "film": _film,
    "streak": _streak,
    "droplet": _droplet,
    "fibre": _fibre,
    "fingerprint": _fingerprint,
    "soot": _soot,
    "tarnish": _tarnish,
}
"""The training families, by name (see the module table)."""


def draw_family(name: str, h: int, w: int, rng: np.random.Generator, families: dict | None = None) -> Layer:
    """Draw one layer of family ``name`` at ``h``×``w`` px.

    Raises:
        ClassifierError: unknown family.
    """
    table = FAMILIES if families is None else families
    if name not in table:
        raise ClassifierError(f"contamination family {name!r} is unknown; expected one of {sorted(table)}")
    return table[name](h, w, rng)


def composite(base: F32, layer: Layer, where: NDArray[np.bool_] | None = None) -> tuple[F32, F32]:
    """Lay ``layer`` on a clean linear-ish RGB image ``base`` (H, W, 3) in [0, 1].

    Args:
        where: pixels the contamination may lie on (the inspected surface in a twin render);
            None = everywhere.

    Returns:
        ``(image, alpha)``: the contaminated image and the opacity actually applied.
    """
    alpha = layer.alpha.astype(np.float32)
    if where is not None:
        alpha = alpha * where.astype(np.float32)
    a = alpha[..., None]
    lum = base.mean(axis=2, keepdims=True)
    if layer.mode == "matte":
        # lit like the steel under it: a matte layer takes the local diffuse level, not the gloss
        shade = np.clip(_soft(lum[..., 0], 3.0)[..., None] / max(float(lum.mean()), 0.05), 0.5, 1.4)
        shade = 0.55 + 0.45 * shade
        out = base * (1 - a) + np.clip(layer.rgb * shade, 0, 1) * a
    elif layer.mode == "film":
        veiled = cv2.GaussianBlur(base, (0, 0), 1.5) * 0.75 + layer.rgb * 0.25 * float(lum.mean() + 0.3)
        out = base * (1 - a) + veiled * a
    elif layer.mode == "absorb":
        # a translucent dark film: the steel (texture, reflections) times the layer's transmission
        out = base * (1 - a) + base * layer.rgb * a
    elif layer.mode == "gloss":
        dark = base * 0.55 + layer.rgb * 0.45
        out = base * (1 - a) + dark * a
    else:
        raise ClassifierError(f"layer mode {layer.mode!r} is unknown; expected matte, film, absorb or gloss")
    return np.clip(out, 0, 1).astype(np.float32), alpha


@dataclass(frozen=True)
class Optics:
    """Camera effects applied to the clean and the dirty image of a draw alike."""

    blur_sigma: float = 0.0
    exposure: float = 1.0
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    noise_sigma: float = 0.0
    jpeg_quality: int | None = None
    noise_seed: int = 0

    @staticmethod
    def draw(rng: np.random.Generator) -> Optics:
        """The training optics distribution."""
        return Optics(
            blur_sigma=float(rng.choice([0.0, rng.uniform(0.3, 1.3)])),
            exposure=float(rng.uniform(0.7, 1.3)),
            white_balance=tuple(float(v) for v in rng.uniform(0.9, 1.1, 3)),
            noise_sigma=float(rng.uniform(0.0, 5.0)),
            jpeg_quality=int(rng.integers(60, 96)) if rng.random() < 0.5 else None,
            noise_seed=int(rng.integers(2**31)),
        )


def optics(img: F32, o: Optics) -> NDArray[np.uint8]:
    """Apply :class:`Optics` to an RGB float image; returns RGB uint8."""
    x = img
    if o.blur_sigma > 0:
        x = cv2.GaussianBlur(x, (0, 0), o.blur_sigma)
    x = x * o.exposure * np.asarray(o.white_balance, np.float32)
    x = x * 255.0
    if o.noise_sigma > 0:
        x = x + np.random.default_rng(o.noise_seed).normal(0, o.noise_sigma, x.shape).astype(np.float32)
    out = np.clip(x + 0.5, 0, 255).astype(np.uint8)
    if o.jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor(out, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, o.jpeg_quality])
        if ok:
            out = cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    return out


def local_variation(values: F32, weight: F32, sigma: float = RING_SIGMA) -> F32:
    """Per pixel, the RMS deviation of ``values`` (H, W) or (H, W, C) from their local mean over
    a Gaussian window ``sigma``, counting only pixels with ``weight`` > 0 (normalised
    convolution): the natural variation of a measure in a pixel's surroundings.

    Where the window holds (almost) no counted pixel, the variation over all counted pixels of
    the image is used; with no counted pixel at all, 0 (nothing to compare with).
    """
    v = values.astype(np.float32)
    if v.ndim == 2:
        v = v[..., None]
    w = weight.astype(np.float32)
    if w.sum() <= 0:
        return np.zeros(v.shape[:2], np.float32)

    def g(x: np.ndarray) -> np.ndarray:
        out = cv2.GaussianBlur(x, (0, 0), sigma)
        return out if out.ndim == 3 or x.ndim == 2 else out[..., None]

    ws = g(w)
    wv = g(v * w[..., None]).reshape(v.shape)
    wv2 = g((v * v) * w[..., None]).reshape(v.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = wv / ws[..., None]
        var = (wv2 / ws[..., None] - mean * mean).sum(axis=2)
    gm = (v * w[..., None]).sum(axis=(0, 1)) / w.sum()
    gvar = float((((v - gm) ** 2).sum(axis=2) * w).sum() / w.sum())
    # a window whose counted weight is < 2 % of a full one (far inside a large film) falls
    # back to the whole image's surroundings: its normalised average is a few pixels' noise
    var = np.where(ws > 0.02, var, gvar)
    return np.sqrt(np.maximum(np.nan_to_num(var, nan=gvar), 0.0)).astype(np.float32)


def visible_mask(
    dirty: NDArray[np.uint8],
    clean: NDArray[np.uint8],
    alpha: F32,
    at_px: int | None = None,
    clutter_k: float = CLUTTER_K,
) -> NDArray[np.float32]:
    """1 where contamination lies (opacity ≥ :data:`VISIBLE_ALPHA`) *and* visibly changes a
    patch of the final image against the same draw without it.

    "Visibly" is judged per patch (a Gaussian window of σ = :data:`PATCH_SIGMA` px around each
    pixel) in CIELAB, by either of two criteria a person looking at the picture would use:

    * the patch's mean colour moves by ΔE*ab ≥ :data:`MIN_DELTA_E` (a colour or brightness
      change: powder, stains, droplets, streaks);
    * the patch's RMS contrast in L* changes by ≥ :data:`MIN_CONTRAST_L` and by a factor
      ≥ :data:`CONTRAST_RATIO` (texture that appears, such as a fibre, or that a haze wipes out);

    and, either way, the change is ≥ ``clutter_k`` (:data:`CLUTTER_K`) times the natural
    variation of that measure in the patch's surroundings in the same image
    (:func:`local_variation` over the dirty image's uncontaminated pixels, opacity <
    :data:`VISIBLE_ALPHA` and outside one patch window of them, or over the clean draw's steel
    at the same place, whichever varies more): the clean twin says what changed, the image
    itself says whether the change stands out from the steel around it.

    A single pixel's change is not enough: a thin film that slightly blurs brushed grain moves
    individual grain-line pixels by more than 12 grey levels while the picture looks the same,
    and labelling that dirty set the false-clean threshold by invisible "dirt".

    Args:
        at_px: judge visibility at this square size (the images and ``alpha`` resized with
            ``INTER_AREA``, as the classifier squashes its input): what averages away at the
            model's input is not visible to it. None = as given.
        clutter_k: the surroundings factor; 0 = the reference-only rule of earlier rounds.
    """
    if clutter_k < 0:
        raise ClassifierError(f"clutter_k {clutter_k} must be >= 0")
    d = np.asarray(dirty)
    c = np.asarray(clean)
    a = alpha.astype(np.float32)
    if at_px is not None:

        def sq(x: np.ndarray) -> np.ndarray:
            return cv2.resize(x, (at_px, at_px), interpolation=cv2.INTER_AREA)

        d, c, a = sq(d), sq(c), sq(a)

    def lab(x: np.ndarray) -> F32:
        return cv2.cvtColor(x.astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB)

    def win(x: np.ndarray) -> F32:
        return cv2.GaussianBlur(x, (0, 0), PATCH_SIGMA)

    ld, lc = lab(d), lab(c)
    md, mc = win(ld), win(lc)
    delta_e = np.sqrt(((md - mc) ** 2).sum(axis=2))

    def rms(lum: F32, mean: F32) -> F32:
        return np.sqrt(np.maximum(win(lum * lum) - mean * mean, 0.0))

    rd, rc = rms(ld[..., 0], md[..., 0]), rms(lc[..., 0], mc[..., 0])
    hi, lo = np.maximum(rd, rc), np.minimum(rd, rc)
    texture = (hi - lo >= MIN_CONTRAST_L) & (hi >= CONTRAST_RATIO * lo)
    colour = delta_e >= MIN_DELTA_E
    if clutter_k > 0:
        # the surroundings: pixels of the dirty image no contamination reaches, one patch
        # window away from any that does (a patch mean there does not include the dirt)
        touched = win((a >= VISIBLE_ALPHA).astype(np.float32)) > 0.01
        ring = (~touched).astype(np.float32)
        # ...and the steel under the contamination itself, from the clean draw: inside a large
        # film the ring is far away, while the edge of a dark reflection right there varies
        # as much as the film changes it (a veiled reflection edge looks like a softer one)
        everywhere = np.ones_like(ring)
        var_mean = np.maximum(local_variation(md, ring), local_variation(mc, everywhere))
        var_rms = np.maximum(local_variation(rd, ring), local_variation(rc, everywhere))
        colour &= delta_e >= clutter_k * var_mean
        texture &= hi - lo >= clutter_k * var_rms
    seen = colour | texture
    return ((a >= VISIBLE_ALPHA) & seen).astype(np.float32)


def closeup_steel(
    surface: str, h: int, w: int, rng: np.random.Generator, look: Look | None = None, reflections: bool = True
) -> F32:
    """A clean close-up stainless texture (H, W, 3) in [0, 1].

    External: brushed grain (:func:`cellctl.classify.texture.steel_image`) plus, sometimes, a
    weld seam or scratches (clean features that are not contamination). Internal: the polished
    mirror plus reflections of what stands in front of it — dark robot/camera silhouettes and
    bright window panels.
    """
    s = max(h, w)
    img = steel_image(surface, s, rng, look or Look())[:h, :w].copy()
    if surface == "external":
        if rng.random() < 0.3:  # weld seam
            y = int(rng.uniform(0.1, 0.9) * h)
            seam = np.zeros((h, w), np.float32)
            cv2.line(seam, (0, y), (w, y + int(rng.uniform(-0.1, 0.1) * h)), 1.0, max(2, h // 40))
            img = img * (1 - 0.25 * _soft(seam, 1.5)[..., None])
        for _ in range(int(rng.integers(0, 4))):  # scratches
            p0 = rng.uniform([0, 0], [w, h]).astype(int)
            p1 = (p0 + rng.normal(0, 0.3 * s, 2)).astype(int)
            sc = np.zeros((h, w), np.float32)
            cv2.line(sc, tuple(int(v) for v in p0), tuple(int(v) for v in p1), 1.0, 1, lineType=cv2.LINE_AA)
            img = np.clip(img + float(rng.choice([-0.08, 0.1])) * sc[..., None], 0, 1)
    elif reflections:
        refl = np.zeros((h, w), np.float32)
        for _ in range(int(rng.integers(1, 4))):
            c = (int(rng.uniform(0, w)), int(rng.uniform(0, h)))
            ax = (int(rng.uniform(0.08, 0.3) * w), int(rng.uniform(0.05, 0.25) * h))
            cv2.ellipse(refl, c, ax, float(rng.uniform(0, 180)), 0, 360, 1.0, -1)
        img = img * (1 - 0.6 * _soft(refl, s / 30)[..., None])
        for _ in range(int(rng.integers(0, 3))):
            x0, y0 = int(rng.uniform(0, w)), int(rng.uniform(0, h))
            panel = np.zeros((h, w), np.float32)
            cv2.rectangle(panel, (x0, y0), (x0 + int(rng.uniform(5, w / 3)), y0 + int(rng.uniform(3, h / 6))), 1.0, -1)
            img = np.clip(img + 0.5 * _soft(panel, 1.5)[..., None], 0, 1)
    return img.astype(np.float32)
