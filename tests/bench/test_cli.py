"""``cellctl bench``'s help and targets: every bench named in BENCHES answers ``--help`` and resolves to a
function in ``cellctl/bench/`` (the harness package), so a move that leaves a stale ``module:function`` fails here."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

from cellctl.cli import build_parser
from cellctl.cli.bench import BENCHES, COMMISSIONED


def _help(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as done:
        build_parser().parse_args(argv)
    assert done.value.code == 0
    return capsys.readouterr().out


def test_bench_help_lists_every_bench_from_the_console_entry_point() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "cellctl", "bench", "--help"], capture_output=True, text=True, timeout=120, check=True
    ).stdout
    assert all(name in out for name in BENCHES)


@pytest.mark.parametrize("what", sorted(BENCHES))
def test_every_bench_answers_help(what: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert "--n" in _help(["bench", what, "--help"], capsys)


@pytest.mark.parametrize("target", sorted({t for t, _ in BENCHES.values()} | {COMMISSIONED}))
def test_every_target_is_a_function_of_the_harness_package(target: str) -> None:
    mod, fn = target.split(":")
    assert mod.startswith("cellctl.bench."), target
    assert callable(getattr(importlib.import_module(mod), fn))
