"""Per-backend config fields registered by name (LeRobot's ``register_subclass``): :data:`BACKENDS`."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from cellctl.strict_model import ConfigModel as _Model

_Fields = TypeVar("_Fields", bound=type[_Model])

BACKENDS: dict[str, dict[str, type[_Model]]] = {}
"""Config section -> backend name -> the class of the fields only that backend reads (:func:`register_backend`)."""


def register_backend(section: str, name: str) -> Callable[[_Fields], _Fields]:
    """Register the decorated class as the fields backend ``name`` of ``section`` reads (LeRobot's
    ``register_subclass``). The section's model inherits every registered class of its section, so the
    YAML stays flat (``camera.device``); a test holds the two together."""

    def register(cls: _Fields) -> _Fields:
        known = BACKENDS.setdefault(section, {})
        if name in known:
            raise ValueError(f"{section}.backend {name!r} registered twice: {known[name].__name__}, {cls.__name__}")
        known[name] = cls
        return cls

    return register


def backend_reading(section: str, key: str) -> str | None:
    """The backend that alone reads ``section.key`` (``camera``, ``device`` -> ``opencv``); None: all do."""
    for name, fields in BACKENDS.get(section, {}).items():
        if key in fields.model_fields:
            return name
    return None
