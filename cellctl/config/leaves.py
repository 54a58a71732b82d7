"""Every settable leaf of the cell config with its default and description: what ``cellctl schema --config`` prints."""

from __future__ import annotations

import typing
from typing import Any

from pydantic import BaseModel

from cellctl.config.backends import backend_reading
from cellctl.config.cell import CellConfig


def _section_model(annotation: Any) -> type[BaseModel] | None:
    """The config section a field holds (``RobotConfig``; also through ``X | None``), or None for a leaf."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if typing.get_origin(annotation) in (list, dict, tuple):
        return None
    for arg in typing.get_args(annotation):
        found = _section_model(arg)
        if found is not None:
            return found
    return None


def config_leaves(
    model: type[BaseModel] | None = None, prefix: str = "", backend: str | None = None
) -> list[tuple[str, Any, str]]:
    """Every settable leaf of the cell config: ``(dotted key, default, description)``, in model order; the
    description of a leaf only one backend reads starts with that backend (``opencv: …``, from :data:`BACKENDS`).

    What ``cellctl schema --config`` prints; a test holds every leaf to a description.
    """
    rows: list[tuple[str, Any, str]] = []
    for name, field in (model or CellConfig).model_fields.items():
        if field.exclude:
            continue
        owner = backend or (backend_reading(prefix.rstrip("."), name) if prefix.count(".") == 1 else None)
        section = _section_model(field.annotation)
        if section is not None:
            rows += config_leaves(section, f"{prefix}{name}.", owner)
        else:
            default = field.get_default(call_default_factory=True)
            text = field.description or ""
            rows.append((f"{prefix}{name}", default, f"{owner}: {text}" if owner and text else text))
    return rows
