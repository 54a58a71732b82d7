"""What a step sees of the cycle: the blackboard limited to what the step declares (FlexBE's ``UserData``).

A step declares the blackboard fields (``record.field``, e.g. ``scan.plan``) it ``READS`` (needs set:
the loader checks a step before it writes them), ``CONSULTS`` (uses when set, tests for None or
empty itself) and ``WRITES``. Its ``execute`` gets ``run.ctx`` as a :class:`StepView`:

* a read of a field neither read nor consulted raises :class:`~cellctl.errors.UndeclaredAccess`,
  unless the step wrote that field itself earlier in the same activation (it reads its own output);
* an assignment to a field not written raises it too;
* a list or dict field the step may read but not write comes as a read-only copy, whose mutation
  (``append``, ``pop``, item assignment) raises it: mutating a member is a write. Only the field's own
  container is guarded, not the objects inside it (``wash.run["refused"]`` is a list in a dict);
* methods and properties of the records and of the context (``ctx.surface``,
  ``ctx.stations.current_station()``) run against the view, so the fields they read count as the
  step's reads;
* the cycle's infrastructure (``cfg``, ``log``, ``pool``, timings, injected services) and its Start
  inputs (``mode``, ``params``, ``user``) are not blackboard: every step may read them; the inputs
  and the records themselves cannot be replaced.

Behaviours, the runner and the result assembly work on the :class:`CycleContext` itself.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable
from typing import Any, NoReturn, cast

from cellctl.errors import ConfigError, UndeclaredAccess
from cellctl.supervisor.context import BLACKBOARD, RECORDS, CycleContext, StepRun

__all__ = ["Declared", "StepView", "check_declared", "seen_by"]

INPUTS = frozenset({"cycle_id", "cfg", "session", "mode", "params", "user", "started", "log_rel"})
"""Context fields a step may read but never replace (the Start's inputs and the cycle's identity)."""


class Declared:
    """One step's declaration, split per record: ``readable[record]`` and ``writable[record]`` field names."""

    def __init__(self, step: str, reads: Iterable[str], consults: Iterable[str], writes: Iterable[str]) -> None:
        self.step = step
        self.readable: dict[str, frozenset[str]] = _by_record([*reads, *consults])
        self.writable: dict[str, frozenset[str]] = _by_record(writes)


def _by_record(names: Iterable[str]) -> dict[str, frozenset[str]]:
    out: dict[str, set[str]] = {}
    for n in names:
        rec, _, field = n.partition(".")
        out.setdefault(rec, set()).add(field)
    return {k: frozenset(v) for k, v in out.items()}


def check_declared(step: str, **declared: Iterable[str]) -> None:
    """Refuse a declaration naming a field the blackboard does not have (at import of the step registry).

    Raises:
        ConfigError: naming the step, the declaration and the unknown name.
    """
    for kind, names in declared.items():
        unknown = sorted(set(names) - BLACKBOARD)
        if unknown:
            raise ConfigError(
                f"step {step!r} declares {kind} {unknown}, not blackboard fields (record.field); "
                f"the records are {sorted(RECORDS)}"
            )


def _refuse(step: str, what: str) -> NoReturn:
    raise UndeclaredAccess(f"step {step!r} {what}")


class _ReadOnlyList(list[Any]):
    """A copy of a list field the step may read but not write; mutating it is an undeclared write."""

    def __init__(self, items: Iterable[Any], step: str, name: str) -> None:
        super().__init__(items)
        self._who = (step, name)

    def _deny(self, *_: Any, **__: Any) -> NoReturn:
        _refuse(self._who[0], f"changes {self._who[1]}, which it does not declare in WRITES")

    append = extend = insert = pop = remove = clear = sort = reverse = _deny
    __setitem__ = __delitem__ = __iadd__ = __imul__ = _deny


class _ReadOnlyDict(dict[Any, Any]):
    """A copy of a dict field the step may read but not write; mutating it is an undeclared write."""

    def __init__(self, items: dict[Any, Any], step: str, name: str) -> None:
        super().__init__(items)
        self._who = (step, name)

    def _deny(self, *_: Any, **__: Any) -> NoReturn:
        _refuse(self._who[0], f"changes {self._who[1]}, which it does not declare in WRITES")

    pop = popitem = clear = update = setdefault = _deny
    __setitem__ = __delitem__ = __ior__ = _deny


class _RecordView:
    """One sub-record as a step sees it."""

    def __init__(self, record: Any, name: str, declared: Declared, written: set[str]) -> None:
        object.__setattr__(self, "_record", record)
        object.__setattr__(self, "_name", name)
        object.__setattr__(self, "_read", declared.readable.get(name, frozenset()))
        object.__setattr__(self, "_write", declared.writable.get(name, frozenset()))
        object.__setattr__(self, "_step", declared.step)
        object.__setattr__(self, "_written", written)

    def __getattr__(self, field: str) -> Any:
        record = self._record
        attr = getattr(type(record), field, None)
        if isinstance(attr, property) and attr.fget is not None:
            return attr.fget(self)
        if callable(attr):  # a method: its reads go through this view
            return attr.__get__(self)
        if field not in record.__dataclass_fields__:
            raise AttributeError(f"{type(record).__name__} has no field {field!r}")
        dotted = f"{self._name}.{field}"
        if field not in self._read and dotted not in self._written:
            _refuse(self._step, f"reads {dotted}, which it does not declare in READS or CONSULTS")
        value = getattr(record, field)
        if field in self._write or dotted in self._written:
            return value
        if isinstance(value, list):
            return _ReadOnlyList(value, self._step, dotted)
        if isinstance(value, dict):
            return _ReadOnlyDict(value, self._step, dotted)
        return value

    def __setattr__(self, field: str, value: Any) -> None:
        dotted = f"{self._name}.{field}"
        if field not in self._record.__dataclass_fields__:
            raise AttributeError(f"{type(self._record).__name__} has no field {field!r}")
        if field not in self._write:
            _refuse(self._step, f"writes {dotted}, which it does not declare in WRITES")
        setattr(self._record, field, value)
        self._written.add(dotted)


class StepView:
    """The cycle context as one step activation sees it (module doc)."""

    def __init__(self, ctx: CycleContext, declared: Declared) -> None:
        object.__setattr__(self, "_ctx", ctx)
        object.__setattr__(self, "_declared", declared)
        written: set[str] = set()
        views = {name: _RecordView(getattr(ctx, name), name, declared, written) for name in RECORDS}
        object.__setattr__(self, "_views", views)

    def __getattr__(self, name: str) -> Any:
        if name in self._views:
            return self._views[name]
        attr = getattr(type(self._ctx), name, None)
        if isinstance(attr, property) and attr.fget is not None:
            return attr.fget(self)
        return getattr(self._ctx, name)

    def __setattr__(self, name: str, value: Any) -> None:
        if name in RECORDS or name in INPUTS:
            _refuse(self._declared.step, f"replaces the cycle's {name}")
        if name not in self._ctx.__dataclass_fields__:
            raise AttributeError(f"CycleContext has no field {name!r}")
        setattr(self._ctx, name, value)  # infrastructure: the pool, the timings


def seen_by(run: StepRun, declared: Declared) -> StepRun:
    """The activation ``run`` as the step of ``declared`` runs it: the same cancellation flag and calls,
    ``ctx`` limited to what the step declares (typed as the context it stands for)."""
    ctx: Any = run.ctx
    if isinstance(ctx, StepView):  # a step run inside another's activation sees the blackboard anew
        ctx = object.__getattribute__(ctx, "_ctx")
    out = copy.copy(run)
    out.ctx = cast(CycleContext, StepView(ctx, declared))
    return out
