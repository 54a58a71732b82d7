"""Check that two versions of ``collect_cycles`` (``cellctl bench inspect``'s detector side) give the same run.

The plans are pinned: the planner's fast mode orders the external tour differently from run to run under load
(seen on 2 shared cores: two runs of the same code differed from the first external view on), which is not
what a refactoring of the bench is checked for. The first run plans and pickles the plans; later runs reuse them.

    git show HEAD~1:cellctl/bench/classify/inspect.py > /tmp/old_inspect.py
    python tools/compare_collect_cycles.py run /tmp/old_inspect.py /tmp/old.pkl
    python tools/compare_collect_cycles.py run cellctl/bench/classify/inspect.py /tmp/new.pkl
    python tools/compare_collect_cycles.py compare /tmp/old.pkl /tmp/new.pkl

Cycles 2..5 of seed 0 (one spot and many spots on both surfaces, with re-looks); every view's faces, camera pose,
heat map and p_dirty, the labels, the truth and the classifier's PNGs must be equal.
"""

from __future__ import annotations

import importlib.util
import os
import pickle
import sys
from typing import Any

import numpy as np

PLANS = os.environ.get("PINNED_PLANS", "/tmp/collect_cycles_plans.pkl")


def _pin_plans() -> None:
    import cellctl.planning.pipeline as pipeline

    real = pipeline.make_plan
    cache: dict[str, Any] = {}
    if os.path.exists(PLANS):
        with open(PLANS, "rb") as f:
            cache = pickle.load(f)

    def pinned(mesh: Any, T: Any, params: Any, robot: Any, **kw: Any) -> Any:
        if params.surface not in cache:
            cache[params.surface] = real(mesh, T, params, robot, **kw)
            with open(PLANS, "wb") as f:
                pickle.dump(cache, f)
        return cache[params.surface]

    pipeline.make_plan = pinned


def run(path: str, out: str) -> None:
    from cellctl.bench.options import BenchOptions

    _pin_plans()
    spec = importlib.util.spec_from_file_location("inspect_under_test", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    result = mod.collect_cycles(BenchOptions(n=6, seed=0), first=2, keep_images=True)
    for varying in ("seconds", "loadavg_1m"):
        result["setup"].pop(varying)
    cycles = [
        {**c, "views": [(v.faces, v.T_bin_cam, v.heat, v.p_dirty) for v in c["views"]]} for c in result["cycles"]
    ]
    with open(out, "wb") as f:
        pickle.dump({"cycles": cycles, "setup": result["setup"], "relook": result["relook"]}, f)


def _equal(x: Any, y: Any, path: str = "") -> None:
    if isinstance(x, dict):
        assert x.keys() == y.keys(), path
        for k in x:
            _equal(x[k], y[k], f"{path}/{k}")
    elif isinstance(x, (list, tuple)):
        assert len(x) == len(y), path
        for i, (p, q) in enumerate(zip(x, y, strict=True)):
            _equal(p, q, f"{path}[{i}]")
    elif isinstance(x, np.ndarray):
        assert x.shape == y.shape and x.dtype == y.dtype and np.array_equal(x, y), path
    else:
        assert x == y, (path, x, y)


def compare(a: str, b: str) -> None:
    with open(a, "rb") as f, open(b, "rb") as g:
        left, right = pickle.load(f), pickle.load(g)
    _equal(left, right)
    views = sum(len(c["views"]) for c in left["cycles"])
    print(f"identical: {len(left['cycles'])} cycles, {views} views (faces, pose, heat, p_dirty, PNG)")


if __name__ == "__main__":
    {"run": run, "compare": compare}[sys.argv[1]](sys.argv[2], sys.argv[3])
