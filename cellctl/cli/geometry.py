"""``cellctl geometry generate``: a bin of the parametric shape family (issue 35).

    cellctl geometry generate --family mixed --seed 3 --out logs/family/mixed_3.stl

writes the mesh, its surface tags (``<out>.surface.npy``, read by ``cellctl plan --mesh``) and its
parameters (``<out>.json``), and prints the parameters as JSON. ``--list`` prints the families and
their options.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    g = sub.add_parser("geometry", help="generated bin geometry (the shape family)")
    gs = g.add_subparsers(dest="geometry_cmd", metavar="SUBCOMMAND", required=True)
    gen = gs.add_parser("generate", help="one bin of a parametric shape family: mesh + tags + parameters")
    gen.add_argument("--family", default="mixed", help="shape family (see --list; default mixed)")
    gen.add_argument("--seed", type=int, default=0, help="which bin of the family (non-negative)")
    gen.add_argument("--out", default=None, help="mesh file (.stl, .ply, .obj …); required unless --list")
    gen.add_argument("--list", action="store_true", help="print the families and their options, write nothing")
    gen.set_defaults(func=generate)


def generate(args: argparse.Namespace) -> int:
    from cellctl.errors import ConfigError
    from cellctl.geometry.family import FAMILIES, write_family_mesh

    if args.list:
        print(json.dumps({k: {o: list(v) for o, v in opts.items()} for k, opts in FAMILIES.items()}, indent=2))
        return 0
    if not args.out:
        raise ConfigError("geometry generate: --out FILE is required (the mesh to write)")
    print(json.dumps(write_family_mesh(args.family, args.seed, Path(args.out)), indent=2))
    return 0
