"""One plan's independent stages on several cores: forked worker processes.

A whole-bin plan evaluates every candidate station (reach, connection, visibility) and each
evaluation depends only on the plan's shared set-up, never on another station's: they can run
at once. The workers are **forked** so that they inherit the set-up as it is (meshes, the ray
caster, the distance grid, closures) with nothing pickled on the way in; only each result
travels back (pickled through a pipe). Results come back in the order of ``items`` whatever
worker computed them and in what order, so a plan is the same with 1 or N workers.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import traceback
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection, wait
from typing import Any, TypeVar

__all__ = ["default_workers", "fork_map"]

T = TypeVar("T")
R = TypeVar("R")


def default_workers() -> int:
    """Worker processes for one plan: the cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def _serve(fn: Callable[[Any], Any], items: Sequence[Any], tasks: Any, out: Connection) -> None:
    """A worker: take item indices from ``tasks`` until None, send ``(index, ok, result)`` back."""
    while True:
        i = tasks.get()
        if i is None:
            break
        try:
            out.send((i, True, fn(items[i])))
        except BaseException:  # the parent re-raises it with the worker's traceback
            out.send((i, False, traceback.format_exc()))
            break
    out.close()


def fork_map(fn: Callable[[T], R], items: Sequence[T], workers: int) -> list[R]:
    """``[fn(x) for x in items]`` on up to ``workers`` forked processes (in process for ≤ 1).

    Items are handed out one at a time (a slow candidate does not hold up the others); every
    result is pickled back. Without the ``fork`` start method (not Linux), or in a daemonic
    process, it runs in process.

    Raises:
        RuntimeError: a worker's exception (its traceback in the message) or a worker that died.
    """
    n = min(int(workers), len(items))
    # a daemonic process (a multiprocessing.Pool worker) may not start processes: in process there
    if n <= 1 or "fork" not in mp.get_all_start_methods() or mp.current_process().daemon:
        return [fn(x) for x in items]
    ctx = mp.get_context("fork")
    tasks = ctx.SimpleQueue()
    for i in range(len(items)):
        tasks.put(i)
    for _ in range(n):
        tasks.put(None)
    procs, conns = [], []
    for _ in range(n):
        r, s = ctx.Pipe(duplex=False)
        p = ctx.Process(target=_serve, args=(fn, items, tasks, s), daemon=True)
        p.start()
        s.close()  # the parent's copy: the pipe reads EOF when the worker's end closes
        procs.append(p)
        conns.append(r)
    results: dict[int, Any] = {}
    error: str | None = None
    try:
        live = list(conns)
        while live:
            for c in wait(live):
                try:
                    i, ok, res = c.recv()  # type: ignore[union-attr]
                except EOFError:
                    live.remove(c)
                    continue
                if not ok:
                    error = f"a planning worker failed on item {i}:\n{res}"
                    live = []
                    break
                results[i] = res
    finally:
        for p in procs:
            if error is not None:
                p.terminate()
            p.join()
        for c in conns:
            c.close()
    if error is not None:
        raise RuntimeError(error)
    missing = [i for i in range(len(items)) if i not in results]
    if missing:
        codes = [p.exitcode for p in procs]
        raise RuntimeError(f"planning workers died (exit codes {codes}) before items {missing} were done")
    return [results[i] for i in range(len(items))]
