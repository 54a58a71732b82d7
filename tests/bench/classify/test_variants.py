"""``cellctl bench classify`` helpers (no timing asserted: speed is the bench's output, not a test)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def test_interleaved_timing_calls_the_variants_in_turn_on_the_same_images() -> None:
    from cellctl.bench.classify.variants import _interleaved

    calls: list[tuple[str, int]] = []
    images = [np.full((4, 4, 3), i, np.uint8) for i in range(3)]

    def fn(name: str):
        return lambda ims: calls.append((name, int(ims[0][0, 0, 0])))

    out = _interleaved({"a": fn("a"), "b": fn("b")}, images, 4)
    assert set(out) == {"a", "b"} and all(lo <= p50 <= p95 for p50, p95, lo in out.values())
    timed = calls[-8:]  # after 3 warm-up calls each
    assert [n for n, _ in timed] == ["a", "b"] * 4
    assert [i for _, i in timed] == [0, 0, 1, 1, 2, 2, 0, 0]


def test_model_path_is_shown_relative_to_the_project_root(tmp_path: Path) -> None:
    from cellctl.bench.classify.variants import _shown

    assert _shown(tmp_path / "models" / "x.pt", tmp_path) == "models/x.pt"
    assert _shown(Path("/elsewhere/x.pt"), tmp_path) == "/elsewhere/x.pt"
