"""``cellctl references list|show``: the commissioned reference sets beside the plan cache, and one
viewpoint's reference as the scan finds it (:mod:`cellctl.recording.references`).

Exit codes: 0 found, 1 nothing found (``show``: no set holds the plan, or no reference for the viewpoint).
"""

from __future__ import annotations

import argparse
import json

from cellctl.cli import add_config_arguments, config_from_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("references", help="the reference sets commissioning cycles wrote (Start mode=commission)")
    verbs = p.add_subparsers(dest="references_verb", metavar="ACTION", required=True)

    ls = verbs.add_parser("list", help="one JSON line per set: bin type, version, cycle, who declared it clean")
    ls.add_argument("--bin", default=None, metavar="TYPE", help="only this bin type")
    add_config_arguments(ls)
    ls.set_defaults(func=run_list)

    sh = verbs.add_parser("show", help="a viewpoint's reference: image, camera pose, set version (exit 1: none)")
    sh.add_argument("--bin", required=True, metavar="TYPE")
    sh.add_argument("--plan", required=True, metavar="PLAN_ID")
    sh.add_argument("--viewpoint", required=True, type=int, metavar="K")
    add_config_arguments(sh)
    sh.set_defaults(func=run_show)


def run_list(args: argparse.Namespace) -> int:
    from cellctl.errors import RecordingError
    from cellctl.recording.references import MANIFEST, read_manifest, reference_root, set_versions

    root = reference_root(config_from_args(args))
    types = [args.bin] if args.bin else sorted(d.name for d in root.iterdir() if d.is_dir()) if root.is_dir() else []
    found = 0
    for bt in types:
        for version, folder in set_versions(root, bt):
            try:
                man = read_manifest(folder / MANIFEST)
            except RecordingError as err:
                print(json.dumps({"bin_type": bt, "version": version, "error": str(err)}))
                continue
            found += 1
            print(
                json.dumps(
                    {
                        "bin_type": man.bin_type,
                        "version": man.version,
                        "cycle_id": man.cycle_id,
                        "declared_by": man.declared_by,
                        "created": man.created,
                        "plans": {pid: len(p.views) for pid, p in man.plans.items()},
                        "enrolled": {s: str(folder / e.file) for s, e in man.enrolled.items()},
                        "problems": man.problems,
                        "folder": str(folder),
                    }
                )
            )
    return 0 if found else 1


def run_show(args: argparse.Namespace) -> int:
    from cellctl.recording.references import lookup_reference, reference_root

    ref = lookup_reference(reference_root(config_from_args(args)), args.bin, args.plan, args.viewpoint)
    if ref is None:
        print(json.dumps({"bin_type": args.bin, "plan_id": args.plan, "viewpoint": args.viewpoint, "reference": None}))
        return 1
    out = {
        "bin_type": ref.bin_type,
        "plan_id": ref.plan_id,
        "viewpoint": ref.viewpoint,
        "version": ref.version,
        "image": str(ref.image),
        "sha256": ref.sha256,
        "T_base_cam": ref.T_base_cam.tolist(),
        "T_base_bin": ref.T_base_bin.tolist() if ref.T_base_bin is not None else None,
    }
    print(json.dumps(out))
    return 0
