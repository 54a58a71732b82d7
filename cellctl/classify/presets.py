"""Training recipes of the clean/dirty classifier: :class:`Phase`, :class:`Preset`, :data:`PRESETS`.

Phase 1 always trains the head alone on cached pooled features of the frozen backbone
(:mod:`cellctl.classify.features`); phase 2 fine-tunes, live (all of the backbone) or on cached
activations of the frozen shallower stages (``Phase.cached``).

* ``paper`` — Table 4: SGD momentum 0.9, weight decay 1e-4, batch 32, StepLR ×0.1 every 5
  epochs; phase 1 lr 1e-3 for 30 epochs, phase 2 all layers lr 1e-4 for 100 epochs. The
  StepLR schedule divides the rate by 10⁴ after 20 epochs, so later epochs cannot learn
  (notes/vision.md §8): early stopping (patience 5 on validation loss) ends them.
* ``default`` — phase 1 AdamW lr 3e-3, cosine decay, up to 40 epochs on cached features
  (wd 1e-4, batch 64); phase 2 AdamW lr 3e-4, cosine decay, up to 5 epochs (batch 64) on the
  cached deeper stages, patience 2; two cached views per image (plain + one augmented).
  See docs/decisions.md "## Classifier" for the measured comparison.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from cellctl.errors import ClassifierError

__all__ = ["PRESETS", "Phase", "Preset", "resolve_preset"]


@dataclass(frozen=True)
class Phase:
    """One training phase. ``lr_step``/``lr_gamma`` = StepLR; ``lr_step=0`` = cosine decay.

    ``cached``: the phase trains on cached backbone outputs instead of live images (always
    true of the head phase; for the fine-tune, the frozen prefix stages are cached).
    """

    epochs: int
    lr: float
    optimizer: str = "sgd"
    momentum: float = 0.9
    weight_decay: float = 1e-4
    batch: int = 32
    lr_step: int = 5
    lr_gamma: float = 0.1
    patience: int = 5
    unfreeze: float = 1.0
    cached: bool = False


@dataclass(frozen=True)
class Preset:
    """A training recipe (see module doc)."""

    name: str
    head: Phase
    finetune: Phase
    input_size: int = 128
    cache_views: int = 3
    arch: str = "lite0"


PRESETS: dict[str, Preset] = {
    "paper": Preset(
        name="paper",
        head=Phase(epochs=30, lr=1e-3, cached=True),
        finetune=Phase(epochs=100, lr=1e-4, unfreeze=1.0),
    ),
    "default": Preset(
        name="default",
        cache_views=2,
        head=Phase(epochs=40, lr=3e-3, optimizer="adamw", lr_step=0, batch=64, patience=8, cached=True),
        finetune=Phase(epochs=5, lr=3e-4, optimizer="adamw", lr_step=0, batch=64, patience=2, cached=True),
    ),
}


def resolve_preset(
    preset: str,
    *,
    arch: str | None = None,
    input_size: int | None = None,
    max_epochs: tuple[int | None, int | None] = (None, None),
) -> tuple[Preset, Phase, Phase]:
    """The preset named ``preset`` with the caller's overrides, and its two phases capped by ``max_epochs``.

    Raises:
        ClassifierError: unknown preset, or an input size that is not a multiple of 32 in [64, 512].
    """
    if preset not in PRESETS:
        raise ClassifierError(f"preset {preset!r} is unknown; expected one of {sorted(PRESETS)}")
    ps = PRESETS[preset]
    if arch is not None:
        ps = replace(ps, arch=arch)
    if input_size is not None:
        ps = replace(ps, input_size=input_size)
    if ps.input_size % 32 or not 64 <= ps.input_size <= 512:
        raise ClassifierError(f"input size {ps.input_size} px must be a multiple of 32 in [64, 512]")
    head = replace(ps.head, epochs=min(ps.head.epochs, max_epochs[0] or ps.head.epochs))
    finetune = replace(
        ps.finetune,
        epochs=min(ps.finetune.epochs, max_epochs[1] if max_epochs[1] is not None else ps.finetune.epochs),
    )
    return ps, head, finetune
