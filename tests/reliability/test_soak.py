"""The soak bench's growth verdict, and a short soak of the real sim cell (slow)."""

from __future__ import annotations

import random

import pytest

from cellctl.bench.reliability.soak import growth


def _samples(values: list[float]) -> list[dict]:
    return [{"cycle": i, "daemon": {"rss_mb": v, "fds": 40, "threads": 18}} for i, v in enumerate(values)]


def test_flat_noisy_memory_is_no_growth() -> None:
    rng = random.Random(0)
    g = growth(_samples([200 + rng.gauss(0, 1.5) for _ in range(100)]), "daemon", "rss_mb")
    assert g["ok"] is True


def test_warm_up_is_not_counted_as_growth() -> None:
    values = [150 + 5 * i for i in range(10)] + [200.0] * 90  # caches fill during the first 10 %
    assert growth(_samples(values), "daemon", "rss_mb")["ok"] is True


def test_a_steady_leak_is_growth() -> None:
    g = growth(_samples([200 + 0.2 * i for i in range(100)]), "daemon", "rss_mb")  # 0.2 MB per sample
    assert g["ok"] is False and g["growth"] > 10


def test_leaked_descriptors_are_growth() -> None:
    samples = [{"cycle": i, "daemon": {"rss_mb": 200, "fds": 40 + i // 5, "threads": 18}} for i in range(100)]
    assert growth(samples, "daemon", "fds")["ok"] is False


def test_too_few_samples_give_no_verdict() -> None:
    assert growth(_samples([1, 2, 3]), "daemon", "rss_mb")["ok"] is None


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_short_soak_of_the_sim_cell_completes_every_cycle_without_leaking_descriptors(port: int) -> None:
    from cellctl.bench.options import BenchOptions
    from cellctl.bench.reliability.soak import bench_soak

    ep = f'["tcp/127.0.0.1:{port}"]'
    out = bench_soak(BenchOptions(n=25, overrides=(f"bus.listen={ep}", f"bus.connect={ep}")))
    assert out["outcomes"] == {"completed": 25}, out["failures"]
    for name, per in out["growth"].items():
        assert per["fds"]["ok"] is not False, (name, per["fds"])
        assert per["threads"]["ok"] is not False, (name, per["threads"])
    assert out["audit"]["ok"], out["audit"]
