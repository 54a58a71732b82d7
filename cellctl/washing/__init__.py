"""Washing: the nozzle model, wash planning from a dirt map, and the twin's powder removal."""

from cellctl.washing.nozzle import DEFAULT_NOZZLE, NozzleModel

__all__ = ["DEFAULT_NOZZLE", "NozzleModel"]
