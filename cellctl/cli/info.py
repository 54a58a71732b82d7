"""``cellctl schema``, ``cellctl states``, ``cellctl validate``: the contracts, printed."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("schema", help="print the JSON Schemas of every wire message (--config: the config's keys)")
    p.add_argument("type", nargs="?", default=None, help="one message type, e.g. cellctl/Command")
    p.add_argument(
        "--config", action="store_true", help="instead: every cell config key with its default and description"
    )
    p.set_defaults(func=run_schema)

    s = sub.add_parser("states", help="print the PackML and cycle state machines")
    s.add_argument("--mermaid", action="store_true", help="as a Mermaid stateDiagram-v2")
    s.set_defaults(func=run_states)

    v = sub.add_parser("validate", help="validate a cell config file (and the state machines) as `run` reads it")
    v.add_argument(
        "file", nargs="?", default=None, help="default: $CELLCTL_CONFIG, else ./config/cell.yaml, else the packaged one"
    )
    v.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    v.set_defaults(func=run_validate)


def run_schema(args: argparse.Namespace) -> int:
    from cellctl.bus.codec import json_schemas
    from cellctl.errors import ProtocolError

    if args.config:
        from cellctl.config import config_leaves

        for key, default, description in config_leaves():
            shown = str(default) if isinstance(default, Path) else json.dumps(default, default=str)
            print(f"{key} = {shown}  # {description}")
        return 0

    schemas = json_schemas()
    if args.type:
        if args.type not in schemas:
            raise ProtocolError(f"message type {args.type!r} is unknown; expected one of {sorted(schemas)}")
        schemas = {args.type: schemas[args.type]}
    print(json.dumps(schemas, indent=2))
    return 0


def run_states(args: argparse.Namespace) -> int:
    from cellctl.supervisor.definition import mermaid
    from cellctl.supervisor.supervisor import load_definitions

    packml, cycle = load_definitions()
    if args.mermaid:
        print(mermaid(packml, cycle), end="")
        return 0
    for name, spec in packml.states.items():
        print(
            f"{spec.code:2d} {name:13} {'acting' if spec.acting else 'wait':6} "
            f"commands: {packml.allowed_commands(name)}"
        )
    print(f"Execute ⊃ cycle (initial {cycle.initial}):")
    for st in cycle.states.values():
        print(f"   {st.name:15} step={st.step:15} " + ", ".join(f"{o}→{d}" for o, d in st.on.items()))
    return 0


def run_validate(args: argparse.Namespace) -> int:
    from cellctl.cli import resolve_config_args

    # the file is positional here; pinned like every other verb's --config (and said on stderr)
    ns = argparse.Namespace(verb=args.verb, config=args.file, overrides=list(args.overrides))
    resolve_config_args(ns)
    cfg = load_run_config(ns.config, ns.overrides)
    print(f"ok: {Path(ns.config).resolve()} (cell {cfg.cell_id!r}) and its state machines are valid")
    return 0


def load_run_config(path: str, overrides: list[str]):  # CellConfig, imported lazily
    """The config, checked exactly as ``cellctl run`` checks it before starting (ConfigError otherwise)."""
    from cellctl.app import preflight
    from cellctl.config import load_config

    cfg = load_config(path, overrides)
    preflight(cfg)
    return cfg
