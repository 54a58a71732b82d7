"""Typed options shared by every ``cellctl bench <what>`` measurement.

Each bench is a library function ``bench_<what>(opts: BenchOptions) -> dict`` that a test or a
script calls directly; the command line (:mod:`cellctl.cli.bench`) only turns its flags into a
:class:`BenchOptions`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from cellctl.errors import ConfigError

if TYPE_CHECKING:
    from cellctl.config import CellConfig

__all__ = ["BenchOptions"]


@dataclass(frozen=True, kw_only=True)
class BenchOptions:
    """What a bench measures on, and how much of it.

    Attributes:
        n: sample count; None = the bench's own default (each bench documents its meaning:
            messages, cycles, views per distance, fuzz cases, …).
        seed: seed of every random draw the bench makes (reported in its JSON where it matters).
        config: cell config YAML; None = ``config/cell.yaml``.
        overrides: ``KEY.PATH=VALUE`` config overrides, applied after the bench's own.
        out: where the CLI also writes the JSON; benches that make a figure put it beside it.
        family: ``bench whole-bin --family [F[:A-B]]``: plan meshes A..B of the shape family F
            (:mod:`cellctl.geometry.family`) instead of the catalog; None = the catalog.
        commissioned: ``bench inspect --commissioned``: a commissioning cycle first, then each view
            decided with and without its reference (:mod:`cellctl.bench.classify.inspect_commissioned`).
        first: ``--seed-offset``: the first cycle of a slice (cycles ``first .. first + n - 1``).
        merge: ``--merge``: slice JSONs to merge into one report instead of running cycles.
    """

    n: int | None = None
    seed: int = 0
    config: str | None = None
    overrides: tuple[str, ...] = ()
    out: Path | None = None
    family: str | None = None
    commissioned: bool = False
    first: int = 0
    merge: tuple[Path, ...] = ()

    def __post_init__(self) -> None:
        if self.n is not None and (isinstance(self.n, bool) or not isinstance(self.n, int) or self.n < 1):
            raise ConfigError(f"bench sample count n={self.n!r} must be a positive integer (or None for the default)")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int):
            raise ConfigError(f"bench seed {self.seed!r} must be an integer")
        if isinstance(self.overrides, str) or not isinstance(self.overrides, Sequence):
            raise ConfigError(f"bench overrides {self.overrides!r} must be a sequence of 'KEY=VALUE' strings")
        object.__setattr__(self, "overrides", tuple(self.overrides))
        if self.out is not None:
            object.__setattr__(self, "out", Path(self.out))
        if isinstance(self.first, bool) or not isinstance(self.first, int) or self.first < 0:
            raise ConfigError(f"bench seed offset (first cycle) {self.first!r} must be a non-negative integer")
        object.__setattr__(self, "merge", tuple(Path(p) for p in self.merge))

    def load_config(self) -> CellConfig:
        """The cell config: ``config`` with the user's ``overrides`` (benches that add their own
        build the list themselves: where theirs go relative to the user's differs)."""
        from cellctl.config import load_config

        return load_config(self.config, list(self.overrides))
