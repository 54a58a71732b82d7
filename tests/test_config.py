"""Config files are typed; unknown keys and wrong values are named with what is allowed."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.config import default_config_path, load_config
from cellctl.errors import ConfigError


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "cell.yaml"
    p.write_text(text)
    return p


def test_default_config_loads() -> None:
    cfg = load_config()
    assert cfg.cell_id == "cell1"
    assert cfg.bus.listen == ["tcp/127.0.0.1:7447"]
    assert cfg.path(cfg.catalog) == default_config_path().parent / "bins.yaml"


@pytest.mark.parametrize(
    "text, message",
    [
        ("robot:\n  speed: 2\n", "unknown key 'robot.speed'; allowed keys here: ['backend', "),
        (
            "robot:\n  speed_scale: fast\n",
            "key 'robot.speed_scale': Input should be a valid number, unable to parse string as a number (got 'fast')",
        ),
        (
            "camera:\n  backend: webcam\n",
            "key 'camera.backend': Input should be 'sim', 'opencv' or 'folder' (got 'webcam')",
        ),
        ("supervisor:\n  timeouts: {move: -1}\n", "key 'supervisor.timeouts.move': Input should be greater than 0"),
        ("supervisor:\n  required_workers: [robot, gripper]\n", "unknown worker roles ['gripper']"),
        ("cell:\n  id: 'a/b'\n", "cell id 'a/b' is invalid"),
        ("colour: blue\n", "unknown key 'colour'"),
        ("- a\n- b\n", "top level must be a mapping"),
        ("robot: [\n", "not valid YAML"),
    ],
)
def test_bad_config_is_explained(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ConfigError) as exc:
        load_config(write(tmp_path, text))
    assert message in str(exc.value)


def test_on_off_stay_strings_so_they_are_rejected_not_misread(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"supervisor.auto_reset.*got 'on'"):
        load_config(write(tmp_path, "supervisor:\n  auto_reset: on\n"))


def test_overrides_and_relative_paths(tmp_path: Path) -> None:
    cfg = load_config(
        write(tmp_path, "recording:\n  dir: out\n"), ["supervisor.auto_reset=true", "robot.speed_scale=5"]
    )
    assert cfg.supervisor.auto_reset is True and cfg.robot.speed_scale == 5
    assert cfg.path(cfg.recording.dir) == tmp_path / "out"
    with pytest.raises(ConfigError, match="expected KEY.PATH=VALUE"):
        load_config(write(tmp_path, ""), ["robot.speed_scale"])


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "nope.yaml")
