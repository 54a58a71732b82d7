"""Classifier verbs: ``dataset``, ``train``, ``eval``, ``detector``, ``classify`` (torch imported lazily).

Examples::

    cellctl dataset synth --surface external --n 1200 --out data/synth
    cellctl dataset synth --surface external --n 400 --out data/shifted --shifted --seed 7
    cellctl dataset contam --surface external --n 1200 --out data/contam --seed 0
    cellctl dataset contam --surface external --n 400 --out data/contam_shifted --shifted --seed 7
    cellctl train --surface external --data data/synth --out models/classifier/external.pt
    cellctl eval --surface external --data data/shifted --json
    cellctl classify img1.png img2.png --surface internal --json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from cellctl.cli import add_config_arguments, config_from_args
from cellctl.surface import SURFACES


def register(sub: argparse._SubParsersAction) -> None:
    """Add the classifier verbs ``dataset``, ``train``, ``eval``, ``detector``, ``classify`` (their order in --help)."""
    _add_dataset(sub)
    _add_train(sub)
    _add_eval(sub)
    _add_detector(sub)
    _add_classify(sub)


def _add_dataset(sub: argparse._SubParsersAction) -> None:
    """``dataset``: make classifier datasets (``synth``, ``contam``)."""
    p = sub.add_parser("dataset", help="make classifier datasets")
    dsub = p.add_subparsers(dest="dataset_verb", metavar="ACTION", required=True)
    _add_dataset_synth(dsub)
    _add_dataset_contam(dsub)


def _add_dataset_synth(dsub: argparse._SubParsersAction) -> None:
    """``dataset synth``: a labelled synthetic clean/dirty set."""
    s = dsub.add_parser("synth", help="render a labelled synthetic clean/dirty set")
    s.add_argument("--surface", required=True, choices=SURFACES)
    s.add_argument("--n", type=int, required=True, help="number of images (half clean, half dirty)")
    s.add_argument("--out", required=True, help="dataset root; images go to OUT/<surface>/<clean|dirty>/")
    s.add_argument("--shifted", action="store_true", help="other lighting / powder colour / camera noise")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument(
        "--source",
        choices=("twin", "procedural"),
        default="twin",
        help="twin: the pybullet twin's camera (default); procedural: numpy textures",
    )
    s.add_argument(
        "--size",
        type=int,
        default=256,
        help="image width in px (twin: 16:9 renders; procedural: square); default 256",
    )
    add_config_arguments(s)
    s.set_defaults(func=run_synth)


def _add_dataset_contam(dsub: argparse._SubParsersAction) -> None:
    """``dataset contam``: a clean/dirty set over contamination families."""
    m = dsub.add_parser("contam", help="clean/dirty set over contamination families (twin renders + close-ups)")
    m.add_argument("--surface", required=True, choices=SURFACES)
    m.add_argument("--n", type=int, required=True, help="number of images (half clean, half dirty)")
    m.add_argument("--out", required=True, help="dataset root; images go to OUT/<surface>/<clean|dirty>/")
    m.add_argument("--shifted", action="store_true", help="the held-out generator (families/optics never trained on)")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--source", choices=("mixed", "closeup"), default="mixed", help="closeup: no twin renders")
    m.add_argument("--twin-fraction", type=float, default=0.4, help="share of draws on a twin render")
    m.add_argument("--size", type=int, default=256)
    m.add_argument(
        "--site",
        choices=("unseen",),
        default=None,
        help="another site's steel, light and camera (cellctl.classify.site; testing enrollment only, never training)",
    )
    add_config_arguments(m)
    m.set_defaults(func=run_contam)


def _add_train(sub: argparse._SubParsersAction) -> None:
    """``train``: a surface's whole-image clean/dirty classifier."""
    t = sub.add_parser("train", help="train a surface's clean/dirty classifier")
    t.add_argument("--surface", required=True, choices=SURFACES)
    t.add_argument("--data", required=True, help="dataset root (DATA/<surface>/<clean|dirty>/*.png)")
    t.add_argument("--out", required=True, help="weights file, e.g. models/classifier/external.pt")
    t.add_argument("--preset", choices=("default", "paper"), default="default")
    t.add_argument("--arch", choices=("lite0", "resnet18"), default=None, help="backbone (default: lite0)")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--input-size", type=int, default=None, help="model input side in px (default 128)")
    t.add_argument("--target-false-clean", type=float, default=0.01, help="threshold target on val (default 0.01)")
    t.add_argument("--max-epochs", type=int, nargs=2, default=None, metavar=("HEAD", "FINETUNE"))
    t.add_argument("--threads", type=int, default=None)
    t.add_argument("--init-from", default=None, help="continue from this trained weights file (same surface)")
    add_config_arguments(t)
    t.set_defaults(func=run_train)


def _add_eval(sub: argparse._SubParsersAction) -> None:
    """``eval``: a surface model on a dataset."""
    e = sub.add_parser("eval", help="evaluate a surface model on a dataset")
    e.add_argument("--surface", required=True, choices=SURFACES)
    e.add_argument("--data", required=True)
    e.add_argument("--model", default=None, help="weights (default: <classifier.models_dir>/<surface>.pt)")
    e.add_argument(
        "--split",
        choices=("auto", "test", "all"),
        default="auto",
        help="test: held-out part of the training split; all: every image; auto: test if DATA is the training folder",
    )
    e.add_argument("--variant", choices=("fp32", "fused"), default="fp32")
    e.add_argument("--target-false-clean", type=float, default=0.01)
    e.add_argument("--png", default=None, help="write a ROC + score histogram PNG here")
    e.add_argument(
        "--recalibrate",
        action="store_true",
        help="first refit temperature + threshold (for --target-false-clean) on the model's validation "
        "split and rewrite the weights and card (DATA must be the training folder)",
    )
    e.add_argument("--json", action="store_true", help="print JSON only")
    e.add_argument("--out", default=None, help="also write the JSON report here")
    add_config_arguments(e)
    e.set_defaults(func=run_eval)


def _add_detector(sub: argparse._SubParsersAction) -> None:
    """``detector``: the combined detector's actions, in this order in ``--help``."""
    d = sub.add_parser("detector", help="the combined detector (supervised patch head + clean-only memory bank)")
    dv = d.add_subparsers(dest="detector_verb", metavar="ACTION", required=True)
    _add_detector_train(dv)
    _add_detector_eval(dv)
    _add_detector_export(dv)
    _add_detector_label_check(dv)
    _add_detector_enroll(dv)
    _add_detector_update(dv)
    _add_detector_proof(dv)
    _add_detector_bank_compare(dv)


def _add_detector_train(dv: argparse._SubParsersAction) -> None:
    """``detector train``: fit a surface's detector."""
    dt = dv.add_parser("train", help="fit a surface's detector on a `dataset contam` folder")
    dt.add_argument("--surface", required=True, choices=SURFACES)
    dt.add_argument("--data", required=True)
    dt.add_argument("--out", default=None, help="default: <classifier.models_dir>/<surface>.detect.pt")
    dt.add_argument("--seed", type=int, default=0)
    dt.add_argument("--epochs", type=int, default=12)
    dt.add_argument("--bank-size", type=int, default=1024)
    dt.add_argument("--target-false-clean", type=float, default=0.01)
    dt.add_argument(
        "--init-from",
        default=None,
        metavar="DETECT_PT",
        help="continue fine-tuning from this format-2 detector of the same surface (bank, fusion, threshold refitted)",
    )
    dt.add_argument(
        "--calib",
        default=None,
        metavar="DIR",
        help="a second `dataset contam` draw (training generator, other seed) that joins val for fusion and threshold",
    )
    add_config_arguments(dt)
    dt.set_defaults(func=run_detector_train)


def _add_detector_eval(dv: argparse._SubParsersAction) -> None:
    """``detector eval``: score a surface's detector on a folder."""
    de = dv.add_parser("eval", help="evaluate a surface's detector on every image of a folder")
    de.add_argument("--surface", required=True, choices=SURFACES)
    de.add_argument("--data", required=True)
    de.add_argument("--model", default=None)
    de.add_argument("--out", default=None, help="also write the JSON report here")
    de.add_argument(
        "--record", metavar="NAME", default=None, help="also store the report in the model card under metrics.NAME"
    )
    add_config_arguments(de)
    de.set_defaults(func=run_detector_eval)


def _add_detector_export(dv: argparse._SubParsersAction) -> None:
    """``detector export``: the detector's networks to ONNX."""
    dx = dv.add_parser(
        "export",
        help="export a surface's detector networks to ONNX beside it (<surface>.detect.onnx), parity-checked "
        "against PyTorch and recorded in its card (cellctl.classify.runtime; `detector train` does it too)",
    )
    dx.add_argument("--surface", required=True, choices=SURFACES)
    dx.add_argument("--model", default=None, help="default: <classifier.models_dir>/<surface>.detect.pt")
    add_config_arguments(dx)
    dx.set_defaults(func=run_detector_export)


def _add_detector_label_check(dv: argparse._SubParsersAction) -> None:
    """``detector label-check``: score visible-mask surroundings factors."""
    dl = dv.add_parser(
        "label-check",
        help="score visible-mask surroundings factors on a held-out draw of the training generator (a pre-change "
        "detector as the single-image observer; docs/classifier/detector.md)",
    )
    dl.add_argument("--surface", required=True, choices=SURFACES)
    dl.add_argument("--n-dirty", type=int, default=300)
    dl.add_argument("--n-clean", type=int, default=150)
    dl.add_argument("--seed", type=int, default=11, help="a seed no data set uses (default 11)")
    dl.add_argument("--model", type=Path, default=None, help="the observer (default models/classifier/S.detect.pt)")
    dl.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    dl.set_defaults(func=run_label_check)


def _add_detector_enroll(dv: argparse._SubParsersAction) -> None:
    """``detector enroll``: adapt a detector to a site's clean images."""
    dn = dv.add_parser(
        "enroll",
        help="adapt a surface's detector to a site's clean images (merged clean bank, threshold from held-out "
        "clean scores); writes one file (docs/classifier/detector.md, 'Site enrollment')",
    )
    dn.add_argument("--surface", required=True, choices=SURFACES)
    dn.add_argument("--images", required=True, type=Path, help="folder of clean PNG/JPEG views (recursive, any size)")
    dn.add_argument("--out", required=True, type=Path, help="the enrolled detector file to write")
    dn.add_argument("--detector", type=Path, default=None, help="base (default <classifier.models_dir>/S.detect.pt)")
    dn.add_argument("--seed", type=int, default=0, help="fit / held-out split")
    add_config_arguments(dn)
    dn.set_defaults(func=run_detector_enroll)


def _add_detector_update(dv: argparse._SubParsersAction) -> None:
    """``detector update``: re-enroll from the operators' confirmed-clean views."""
    du = dv.add_parser(
        "update",
        help="re-enroll a surface's detector from the views operators confirmed clean on the HMI (review bank), and "
        "report how the decision moved: threshold, false-dirty on the confirmed views and on a generated held-out set "
        "(cellctl.review.update)",
    )
    du.add_argument("--surface", required=True, choices=SURFACES)
    du.add_argument("--out", type=Path, default=None, help="the enrolled file (default <review dir>/S.enrolled.pt)")
    du.add_argument("--detector", type=Path, default=None, help="base (default <classifier.models_dir>/S.detect.pt)")
    du.add_argument("--seed", type=int, default=0, help="fit / held-out split and the generated held-out set")
    du.add_argument("--held-out", type=int, default=12, help="generated held-out images per class (default 12)")
    du.add_argument("--proof-quick", action="store_true", help="also `detector proof --quick` (shifted) on both")
    add_config_arguments(du)
    du.set_defaults(func=run_detector_update)


def _add_detector_proof(dv: argparse._SubParsersAction) -> None:
    """``detector proof``: shifted, leave-one-family-out and unseen-site scores."""
    dp = dv.add_parser(
        "proof",
        help="generate and score the shifted generator, leave-one-family-out refits and the unseen site (enrolled "
        "and not) with Clopper-Pearson intervals; JSON by section (cellctl.classify.proof)",
    )
    dp.add_argument("--surface", required=True, choices=SURFACES)
    dp.add_argument("--out", required=True, type=Path, help="the JSON report (sections of an earlier run kept)")
    dp.add_argument("--detector", type=Path, default=None, help="default <classifier.models_dir>/S.detect.pt")
    dp.add_argument("--n", type=int, default=None, help="images per class (shifted, site; default 600 / 300)")
    dp.add_argument("--seed", type=int, default=0, help="base seed; each set adds its own offset (in the JSON)")
    dp.add_argument("--quick", action="store_true", help="a few close-up images per set (tests)")
    dp.add_argument("--only", action="append", choices=("shifted", "lofo", "site"), help="run only these sections")
    dp.add_argument("--work", type=Path, default=None, help="keep the generated images here (default: a temp dir)")
    add_config_arguments(dp)
    dp.set_defaults(func=run_detector_proof)


def _add_detector_bank_compare(dv: argparse._SubParsersAction) -> None:
    """``detector bank-compare``: the clean-only bank on frozen ImageNet features."""
    db = dv.add_parser(
        "bank-compare",
        help="the clean-only bank alone on frozen ImageNet Lite0/1/2 features (128-192 px) vs the fine-tuned "
        "backbone, on the shifted generator and the unseen site (cellctl.classify.bank_compare)",
    )
    db.add_argument("--surface", required=True, choices=SURFACES)
    db.add_argument("--out", required=True, type=Path, help="the JSON report")
    db.add_argument("--detector", type=Path, default=None, help="default <classifier.models_dir>/S.detect.pt")
    db.add_argument("--n", type=int, default=200, help="clean and dirty images per test set (default 200)")
    db.add_argument("--seed", type=int, default=0)
    db.add_argument("--source", choices=("mixed", "closeup"), default="mixed", help="closeup: no twin renders")
    add_config_arguments(db)
    db.set_defaults(func=run_detector_bank_compare)


def _add_classify(sub: argparse._SubParsersAction) -> None:
    """``classify``: classify image files."""
    c = sub.add_parser("classify", help="classify image files")
    c.add_argument("images", nargs="+")
    c.add_argument("--surface", required=True, choices=SURFACES)
    c.add_argument("--model", default=None)
    c.add_argument("--variant", choices=("fp32", "fused"), default="fp32")
    c.add_argument("--json", action="store_true", help="one JSON object per line")
    c.add_argument(
        "--detector", default=None, metavar="FILE", help="this detector file (shipped or `detector enroll`ed) decides"
    )
    c.add_argument(
        "--decision",
        choices=("auto", "detector", "supervised"),
        default=None,
        help="detector: combined supervised + clean-only decision (classifier.detector_files or "
        "<surface>.detect.pt); supervised: the whole-image network only; auto: the detector when its file exists; "
        "default: classifier.decision (detector), or supervised when --model is given",
    )
    add_config_arguments(c)
    c.set_defaults(func=run_classify)


def _model_path(args: argparse.Namespace) -> Path:
    if args.model:
        return Path(args.model)
    cfg = config_from_args(args)
    return cfg.path(cfg.classifier.models_dir) / f"{args.surface}.pt"


def run_synth(args: argparse.Namespace) -> int:
    from cellctl.classify.synth import synth_dataset

    cfg = config_from_args(args)
    summary = synth_dataset(
        args.out,
        args.surface,
        args.n,
        seed=args.seed,
        shifted=args.shifted,
        source=args.source,
        size=args.size,
        config=cfg,
    )
    print(json.dumps(summary))
    return 0


def run_contam(args: argparse.Namespace) -> int:
    from cellctl.classify.contam_dataset import contam_dataset

    if args.site is not None:
        from cellctl.classify.site import site_dataset

        if args.shifted:
            print("error: --site and --shifted are separate generators; give one", file=sys.stderr)
            return 2
        n_dirty = args.n // 2
        summary = site_dataset(args.out, args.surface, args.n - n_dirty, n_dirty, seed=args.seed, size=args.size)
        print(json.dumps(summary))
        return 0
    summary = contam_dataset(
        args.out,
        args.surface,
        args.n,
        seed=args.seed,
        shifted=args.shifted,
        source=args.source,
        twin_fraction=args.twin_fraction,
        size=args.size,
        config=config_from_args(args),
    )
    print(json.dumps(summary))
    return 0


def run_train(args: argparse.Namespace) -> int:
    from cellctl.classify.train import train

    cfg = config_from_args(args)
    card = train(
        args.data,
        args.surface,
        args.out,
        preset=args.preset,
        arch=args.arch,
        seed=args.seed,
        input_size=args.input_size,
        target_false_clean=args.target_false_clean,
        imagenet_weights=cfg.path(cfg.classifier.imagenet_weights) if cfg.classifier.imagenet_weights else None,
        max_epochs=tuple(args.max_epochs) if args.max_epochs else (None, None),
        threads=args.threads,
        init_from=args.init_from,
    )
    t = card["metrics"]["test"]
    print(
        json.dumps({"model_id": card["model_id"], "out": args.out, "test": t, "train_seconds": card["train_seconds"]})
    )
    return 0


def run_eval(args: argparse.Namespace) -> int:
    from cellctl.classify.evaluate import evaluate_folder

    if args.recalibrate:
        from cellctl.classify.calibration import calibrate

        card = calibrate(_model_path(args), args.data, target_false_clean=args.target_false_clean)
        print(
            f"recalibrated {card['model_id']}: temperature {card['temperature']:.3f}, "
            f"threshold {card['threshold']:.4f}",
            file=sys.stderr,
        )

    report = evaluate_folder(
        _model_path(args),
        args.data,
        args.surface,
        split=args.split,
        target_false_clean=args.target_false_clean,
        variant=args.variant,
        png=args.png,
    )
    text = json.dumps(report, indent=None if args.json else 2)
    print(text)
    if args.out:
        Path(args.out).write_text(json.dumps(report, indent=2) + "\n")
    if not args.json:
        c = report["confusion"]
        print(
            f"accuracy {report['accuracy']:.4f}  false-clean {report['false_clean_rate']}  "
            f"AUC {report['roc_auc']}  uncertain {report['uncertain_fraction']:.3f}  "
            f"[clean→clean {c['clean_as_clean']}, clean→dirty {c['clean_as_dirty']}, "
            f"dirty→clean {c['dirty_as_clean']}, dirty→dirty {c['dirty_as_dirty']}]",
            file=sys.stderr,
        )
    return 0


def _detector_path(args: argparse.Namespace) -> Path:
    from cellctl.classify.fusion import detector_path

    given = args.out if args.func is run_detector_train else args.model
    if given:
        return Path(given)
    cfg = config_from_args(args)
    return detector_path(cfg.path(cfg.classifier.models_dir), args.surface)


def run_detector_train(args: argparse.Namespace) -> int:
    from cellctl.classify.fusion import train_detector

    card = train_detector(
        args.data,
        args.surface,
        _detector_path(args),
        seed=args.seed,
        epochs=args.epochs,
        bank_size=args.bank_size,
        target_false_clean=args.target_false_clean,
        init_from=args.init_from,
        calib=args.calib,
    )
    from cellctl.classify.onnx_export import export_detector

    # the export belongs to the weights just written: made now, so no stale one is left beside them
    onnx = export_detector(_detector_path(args), command=card["command"])
    print(
        json.dumps(
            {
                "model_id": card["model_id"],
                "test": card["metrics"]["test"],
                "seconds": card["train_seconds"],
                "onnx": onnx["file"],
            }
        )
    )
    return 0


def run_detector_export(args: argparse.Namespace) -> int:
    from cellctl.classify.onnx_export import export_detector

    cmd = f"cellctl detector export --surface {args.surface}" + (f" --model {args.model}" if args.model else "")
    print(json.dumps(export_detector(_detector_path(args), command=cmd)))
    return 0


def run_detector_eval(args: argparse.Namespace) -> int:
    from cellctl.classify.fusion import Detector, evaluate_detector

    path = _detector_path(args)
    report = evaluate_detector(Detector.load(path, surface=args.surface), args.data, args.surface)
    report["data"] = Path(args.data).as_posix()
    print(json.dumps(report))
    if args.out:
        Path(args.out).write_text(json.dumps(report, indent=2) + "\n")
    if args.record:
        # the card describes the weights (its sha256 is theirs): adding figures leaves them valid
        card_path = path.with_suffix(".json")
        card = json.loads(card_path.read_text())
        card.setdefault("metrics", {})[args.record] = report
        card_path.write_text(json.dumps(card, indent=2) + "\n")
    return 0


def run_detector_proof(args: argparse.Namespace) -> int:
    from cellctl.classify.fusion import detector_path
    from cellctl.classify.proof import SECTIONS, ProofSizes, merge_into, proof

    cfg = config_from_args(args)
    det = args.detector or detector_path(cfg.path(cfg.classifier.models_dir), args.surface)
    sizes = ProofSizes.quick() if args.quick else ProofSizes()
    if args.n is not None:
        sizes = sizes.scaled(args.n)
    sections = tuple(args.only) if args.only else SECTIONS
    report = proof(args.surface, det, sizes=sizes, seed=args.seed, sections=sections, work=args.work)
    report["command"] = " ".join(["cellctl", *sys.argv[1:]])
    report = merge_into(args.out, report)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report["targets"]))
    return 0


def run_detector_bank_compare(args: argparse.Namespace) -> int:
    from cellctl.classify.bank_compare import bank_compare
    from cellctl.classify.fusion import detector_path

    cfg = config_from_args(args)
    det = args.detector or detector_path(cfg.path(cfg.classifier.models_dir), args.surface)
    report = bank_compare(args.surface, det, n=args.n, seed=args.seed, source=args.source)
    report["command"] = " ".join(["cellctl", *sys.argv[1:]])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1) + "\n")
    for row in report["rows"]:
        print(json.dumps(row))
    return 0


def run_label_check(args: argparse.Namespace) -> int:
    from cellctl.classify.label_check import label_check

    model = args.model or Path("models/classifier") / f"{args.surface}.detect.pt"
    text = json.dumps(label_check(args.surface, args.n_dirty, args.n_clean, args.seed, model), indent=1)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")
    print(text)
    return 0


def run_detector_enroll(args: argparse.Namespace) -> int:
    from cellctl.classify.enroll import enroll_detector, folder_images, save_enrolled
    from cellctl.classify.fusion import Detector, detector_path

    cfg = config_from_args(args)
    images = folder_images(args.images)  # a bad folder is refused before the detector loads
    base = args.detector or detector_path(cfg.path(cfg.classifier.models_dir), args.surface)
    det = enroll_detector(
        Detector.load(base, surface=args.surface), images, args.surface, seed=args.seed, source=args.images
    )
    save_enrolled(det, args.out)
    print(json.dumps({"out": str(args.out), "model_id": det.model_id, **(det.enrollment or {})}))
    return 0


def run_detector_update(args: argparse.Namespace) -> int:
    from cellctl.errors import ClassifierError
    from cellctl.review.bank import bank_dir
    from cellctl.review.update import update_detector

    cfg = config_from_args(args)
    if not 1 <= args.held_out <= 1000:
        raise ClassifierError(f"--held-out {args.held_out} is out of range; expected 1..1000")
    out = args.out or bank_dir(cfg) / f"{args.surface}.enrolled.pt"
    report = update_detector(cfg, args.surface, out, base=args.detector, seed=args.seed, held_out=args.held_out,
                             proof_quick=args.proof_quick)  # fmt: skip
    print(json.dumps(report))
    return 0


def run_classify(args: argparse.Namespace) -> int:
    from cellctl.classify.data import load_image
    from cellctl.classify.fusion import Detector, detector_path
    from cellctl.classify.infer import SurfaceModel
    from cellctl.classify.runtime import onnx_path
    from cellctl.errors import CellError

    cfg = config_from_args(args)
    det_file = detector_path(cfg.path(cfg.classifier.models_dir), args.surface)
    # classifier.runtime picks ONNX Runtime or PyTorch; an enrolled file shares the shipped export
    run = {"runtime": cfg.classifier.runtime, "threads": cfg.classifier.threads, "also_onnx": (onnx_path(det_file),)}
    decision = args.decision or ("supervised" if args.model else cfg.classifier.decision)
    enrolled = getattr(cfg.classifier.detector_files, args.surface)
    if enrolled is not None:  # the cell's site-enrolled file decides, as in the worker
        det_file = cfg.path(enrolled)
    if args.detector:
        model = Detector.load(args.detector, surface=args.surface, **run)
    elif decision == "detector" or (decision == "auto" and det_file.is_file()):
        model = Detector.load(det_file, surface=args.surface, **run)
    else:
        model = SurfaceModel.load(_model_path(args), surface=args.surface, variant=args.variant)
    rc = 0
    for path in args.images:
        try:
            pred = model.predict([load_image(path, cfg.camera.max_image_pixels)])[0]
            out = {"image": path, **pred.as_dict()}
        except CellError as err:
            out = {"image": path, "error": str(err)}
            rc = 2
        if args.json:
            print(json.dumps(out))
        elif "error" in out:
            print(f"{path}: error: {out['error']}")
        else:
            flag = " (uncertain)" if out["uncertain"] else ""
            print(f"{path}: {out['label']}{flag} p_dirty={out['p_dirty']:.4f} [{out['model_id']}]")
    return rc
