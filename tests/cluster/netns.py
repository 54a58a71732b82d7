"""The netns harness for the cluster tests: skip with the reason where namespaces are not allowed.

The harness itself (:mod:`cellctl.bench.reliability.netns`, the relay, :mod:`cellctl.bench.reliability.cluster`)
lives in the package because ``cellctl bench cluster`` builds the same plant.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.bench.reliability.cluster import Cluster, ClusterOptions
from cellctl.bench.reliability.netns import netns_unavailable

__all__ = ["cluster_of", "require_netns"]


def require_netns() -> None:
    why = netns_unavailable()
    if why is not None:
        pytest.skip(f"cluster tests need network namespaces: {why}")


def cluster_of(tmp: Path, **opts: object) -> Cluster:
    require_netns()
    return Cluster(ClusterOptions(**opts), tmp)  # type: ignore[arg-type]
