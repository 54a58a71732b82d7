"""``cellctl bench inspect --commissioned`` without rendering: the figures from bin records, slices merged into
one run (and refused when they cannot be one), the decal's wall-plane lookup, the command-line flags."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from cellctl.bench.classify.inspect_commissioned import ARMS, Decal, merge, summarise
from cellctl.classify.contamination import Layer
from cellctl.errors import ConfigError


def _bin(cycle: int, kind: str, verdict: str, dirty: bool, unc: int = 0, tp: float = 0.0, fn: float = 0.0) -> dict:
    return {
        "cycle": cycle,
        "surface": "external",
        "kind": kind,
        "family": "soot" if kind == "family" else None,
        "dirty_seen": dirty,
        "dirty_unseen_only": False,
        "verdict": verdict,
        "uncertain": unc,
        "relooks": 0,
        "views": 10,
        "tp_m2": tp,
        "fp_m2": 0.0,
        "fn_m2": fn,
        "paths": {"reference": 9, "detector:far_from_prior": 1},
    }


def test_summary_counts_bins_faces_and_paths() -> None:
    bins = [
        _bin(0, "clean", "clean", False, unc=0),
        _bin(1, "clean", "dirty", False, unc=2),
        _bin(2, "family", "clean", True, tp=0.0, fn=1.0),
        _bin(3, "one_spot", "dirty", True, tp=3.0, fn=0.0),
    ]
    s = summarise(bins, [5.0, 7.0, 9.0])
    assert (s["false_clean_bins"], s["dirty_seen_bins"], s["bin_false_clean_rate"]) == (1, 2, 0.5)
    assert s["false_clean_kinds"] == ["external/family/soot"]
    assert (s["false_dirty_bins"], s["clean_bins"], s["bin_false_dirty_rate"]) == (1, 2, 0.5)
    assert s["face_recall"] == 0.75 and s["face_precision"] == 1.0
    assert s["uncertain_per_clean_cycle_median"] == 1.0 and s["per_view_ms_p50"] == 7.0
    assert s["view_paths"] == {"reference": 36, "detector:far_from_prior": 4}


def _slice(tmp_path: Path, first: int, seed: int = 0) -> Path:
    bins = [_bin(first + k, "clean", "clean", False) for k in range(2)]
    setup = {"seed": seed, "first": first, "cycles": 2, "seconds": 1.0, "loadavg_1m": 1.0, "bin": "case_study"}
    blob = {"slice": {"bins": {a: bins for a in ARMS}, "latency_ms": {a: [1.0, 2.0] for a in ARMS}, "setup": setup}}
    p = tmp_path / f"slice_{first}_{seed}.json"
    p.write_text(json.dumps(blob))
    return p


def test_slices_merge_into_one_run_and_foreign_slices_are_refused(tmp_path: Path) -> None:
    a, b = _slice(tmp_path, 0), _slice(tmp_path, 2)
    m = merge([b, a])
    assert m["cycles"] == 4 and [s["first"] for s in m["slices"]] == [0, 2]
    assert m["arms"]["references"]["clean_bins"] == 4 and m["setup"] == {"seed": 0, "bin": "case_study"}
    with pytest.raises(ConfigError, match="overlaps"):
        merge([a, a])
    with pytest.raises(ConfigError, match="different seeds"):
        merge([a, _slice(tmp_path, 2, seed=1)])
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    with pytest.raises(ConfigError, match="bad.json"):
        merge([bad])


def test_a_decal_lies_on_its_wall_only() -> None:
    n = 64
    layer = Layer(np.ones((n, n), np.float32), np.zeros((n, n, 3), np.float32), "matte", "soot", {})
    d = Decal(layer, np.zeros(3), np.array([0.0, 0, 1]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0]), 0.1)
    pts = np.array([[0.0, 0, 0], [0.04, -0.04, 0.001], [0.06, 0, 0], [0.0, 0, 0.01], [0.0, 0, 0]])
    normals = np.array([[0.0, 0, 1]] * 4 + [[0.0, 0, -1]])  # the last: the wall's other side
    inside, alpha, rgb = d.lookup(pts, normals)
    assert inside.tolist() == [True, True, False, False, False]
    assert alpha.tolist() == [1.0, 1.0, 0.0, 0.0, 0.0] and rgb.shape == (5, 3)


def test_command_line_flags_reach_the_options() -> None:
    from cellctl.cli.bench import options_from_args, register

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    args = parser.parse_args(["bench", "inspect", "--commissioned", "--seed-offset", "50", "--cycles", "50"])
    opts = options_from_args(args)
    assert (opts.commissioned, opts.first, opts.n, opts.merge) == (True, 50, 50, ())
    args = parser.parse_args(["bench", "inspect", "--merge", "a.json", "b.json"])
    assert options_from_args(args).merge == (Path("a.json"), Path("b.json"))
