"""The bin surfaces: one name type, one list, one per-face tag each.

A bin has two surfaces, inspected by two networks: ``external`` (brushed outer steel) and
``internal`` (polished inner steel). Wire messages, config, plans, the classifier and the
mesh files all spell them the same way; this module is the one place that spelling lives.

``Surface`` is a ``Literal`` alias (not an Enum) so that pydantic models using it keep the
JSON schema ``{"enum": ["external", "internal"]}`` they had — the schemas recorded in MCAP
logs and printed by ``cellctl schema`` stay byte-identical.

Leaf module: imports only :mod:`cellctl.errors`.
"""

from __future__ import annotations

from typing import Literal, get_args

from cellctl.errors import CellError

__all__ = ["EXTERNAL", "FACE_TAG", "INTERNAL", "SURFACES", "Surface", "check_surface", "per_surface"]

Surface = Literal["external", "internal"]
"""A bin surface name."""

SURFACES: tuple[Surface, ...] = get_args(Surface)
"""Every surface, in index order (external first): the classifier's model order."""

EXTERNAL = 0
"""Per-face tag of an external face in a bin mesh (PLY ``uchar surface``)."""
INTERNAL = 1
"""Per-face tag of an internal face in a bin mesh."""

FACE_TAG: dict[Surface, int] = {"external": EXTERNAL, "internal": INTERNAL}
"""Surface name → per-face mesh tag."""


def per_surface(external: float, internal: float) -> dict[Surface, float]:
    """One value per surface (a config default such as ``min_seen_fraction``), spelt without the names."""
    return {"external": external, "internal": internal}


def check_surface(value: object, error: type[CellError] = CellError, what: str = "surface") -> Surface:
    """Return ``value`` as a :data:`Surface`, or raise ``error`` naming it and the allowed ones.

    Args:
        value: the name to check.
        error: the exception class to raise (the caller's family: ClassifierError,
            PlanningError, ProtocolError …).
        what: how the message names the value (``"start param surface"``).
    """
    if isinstance(value, str) and value in SURFACES:
        return value  # narrowed by the membership test
    raise error(f"{what} {value!r} is unknown; expected one of {list(SURFACES)}")
