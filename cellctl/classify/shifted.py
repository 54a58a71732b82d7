"""The held-out shifted generator: contamination and optics that training never draws.

A proxy for images no one here made. Nothing in this module is used to train or calibrate a
model; ``cellctl dataset contam --shifted`` writes a separate set that the model cards report
on separately. What is held out:

* **families** — ``splatter`` (sprays of tiny specks around an impact point), ``flakes``
  (angular crystalline shards, some glinting), ``grease`` (a dark smeared blob with a soft
  tail), ``stain`` (orange-brown tide-marked residue);
* **optics** — motion blur (a line kernel), vignetting, lateral chromatic aberration, a colour
  cast and gamma outside the training range, down-and-up resampling (a cheaper lens/sensor),
  stronger sensor noise;
* **appearance of the base** — the twin's shifted lighting (``RenderParams`` outside the
  training ranges) and :meth:`cellctl.classify.texture.Look.shifted` for close-ups.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.classify.contamination import F32, Layer, _const, _soft
from cellctl.classify.texture import fbm

__all__ = ["HELD_OUT_FAMILIES", "ShiftedOptics"]


def _splatter(h: int, w: int, rng: np.random.Generator) -> Layer:
    alpha = np.zeros((h, w), np.float32)
    c = rng.uniform([0, 0], [w, h])
    n = int(rng.integers(40, 300))
    spread = float(rng.uniform(0.05, 0.25) * min(h, w))
    pts = c + rng.normal(0, spread, (n, 2))
    for x, y in pts:
        cv2.circle(alpha, (int(x), int(y)), int(rng.choice([0, 1, 1, 2])), 1.0, -1)
    col = rng.uniform(0.1, 0.95, 3).astype(np.float32)
    return Layer(alpha * float(rng.uniform(0.8, 1.0)), _const(h, w, col), "matte", "splatter", {"n": n})


def _flakes(h: int, w: int, rng: np.random.Generator) -> Layer:
    alpha = np.zeros((h, w), np.float32)
    rgb = _const(h, w, rng.uniform(0.6, 0.98, 3))
    n = int(rng.integers(3, 25))
    for _ in range(n):
        c = rng.uniform([0, 0], [w, h])
        r = float(rng.uniform(1.5, 0.05 * min(h, w) + 2))
        k = int(rng.integers(3, 6))
        ang = np.sort(rng.uniform(0, 2 * np.pi, k))
        poly = (c + np.stack([np.cos(ang), np.sin(ang)], -1) * r * rng.uniform(0.5, 1.0, (k, 1))).astype(np.int32)
        cv2.fillPoly(alpha, [poly], 1.0)
        if rng.random() < 0.3:  # a glint: a facet towards the light
            cv2.fillPoly(rgb, [poly], (1.0, 1.0, 1.0))
    return Layer(alpha * float(rng.uniform(0.8, 1.0)), rgb, "matte", "flakes", {"n": n})


def _grease(h: int, w: int, rng: np.random.Generator) -> Layer:
    blob = np.zeros((h, w), np.float32)
    c = (int(rng.uniform(0.15, 0.85) * w), int(rng.uniform(0.15, 0.85) * h))
    ax = (int(rng.uniform(0.05, 0.2) * w) + 2, int(rng.uniform(0.03, 0.12) * h) + 2)
    cv2.ellipse(blob, c, ax, float(rng.uniform(0, 180)), 0, 360, 1.0, -1)
    tail = cv2.GaussianBlur(blob, (0, 0), float(rng.uniform(3, 8)))
    alpha = np.clip(0.7 * blob + 0.6 * tail, 0, 1) * (0.7 + 0.3 * fbm((h, w), rng, 3, 4))
    col = np.array([0.18, 0.16, 0.12], np.float32) * float(rng.uniform(0.8, 1.4))
    return Layer(_soft(alpha, 1.0), _const(h, w, col), "gloss", "grease", {})


def _stain(h: int, w: int, rng: np.random.Generator) -> Layer:
    field = _soft(fbm((h, w), rng, 4, 4), 2.0)
    cover = float(rng.uniform(0.01, 0.12))
    thr = float(np.quantile(field, 1.0 - cover))
    inside = np.clip((field - thr) / 0.02, 0, 1)
    edge = np.clip(1.0 - np.abs(field - thr) / 0.01, 0, 1)  # tide mark at the rim
    alpha = np.clip(0.35 * inside + 0.8 * edge * (field > thr - 0.01), 0, 1)
    col = np.array([0.62, 0.36, 0.16], np.float32) * rng.uniform(0.8, 1.15, 3).astype(np.float32)
    return Layer(alpha.astype(np.float32), _const(h, w, np.clip(col, 0, 1)), "matte", "stain", {})


HELD_OUT_FAMILIES = {"splatter": _splatter, "flakes": _flakes, "grease": _grease, "stain": _stain}
"""Families only the shifted generator draws."""


@dataclass(frozen=True)
class ShiftedOptics:
    """Held-out camera effects (never drawn for training)."""

    motion_px: int
    motion_angle: float
    vignette: float
    chroma_px: int
    cast: tuple[float, float, float]
    gamma: float
    resample: float
    noise_sigma: float
    noise_seed: int

    @staticmethod
    def draw(rng: np.random.Generator) -> ShiftedOptics:
        return ShiftedOptics(
            motion_px=int(rng.choice([0, int(rng.integers(3, 7))])),
            motion_angle=float(rng.uniform(0, 180)),
            vignette=float(rng.uniform(0.15, 0.5)),
            chroma_px=int(rng.integers(0, 3)),
            cast=tuple(float(v) for v in rng.choice([0.8, 0.86, 1.14, 1.22], 3)),
            gamma=float(rng.choice([0.75, 1.3])),
            resample=float(rng.choice([1.0, 0.5, 0.6])),
            noise_sigma=float(rng.uniform(5.0, 9.0)),
            noise_seed=int(rng.integers(2**31)),
        )

    def apply(self, img: F32) -> NDArray[np.uint8]:
        h, w = img.shape[:2]
        x = img.astype(np.float32)
        if self.motion_px > 0:
            k = np.zeros((self.motion_px, self.motion_px), np.float32)
            k[self.motion_px // 2, :] = 1.0
            rot = cv2.getRotationMatrix2D(((self.motion_px - 1) / 2, (self.motion_px - 1) / 2), self.motion_angle, 1)
            k = cv2.warpAffine(k, rot, (self.motion_px, self.motion_px))
            x = cv2.filter2D(x, -1, k / max(float(k.sum()), 1e-6))
        if self.resample < 1.0:
            small = cv2.resize(x, (max(8, int(w * self.resample)), max(8, int(h * self.resample))), cv2.INTER_AREA)
            x = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
        if self.chroma_px:
            x[..., 0] = np.roll(x[..., 0], self.chroma_px, axis=1)
            x[..., 2] = np.roll(x[..., 2], -self.chroma_px, axis=1)
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((xx - w / 2) / (w / 2)) ** 2 + ((yy - h / 2) / (h / 2)) ** 2
        x = x * (1.0 - self.vignette * np.clip(r2 / 2, 0, 1))[..., None]
        x = np.clip(x * np.asarray(self.cast, np.float32), 0, 1) ** self.gamma * 255.0
        x = x + np.random.default_rng(self.noise_seed).normal(0, self.noise_sigma, x.shape).astype(np.float32)
        return np.clip(x + 0.5, 0, 255).astype(np.uint8)
