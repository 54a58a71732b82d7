"""CLI mistakes end in one line naming the value, with a non-zero exit, before anything is sent (issue 32, item 8)."""

from __future__ import annotations

import time
from pathlib import Path

from cellctl.bus.plc_client import PlcClient
from cellctl.cli import main
from cellctl.config import CellConfig
from tests.conftest import cfg_overrides
from tests.fakes.workers import FakeCell, fake_identify


def _sets(tmp_path: Path, port: int) -> list[str]:
    return [a for ov in cfg_overrides(tmp_path, port) for a in ("--set", ov)]


def _one_error_line(capsys, rc: int) -> str:
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err, err
    return err.strip().splitlines()[-1]


def test_report_png_to_a_folder_and_to_an_unwritable_path_and_wait_bogus(
    cfg: CellConfig,
    tmp_path: Path,
    port: int,
    capsys,
) -> None:
    from cellctl.app import build_cell
    from cellctl.geometry.catalog import load_catalog

    cell = build_cell(cfg, identification=(fake_identify, load_catalog(cfg.path(cfg.catalog))))
    plc = PlcClient(cfg, "t")
    try:
        time.sleep(0.2)
        with FakeCell(cfg, dirty_viewpoints={1}):
            plc.command("reset", timeout=5)
            assert plc.wait_for(lambda s: s.state == "Idle", 10) is not None
            plc.command("start", timeout=5)
            res = plc.results.get(timeout=30)
        plc.wait_for(lambda s: s.state == "Complete", 10)
        before = cell.supervisor.state
        # --wait with a state that does not exist: refused before the command is sent
        rc = main(["cmd", "reset", "--wait", "Bogus", "--timeout", "3", *_sets(tmp_path, port)])
        assert "--wait 'Bogus' is not a PackML state" in _one_error_line(capsys, rc)
        time.sleep(0.3)
        assert cell.supervisor.state == before  # the reset never went
    finally:
        plc.close()
        cell.close()
    cid = res.cycle_id
    folder = tmp_path / "pics"
    folder.mkdir()
    assert main(["report", cid, "--png", str(folder), *_sets(tmp_path, port)]) == 0
    assert (folder / f"{cid}.png").is_file() and not Path(f"{folder}.png").exists()
    assert f"wrote {folder / f'{cid}.png'}" in capsys.readouterr().err
    blocker = tmp_path / "a-file"
    blocker.write_text("x")  # a path under a file cannot be written, whoever runs the test
    rc = main(["report", cid, "--png", str(blocker / "map.png"), *_sets(tmp_path, port)])
    assert f"cannot write the dirt map to {str(blocker / 'map.png')!r}" in _one_error_line(capsys, rc)


def test_hmi_user_add_checks_the_name_before_the_password(tmp_path: Path, monkeypatch, capsys) -> None:
    def never(*a: object) -> str:
        raise AssertionError("the password was asked for an invalid name")

    monkeypatch.setattr("getpass.getpass", never)
    rc = main(["hmi", "user", "add", "Bad Name", "--role", "operator", "--hmi-config", str(tmp_path / "hmi.yaml")])
    line = _one_error_line(capsys, rc)
    assert "key 'name'" in line and "'Bad Name'" in line
    assert not (tmp_path / "hmi.yaml").exists()


def test_replay_of_a_ten_byte_file_fails_in_one_line(tmp_path: Path, port: int, capsys) -> None:
    """The MCAP magic and two bytes: refused before any session opens (no daemon needed to say so)."""
    f = tmp_path / "ten.mcap"
    f.write_bytes(b"\x89MCAP0\r\n\x00\x01")
    rc = main(["replay", str(f), *_sets(tmp_path, port)])
    line = _one_error_line(capsys, rc)
    assert str(f) in line and "holds no readable message" in line


def test_cycles_last_must_be_positive(tmp_path: Path, port: int, capsys) -> None:
    rc = main(["cycles", "--last", "-1", *_sets(tmp_path, port)])
    assert "--last -1: expected a number of cycles >= 1" in _one_error_line(capsys, rc)
