"""``cellctl validate`` refuses what ``cellctl run`` would refuse or misread, in one line naming key and value
(issue 32, item 7); ``run`` runs the same checks before it starts anything."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from cellctl.bus.endpoints import check_endpoint
from cellctl.cli import main
from tests.conftest import cfg_overrides

CELL = Path(__file__).resolve().parent.parent / "config" / "cell.yaml"


def _validate(capsys, *args: str) -> str:
    rc = main(["validate", *args])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err, err
    return err.strip().splitlines()[-1]


@pytest.mark.parametrize(
    ("override", "said"),
    [
        (f"catalog={CELL}", f"catalog: {str(CELL)!r} is not a bin catalog: expected a top-level 'bins' mapping"),
        ("catalog=/nonexistent/bins.yaml", "catalog: bin catalog '/nonexistent/bins.yaml' does not exist"),
        ("bus.listen=[nonsense]", "key 'bus.listen': Value error, endpoint 'nonsense' is not a Zenoh endpoint"),
        ('bus.connect=["tcp/127.0.0.1"]', "endpoint 'tcp/127.0.0.1': expected tcp/<host>:<port 0..65535>"),
        ('bus.connect=["carrier-pigeon/x"]', "protocol 'carrier-pigeon' is unknown"),
        ("sim.bin_type=crate", "sim.bin_type 'crate' is not in the catalog"),
    ],
)
def test_validate_refuses_what_run_cannot_use(capsys, override: str, said: str) -> None:
    assert said in _validate(capsys, str(CELL), "--set", override)


def test_duplicate_keys_and_binary_files_are_refused(tmp_path: Path, capsys) -> None:
    dup = tmp_path / "dup.yaml"
    dup.write_text("cell:\n  id: a\nsim:\n  seed: 1\n  seed: 2\n")
    assert "duplicate key 'seed' at line 5 (first at line 4)" in _validate(capsys, str(dup))
    binary = tmp_path / "cell.yaml"
    binary.write_bytes(b"cell:\n  id: a\n\xff\xfe\x00\x01")
    assert "not a YAML text file (byte 14 is not UTF-8 text)" in _validate(capsys, str(binary))


def test_endpoint_check() -> None:
    good = ("tcp/127.0.0.1:7447", "tls/cell1.example:7447", "udp/[::1]:7447", "tcp/127.0.0.1:0", "unixsock-stream/x")
    for ok in good:
        assert check_endpoint(ok) == ok
    for bad in ("nonsense", "tcp/127.0.0.1:70000", "tcp/:7447", "foo/bar"):
        with pytest.raises(ValueError, match=repr(bad)):
            check_endpoint(bad)


def test_run_refuses_the_same_config_before_starting(tmp_path: Path, port: int) -> None:
    """Bounded: a run that starts anyway would serve until the timeout."""
    sets = [a for ov in [*cfg_overrides(tmp_path, port), "sim.bin_type=crate"] for a in ("--set", ov)]
    out = subprocess.run(
        [sys.executable, "-m", "cellctl", "run", "--config", str(CELL), *sets],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "sim.bin_type 'crate' is not in the catalog" in out.stderr.strip().splitlines()[-1]
