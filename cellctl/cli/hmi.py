"""``cellctl hmi``: the operator's web screen and REST API; ``cellctl hmi user …`` manages its logins."""

from __future__ import annotations

import argparse
import getpass
import sys
from pathlib import Path

from cellctl.cli import add_config_arguments, config_from_args
from cellctl.errors import ConfigError


def _hmi_config_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--hmi-config", default=None,
                   help="HMI config YAML (default: hmi.yaml beside the cell config; users, port)")  # fmt: skip
    p.add_argument("--hmi-set", dest="hmi_overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override an HMI config key, e.g. --hmi-set port=8081 (repeatable)")  # fmt: skip


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("hmi", help="serve the operator HMI and REST API (http://127.0.0.1:8080 by default)")
    _hmi_config_arguments(p)
    p.add_argument("--host", default=None, help="bind address (default from the HMI config: 127.0.0.1)")
    p.add_argument("--port", type=int, default=None, help="HTTP port (default from the HMI config: 8080)")
    p.add_argument("--foxglove", action="store_true", help="also serve the live Foxglove view (ws 127.0.0.1:8765)")
    p.add_argument("--principal", default="hmi", help="who the HMI is on a secured bus (default: hmi)")
    add_config_arguments(p)
    p.set_defaults(func=run_hmi)
    users = p.add_subparsers(dest="hmi_verb", metavar="user", required=False)
    u = users.add_parser("user", help="add, remove or list HMI users (hmi.yaml beside the cell config)")
    usub = u.add_subparsers(dest="user_verb", required=True)
    add = usub.add_parser("add", help="add a user or set a new password (read from the terminal or stdin)")
    add.add_argument("name")
    # checked by HmiUser before the password is asked (hmi.config.ROLES: importing it here would load the server)
    add.add_argument("--role", required=True, help="operator, maintenance, qa (review only) or viewer (read only)")
    add.add_argument("--password-stdin", action="store_true", help="read the password from stdin (scripts)")
    rm = usub.add_parser("remove", help="remove a user")
    rm.add_argument("name")
    usub.add_parser("list", help="list users and roles")
    for q in (add, rm, usub.choices["list"]):
        _hmi_config_arguments(q)
        q.set_defaults(func=run_user)


def _hmi_path(args: argparse.Namespace) -> Path:
    """``--hmi-config``, else ``hmi.yaml`` beside the cell config in use (``./config/hmi.yaml`` with the
    packaged defaults): user edits never land in the install."""
    from cellctl.config import PACKAGED

    if args.hmi_config:
        return Path(args.hmi_config)
    if getattr(args, "config_source", PACKAGED) == PACKAGED:
        return Path.cwd() / "config" / "hmi.yaml"
    return Path(args.config).resolve().parent / "hmi.yaml"


def run_user(args: argparse.Namespace) -> int:
    from cellctl.hmi.auth import hash_password
    from cellctl.hmi.config import HmiUser, load_hmi_config, save_hmi_config

    path = _hmi_path(args)
    hcfg = load_hmi_config(path if path.is_file() else None, args.hmi_overrides)
    if args.user_verb == "list":
        for u in hcfg.users:
            print(f"{u.name}\t{u.role}")
        return 0
    others = [u for u in hcfg.users if u.name != args.name]
    if args.user_verb == "remove":
        if len(others) == len(hcfg.users):
            raise ConfigError(f"user {args.name!r} is not in {str(path)!r}; users: {[u.name for u in hcfg.users]}")
        hcfg.users = others
    else:
        _check_user(args.name, args.role, path)  # before the password is asked: a bad name wastes no typing
        if args.password_stdin:
            password = sys.stdin.readline().rstrip("\n")
        else:
            password = getpass.getpass(f"password for {args.name}: ")
            if getpass.getpass("again: ") != password:
                raise ConfigError("the two passwords differ; nothing changed")
        hcfg.users = [*others, HmiUser(name=args.name, role=args.role, password_hash=hash_password(password))]
    save_hmi_config(hcfg, path)
    print(f"{path}: {args.user_verb} {args.name}", file=sys.stderr)
    return 0


def _check_user(name: str, role: str, path: Path) -> None:
    """Raise ConfigError naming the value if ``name``/``role`` would not make a valid HMI user."""
    from pydantic import ValidationError

    from cellctl.config import explain_validation
    from cellctl.hmi.config import HmiUser

    try:
        HmiUser.model_validate({"name": name, "role": role, "password_hash": "scrypt$"})  # a stand-in hash
    except ValidationError as err:
        raise ConfigError(explain_validation(err, HmiUser, f"{path}: user").replace("\n", "; ")) from None


def run_hmi(args: argparse.Namespace) -> int:
    from cellctl.hmi.config import load_hmi_config
    from cellctl.hmi.server import Hmi, HmiServer

    cfg = config_from_args(args)
    if cfg.bus.security_dir is not None:
        # its own principal (cellctl.bus.security), not the config's: bus.yaml names `operator`, which may not command
        cfg.bus.principal = args.principal
    path = _hmi_path(args)
    hcfg = load_hmi_config(path if args.hmi_config or path.is_file() else None, args.hmi_overrides)
    if args.host is not None:
        hcfg.host = args.host
    if args.port is not None:
        hcfg.port = args.port
    if args.foxglove:
        hcfg.foxglove.enabled = True
    if not hcfg.users:
        print(f"cellctl hmi: no users in {path}: read-only (add one with `cellctl hmi user add NAME --role operator`)",
              file=sys.stderr)  # fmt: skip
    hmi = Hmi(cfg, hcfg)
    try:
        server = HmiServer(hmi)
        print(f"cellctl hmi: cell {cfg.cell_id!r} on {cfg.bus.connect}; serving {server.url}", file=sys.stderr)
        if hmi.foxglove is not None:
            print(f"cellctl hmi: live Foxglove view on ws://{hcfg.foxglove.host}:{hcfg.foxglove.port}", file=sys.stderr)
        server.run()
    finally:
        hmi.close()
    return 0
