"""Benches are library functions of a typed BenchOptions; the CLI only builds the options."""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path

import pytest

from cellctl.bench.options import BenchOptions
from cellctl.cli import build_parser
from cellctl.cli.bench import BENCHES, options_from_args
from cellctl.errors import ConfigError


def test_options_from_the_command_line() -> None:
    argv = ["bench", "soak", "--cycles", "7", "--seed", "3", "--set", "a.b=1", "--out", "x.json"]
    args = build_parser().parse_args(argv)
    opts = options_from_args(args)
    assert opts == BenchOptions(n=7, seed=3, overrides=("a.b=1",), out=Path("x.json"))
    assert options_from_args(build_parser().parse_args(["bench", "bus"])) == BenchOptions()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n": 0}, "n=0 must be a positive integer"),
        ({"n": -5}, "n=-5"),
        ({"n": True}, "n=True"),
        ({"n": 2.5}, "n=2.5"),
        ({"seed": "0"}, "seed '0' must be an integer"),
        ({"overrides": "a=1"}, "overrides 'a=1' must be a sequence"),
    ],
)
def test_bad_options_are_refused_naming_the_value(kwargs: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        BenchOptions(**kwargs)


def test_options_normalise_and_load_the_config() -> None:
    opts = BenchOptions(overrides=["supervisor.auto_reset=true"], out="o/bench.json")  # type: ignore[arg-type]
    assert opts.overrides == ("supervisor.auto_reset=true",) and opts.out == Path("o/bench.json")
    assert opts.load_config().supervisor.auto_reset is True


@pytest.mark.parametrize("what", sorted(BENCHES))
def test_every_bench_takes_one_typed_options_argument(what: str) -> None:
    mod, fn = BENCHES[what][0].split(":")
    bench = getattr(importlib.import_module(mod), fn)
    params = list(inspect.signature(bench).parameters.values())
    assert [p.name for p in params] == ["opts"]
    assert params[0].annotation in (BenchOptions, "BenchOptions")
