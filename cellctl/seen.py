"""What a ``clean`` verdict needs: every bin surface seen to its configured share.

A cycle that saw no dirt vouches only for what it saw. ``classifier.verdict.min_seen_fraction`` gives,
per surface, the share of that surface's area a cycle must have seen; a cycle below it on any surface
ends ``incomplete``, with the fractions, instead of ``clean``. Dirt seen stays ``dirty`` however little
was seen (dirt seen is dirt). The planner applies the same rule to a plan's predicted fractions, so a bin
that no plan can see enough of says so at planning time (:func:`shortfall` on the plan's surfaces).

Leaf module: imports only :mod:`cellctl.surface`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal, get_args

from cellctl.surface import SURFACES

__all__ = [
    "VERDICTS",
    "Verdict",
    "describe_shortfall",
    "gate_verdict",
    "plan_warning",
    "shortfall",
    "whole_plan_warning",
]

Verdict = Literal["clean", "dirty", "incomplete"]
"""A bin's verdict: ``incomplete`` = no dirt seen, but too little of some surface seen to call it clean."""

VERDICTS: tuple[Verdict, ...] = get_args(Verdict)
"""Every verdict, in the order the contracts list them."""


def shortfall(
    seen: Mapping[str, float | None] | None, minimum: Mapping[str, float]
) -> dict[str, tuple[float | None, float]]:
    """Surfaces seen less than their minimum: surface → (seen fraction, minimum), in :data:`SURFACES` order.

    A surface whose fraction is unknown (absent or None: no mesh to measure it on) counts as unseen when
    it has a minimum above 0; a surface without a minimum (absent or 0) never falls short.
    """
    seen = seen or {}
    out: dict[str, tuple[float | None, float]] = {}
    for s in SURFACES:
        need = float(minimum.get(s, 0.0))
        got = seen.get(s)
        if need > 0 and (got is None or got < need):
            out[s] = (got, need)
    return out


def describe_shortfall(short: Mapping[str, tuple[float | None, float]]) -> str:
    """``"internal 34 % seen, needs 60 %; external unknown, needs 60 %"`` (for reasons and warnings)."""
    return "; ".join(
        f"{s} {'unknown' if got is None else f'{got:.0%} seen'}, needs {need:.0%}" for s, (got, need) in short.items()
    )


def gate_verdict(
    verdict: Verdict | None, seen: Mapping[str, float | None] | None, minimum: Mapping[str, float]
) -> tuple[Verdict | None, str | None]:
    """The verdict a cycle may report, and why it is not ``clean`` when the gate changed it.

    Only ``clean`` is gated: ``dirty`` and no verdict (None) pass unchanged.
    """
    if verdict != "clean":
        return verdict, None
    short = shortfall(seen, minimum)
    if not short:
        return "clean", None
    why = "incomplete: no dirt seen, but " + describe_shortfall(short) + " (classifier.verdict.min_seen_fraction)"
    return "incomplete", why


def plan_warning(
    seen: Mapping[str, float | None], minimum: Mapping[str, float], reach: Mapping[str, float] | None = None
) -> str | None:
    """What a plan's predicted fractions mean for its cycles' verdicts: None when they can be ``clean``.

    ``reach`` (surface → the arm-aware bound's share of the surface) splits a shortfall into "no
    reachable camera pose sees enough" and "the planner did not".
    """
    short = shortfall(seen, minimum)
    if not short:
        return None
    why = []
    for s, (_, need) in short.items():
        r = (reach or {}).get(s)
        if r is not None:
            why.append(f"{s}: " + (f"no reachable camera pose sees more than {r:.0%}" if r < need else
                                   f"reachable poses see {r:.0%}, the plan does not"))  # fmt: skip
    return (
        "this plan cannot certify the bin clean: "
        + describe_shortfall(short)
        + " (classifier.verdict.min_seen_fraction); its cycles end `incomplete` unless they see dirt"
        + (f" ({'; '.join(why)})" if why else "")
    )


def whole_plan_warning(plan: Any, minimum: Mapping[str, float]) -> str | None:
    """:func:`plan_warning` of a :class:`cellctl.planning.whole.WholePlan` (its ``surfaces``' seen area
    and arm-aware bound, ``reachable_m2``, over each surface's area); None when its cycles can be clean."""
    surfaces = plan.surfaces
    seen = {k: v.area_fraction for k, v in surfaces.items()}
    reach = {k: v.reachable_m2 / v.area_m2 for k, v in surfaces.items() if v.area_m2 > 0 and v.reachable_m2 > 0}
    return plan_warning(seen, minimum, reach)
