"""``cellctl`` with the bin-identification double, as a process tests can SIGKILL (tests only).

``python -m tests.fakes.daemon run --set ...`` is ``cellctl run`` except that the identify
step uses :func:`tests.fakes.workers.fake_identify`: the worker doubles send flat grey
images, in which the real ChArUco identification would (rightly) find no bin.
"""

from __future__ import annotations

import sys
from typing import Any

from cellctl import app
from cellctl.cli import main
from cellctl.config import CellConfig
from tests.fakes.workers import fake_identify


def fake_identification(cfg: CellConfig) -> tuple[Any, Any]:
    from cellctl.geometry.catalog import load_catalog

    return fake_identify, load_catalog(cfg.path(cfg.catalog))


if __name__ == "__main__":
    app.load_identification = fake_identification  # the composition root's one seam for identification
    sys.exit(main(sys.argv[1:]))
