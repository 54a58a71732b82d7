"""Procedural stainless-steel images with powder (numpy + OpenCV), with the visible-powder mask.

Used by the tests (small, fast, seeded images) and as the powder/steel model when the twin's
renderer is not available (``cellctl dataset synth --source procedural``). The recipe follows
notes/vision.md §9: brushed base = white noise blurred along the grain + fBm waviness +
anisotropic highlight (external, matt); polished base = darker mirror with smooth environment
blobs and saturated highlights (internal, glossy); powder = thresholded fBm clumps plus
log-normal grains, matte albedo, composited ``img·(1−α) + powder·α``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.classify.collect import check_surface

__all__ = ["Look", "composite", "fbm", "powder_layer", "steel_image"]


@dataclass(frozen=True)
class Look:
    """Appearance parameters; :meth:`shifted` gives the out-of-distribution variant."""

    powder_rgb: tuple[float, float, float] = (0.92, 0.91, 0.88)
    light_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    exposure: tuple[float, float] = (0.8, 1.2)
    noise_sigma: tuple[float, float] = (0.5, 3.0)

    @staticmethod
    def shifted() -> Look:
        """Warm light, yellowish powder, stronger sensor noise (not seen in training)."""
        return Look(
            powder_rgb=(0.93, 0.86, 0.62),
            light_tint=(1.08, 0.98, 0.82),
            exposure=(0.6, 1.45),
            noise_sigma=(3.0, 7.0),
        )


def fbm(shape: tuple[int, int], rng: np.random.Generator, octaves: int = 4, base: int = 4) -> NDArray[np.float32]:
    """Fractal value noise in [0, 1], shape ``(H, W)``."""
    h, w = shape
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for o in range(octaves):
        n = base * 2**o
        small = rng.random((n, n)).astype(np.float32)
        out += amp * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= 0.5
    out /= total
    out -= out.min()
    return out / max(float(out.max()), 1e-6)


def steel_image(surface: str, size: int, rng: np.random.Generator, look: Look = Look()) -> NDArray[np.float32]:
    """A clean stainless image, RGB float32 in [0, 1], shape ``(size, size, 3)``."""
    check_surface(surface)
    s = size
    if surface == "external":
        # Brushed: white noise smeared along a random grain direction.
        noise = rng.random((s, s)).astype(np.float32)
        k = max(3, s // 4)
        kernel = np.zeros((k, k), np.float32)
        kernel[k // 2, :] = 1.0 / k
        rot = cv2.getRotationMatrix2D((k / 2 - 0.5, k / 2 - 0.5), float(rng.uniform(0, 180)), 1.0)
        kernel = cv2.warpAffine(kernel, rot, (k, k))
        kernel /= max(float(kernel.sum()), 1e-6)
        grain = cv2.filter2D(noise, -1, kernel, borderType=cv2.BORDER_REFLECT)
        grain = (grain - grain.mean()) / (grain.std() + 1e-6)
        base = 0.55 + 0.06 * grain + 0.12 * (fbm((s, s), rng, 3, 2) - 0.5)
        yy, xx = np.mgrid[0:s, 0:s].astype(np.float32) / s
        ang = rng.uniform(0, np.pi)
        lobe = np.exp(-(((np.cos(ang) * (xx - rng.uniform(0.2, 0.8)) + np.sin(ang) * (yy - 0.5)) / 0.25) ** 2))
        base = base + rng.uniform(0.05, 0.2) * lobe
    else:
        # Polished: dark mirror reflecting a blurred environment, a few saturated highlights.
        env = cv2.GaussianBlur(fbm((s, s), rng, 3, 2), (0, 0), s / 24)
        base = 0.25 + 0.45 * env
        for _ in range(int(rng.integers(1, 4))):
            c = rng.uniform(0, s, 2)
            ax = (float(rng.uniform(0.03, 0.2) * s), float(rng.uniform(0.01, 0.06) * s))
            hl = np.zeros((s, s), np.float32)
            cv2.ellipse(
                hl,
                (int(c[0]), int(c[1])),
                (int(ax[0]), int(ax[1])),
                float(rng.uniform(0, 180)),
                0,
                360,
                1.0,
                -1,
            )
            base = base + rng.uniform(0.3, 0.8) * cv2.GaussianBlur(hl, (0, 0), max(1.0, s / 64))
        base = base + 0.015 * (rng.random((s, s)).astype(np.float32) - 0.5)
    tint = np.array(look.light_tint, np.float32) * rng.uniform(0.97, 1.03, 3).astype(np.float32)
    img = base[..., None] * tint[None, None, :]
    return np.clip(img * rng.uniform(*look.exposure), 0.0, 1.0).astype(np.float32)


def powder_layer(size: int, rng: np.random.Generator, coverage: float) -> NDArray[np.float32]:
    """Powder opacity α in [0, 1], shape ``(size, size)``, covering about ``coverage`` of the frame."""
    s = size
    if coverage <= 0:
        return np.zeros((s, s), np.float32)
    field = fbm((s, s), rng, 4, int(rng.choice([2, 4, 8])))
    thr = float(np.quantile(field, 1.0 - coverage))
    clumps = np.clip((field - thr) / 0.03, 0.0, 1.0)
    grains = np.zeros((s, s), np.float32)
    n = int(coverage * s * s / 6) + 3
    ys, xs = rng.integers(0, s, n), rng.integers(0, s, n)
    radii = np.clip(rng.lognormal(0.0, 0.5, n), 0.5, 4.0)
    for y, x, r in zip(ys, xs, radii, strict=True):
        if clumps[y, x] > 0 or rng.random() < 0.3:
            cv2.circle(grains, (int(x), int(y)), max(1, int(round(r * s / 256))), 1.0, -1)
    alpha = np.maximum(clumps, grains) * rng.uniform(0.55, 0.95)
    return cv2.GaussianBlur(alpha, (0, 0), max(0.6, s / 256)).astype(np.float32)


def composite(
    img: NDArray[np.float32], alpha: NDArray[np.float32], rng: np.random.Generator, look: Look
) -> NDArray[np.uint8]:
    """Powder over steel plus sensor noise, as RGB uint8."""
    powder = np.array(look.powder_rgb, np.float32) * np.array(look.light_tint, np.float32)
    powder = powder * rng.uniform(*look.exposure) * rng.uniform(0.85, 1.0)
    out = img * (1.0 - alpha[..., None]) + powder[None, None, :] * alpha[..., None]
    out = out + rng.normal(0.0, rng.uniform(*look.noise_sigma) / 255.0, out.shape).astype(np.float32)
    return (np.clip(out, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
