"""The base of every typed config record: unknown keys are errors, never silently dropped.

A typo in a YAML key (``robot.speed_scal``) would otherwise fall back to the default without a word;
with ``extra="forbid"`` the loader names the key and the allowed ones. Leaf module: pydantic only.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict

__all__ = ["ConfigModel", "FrozenConfigModel"]


class ConfigModel(BaseModel):
    """A config record that rejects unknown keys and checks every assignment (``--set`` and code alike).

    Flags are ``StrictBool`` in subclasses: pydantic would otherwise read "on"/"yes" as True behind the
    operator's back; YAML parsing keeps them strings so they are reported instead.
    """

    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class FrozenConfigModel(BaseModel):
    """A config record that rejects unknown keys and never changes once read (catalog, router deployment)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
