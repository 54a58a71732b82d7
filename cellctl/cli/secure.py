"""``cellctl secure init|rotate|acl``: generate and maintain a secured bus deployment (docs/security.md)."""

from __future__ import annotations

import argparse
import stat
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("secure", help="secured bus: passwords, access-control list, TLS certificates")
    verbs = p.add_subparsers(dest="secure_verb", metavar="ACTION", required=True)

    i = verbs.add_parser("init", help="write a deployment folder: passwords, router ACL, one client file per principal")
    i.add_argument("--out", required=True, type=Path, help="folder to create (mode 0700)")
    i.add_argument("--cell", default="cell1", help="cell id the ACL is written for (default cell1)")
    i.add_argument("--endpoint", default="127.0.0.1:7447", metavar="HOST:PORT", help="the router's address")
    i.add_argument("--tls", action="store_true", help="TLS links: private CA, router and client certificates")
    i.add_argument("--mtls", action="store_true", help="mutual TLS (implies --tls): clients present certificates")
    i.add_argument("--days", type=int, default=825, help="certificate validity (default 825)")
    i.add_argument("--force", action="store_true", help="replace an existing deployment (every secret changes)")
    i.set_defaults(func=run_init)

    r = verbs.add_parser("rotate", help="give one principal a new random password (restart the daemon after)")
    r.add_argument("--dir", required=True, type=Path, help="the deployment folder")
    r.add_argument("principal")
    r.set_defaults(func=run_rotate)

    a = verbs.add_parser("acl", help="print what each principal may do, as a markdown table")
    a.add_argument("--dir", type=Path, default=None, help="read the ACL of this deployment (default: derive it)")
    a.add_argument("--cell", default="cell1", help="cell id to derive the ACL for (without --dir)")
    a.set_defaults(func=run_acl)


def _report(files: list[Path]) -> None:
    for f in files:
        print(f"{stat.filemode(f.stat().st_mode)}  {f}")


def run_init(args: argparse.Namespace) -> int:
    from cellctl.bus.security import BUS_YAML, bus_overrides, init_deployment

    files = init_deployment(
        args.out, args.cell, endpoint=args.endpoint, tls=args.tls, mtls=args.mtls, days=args.days, force=args.force
    )
    _report(files)
    sets = " ".join(f"--set '{o}'" for o in bus_overrides(args.out, args.endpoint, args.tls or args.mtls))
    print(f"\nmerge {args.out / BUS_YAML} into the cell config, or pass:\n  {sets}")
    print("commands need the plc principal:  cellctl cmd reset ... --set bus.principal=plc")
    print("keep passwords, clients/ and tls/*.key secret; copy each host only its own client file (docs/security.md)")
    return 0


def run_rotate(args: argparse.Namespace) -> int:
    from cellctl.bus.security import rotate_password

    _report(rotate_password(args.dir, args.principal))
    print(f"restart the daemon, then install the new {args.dir}/clients/{args.principal}.json5 where it runs")
    return 0


def run_acl(args: argparse.Namespace) -> int:
    import json

    import zenoh

    from cellctl.bus.security import ROUTER_FILE, access_control, principal_table

    if args.dir is not None:
        acl = json.loads(zenoh.Config.from_file(str(args.dir / ROUTER_FILE)).get_json("access_control"))
    else:
        acl = access_control(args.cell)
    print(principal_table(acl))
    return 0
