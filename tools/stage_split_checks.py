"""Fingerprints of what three stage-split functions produce, to show a refactor left them the same (issue 33).

Run it once in the tree before the change and once after, and diff the two outputs::

    git archive <before> | tar -x -C /tmp/before
    PYTHONPATH=/tmp/before python tools/stage_split_checks.py detector /tmp/contam > before.json
    PYTHONPATH=.           python tools/stage_split_checks.py detector /tmp/contam > after.json
    diff before.json after.json

(``PYTHONPATH`` picks the tree whose ``cellctl`` runs; the tool itself only imports it.) Checks:

- ``detector ROOT``: :func:`cellctl.classify.fusion.train_detector` on a small seeded contamination set (built
  under ``ROOT`` on the first run: 48 external close-ups, seed 3, and a calibration draw, seed 5): 1 epoch, then
  two continued trainings (``init_from`` + ``calib``, fused and supervised). Prints a digest of every weight
  tensor, the card less its clock fields (``created``, ``train_seconds``), and the file's sha256 (in the card).
- ``twin``: 30 draws of :func:`cellctl.classify._twin_source.make_twin_source` (external, external shifted,
  internal; and, with ``--plans DIR``, drawing planned viewpoints from the cached plans there): a digest of each
  image, label mask and surface mask, and the recorded params.
- ``identify``: runs ``tests/vision/test_identify.py``, ``test_twin_identification.py`` and ``test_fuse.py``
  and records every :func:`cellctl.vision.identify.identify` outcome: the identification less ``elapsed_ms``,
  or the refusal's code and message.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np


def _plain(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return np.round(v.astype(float), 12).tolist()
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, float):
        return round(v, 12)
    return v


def check_detector(root: Path) -> dict[str, Any]:
    import torch

    from cellctl.classify.contam_dataset import contam_dataset
    from cellctl.classify.fusion import train_detector

    root.mkdir(parents=True, exist_ok=True)
    if not (root / "train").exists():
        contam_dataset(root / "train", "external", 48, seed=3, source="closeup", size=96)
        contam_dataset(root / "calib", "external", 24, seed=5, source="closeup", size=96)
    torch.manual_seed(0)  # the heads' initialisation draws from torch's global generator
    first = root / "out" / "a.detect.pt"
    runs: dict[str, dict[str, Any]] = {
        "a": {"epochs": 1, "bank_size": 32},
        "b": {"epochs": 0, "bank_size": 32, "init_from": first, "calib": root / "calib"},
        "c": {"epochs": 0, "bank_size": 32, "init_from": first, "calib": root / "calib"}
        | {"decision_score": "supervised"},
    }
    out: dict[str, Any] = {}
    for name, kw in runs.items():
        path = root / "out" / f"{name}.detect.pt"
        card = train_detector(root / "train", "external", path, **kw)
        for k in ("created", "train_seconds"):
            card.pop(k)
        blob = torch.load(path, weights_only=True)
        digest: dict[str, Any] = {}
        for k, v in sorted(blob.items()):
            if isinstance(v, dict):
                raw = b"".join(t.numpy().tobytes() for _, t in sorted(v.items()))
                digest[k] = hashlib.sha256(raw).hexdigest()[:16]
            elif isinstance(v, torch.Tensor):
                digest[k] = hashlib.sha256(v.numpy().tobytes()).hexdigest()[:16]
            else:
                digest[k] = v
        out[name] = {"blob": digest, "card": card}
    return out


def check_twin(plans: Path | None) -> dict[str, Any]:
    from cellctl.classify._twin_source import make_twin_source
    from cellctl.config import load_config

    cases: list[tuple[str, bool, Any]] = [("external", False, None), ("external", True, None)]
    cases.append(("internal", False, None))
    if plans is not None:
        cfg = load_config(None, [f"planner.plans_dir={plans.resolve()}"])
        cases += [("external", False, cfg), ("internal", True, cfg)]
    out: dict[str, Any] = {}
    for surface, shifted, cfg in cases:
        draw = make_twin_source(surface, 96, shifted, 0, cfg)
        rng = np.random.default_rng(7)
        for i in range(6):
            s = draw(rng, i % 2 == 0)
            raw = s.rgb.tobytes() + np.asarray(s.powder).tobytes() + np.asarray(s.surface).tobytes()
            out[f"{surface}/{shifted}/{cfg is not None}/{i}"] = {
                "h": hashlib.sha256(raw).hexdigest()[:16],
                "params": s.params,
            }
    return out


class _IdentifyLog:
    """A pytest plugin that wraps :func:`identify` before the test modules import it and logs every outcome."""

    def __init__(self) -> None:
        import cellctl.vision as pkg

        mod = sys.modules["cellctl.vision.identify"]  # the package re-exports the function under the same name
        orig = mod.identify
        self.log: list[Any] = []

        def identify(*a: Any, **k: Any) -> Any:
            try:
                r = orig(*a, **k)
            except Exception as err:
                self.log.append({"error": type(err).__name__, "code": getattr(err, "code", None), "msg": str(err)})
                raise
            self.log.append(_plain({f: getattr(r, f) for f in r.__dataclass_fields__ if f != "elapsed_ms"}))
            return r

        mod.identify = identify
        if getattr(pkg, "identify", None) is orig:
            pkg.identify = identify


def check_identify() -> list[Any]:
    import pytest

    plugin = _IdentifyLog()
    tests = [f"tests/vision/{t}.py" for t in ("test_identify", "test_twin_identification", "test_fuse")]
    rc = pytest.main(["-q", "-p", "no:cacheprovider", *tests], plugins=[plugin])
    if rc != 0:
        sys.exit(f"the identify tests failed (exit {rc})")
    return plugin.log


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="check", required=True)
    d = sub.add_parser("detector")
    d.add_argument("root", type=Path, help="folder for the seeded data set and the trained detectors")
    t = sub.add_parser("twin")
    t.add_argument("--plans", type=Path, help="a plans folder (planned viewpoints are drawn from it)")
    sub.add_parser("identify")
    args = ap.parse_args()
    if args.check == "detector":
        result: Any = check_detector(args.root)
    elif args.check == "twin":
        result = check_twin(args.plans)
    else:
        result = check_identify()
    sys.stdout.flush()
    print(json.dumps(result, indent=1, sort_keys=True, default=str))


if __name__ == "__main__":
    main()
