"""Cross-validation of a CenterNet training recipe over whole sequences of the real TRAINING
frames, and the same recipe trained on all of them (``--final``).

Every choice about the detector's training (a loss option, an augmentation, which parts
train, how long) is made here, never on the reporting split (``detector_node.real_split``).
The folds are ``real_split.CV_FOLDS`` (issue 34): three folds of whole tracking sequences
(keyframes and the object frames that are frames of them) plus object frames of no known
sequence cut by id range. A fold is scored on its frames and trained on the other folds'
frames and on the ``object_crops352`` crops that may not be frames of its sequences.

A recipe is one or two ``detector_train`` runs with the data options added here (object
frames @0.5, keyframes @0.3, crops @0.2, as the former recipe):

- stage 1: ``--stage1`` (default :data:`STAGE1`: the former recipe, orientation head only on a
  feature bank) plus ``--extra``;
- stage 2 (``--stage2 OPTIONS``, optional): ``--init`` stage 1's ``final.pt`` plus OPTIONS
  (``--stage1-from NAME``: stage 1 as another variant trained it, not trained again).

Each fold's checkpoint is scored as ``bench_detector.py`` scores the reporting split: KITTI
2D AP|R40 (Car, moderate, IoU 0.7 and 0.5), 4-bin accuracy of the continuous angle's bin over
the Cars matched at IoU >= 0.5 (pooled over the folds' pairs), median angle error. Printed
per fold and pooled, written to ``WORK/NAME/cv.json``; the exact commands go to
``WORK/NAME/commands.sh``.

Usage: python bench/detector_cv.py --name NAME [--stage1 "..."] [--extra "..."]
       [--stage2 "..." [--stage1-from NAME]] [--folds 1,2,3] [--parallel N]
       [--work /tmp/det_cv] [--bank DIR] [--score-only]
       [--final]   # train the recipe on all training frames (WORK/NAME/final/), no scoring
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

from detector_node import real_split

REPO = Path(__file__).resolve().parent.parent
K = REPO.parent / "shared" / "kitti"

#: the former recipe (issue 22 / 2026-11-27): orientation head only, on a feature bank
STAGE1 = (
    "--size centernet --input-width 896 --input-height 224 --roi-top 0.25 --orientation-only "
    "--residual-overlap --feature-bank 800 --epochs 30 --epoch-samples 800 --batch-size 16 "
    "--warmup-epochs 1 --warmup-lr 3e-4 --lr 1e-3 --final-epochs 5 --final-lr 1e-4 --seed 0 "
    "--num-threads 1 --no-progress"
)
WEIGHTS = {"object": 0.5, "keyframes": 0.3, "partial": 0.2}


def data_options(fold: int | None) -> list[str]:
    """``--train`` / ``--partial`` options of a fold's training frames (None: all of them)."""
    if fold is None:
        kf, obj = real_split.train_sources(K)
        d = {"keyframes": [kf], "object": [obj], "partial": [real_split.partial_source(K)]}
    else:
        d = real_split.cv_fold_sources(K, fold)
    return [
        "--train",
        *(f"{s}@{WEIGHTS['object']}" for s in d["object"]),
        *(f"{s}@{WEIGHTS['keyframes']}" for s in d["keyframes"]),
        "--partial",
        *(f"{s}@{WEIGHTS['partial']}" for s in d["partial"]),
    ]


def stage_commands(fold: int | None, args, out: Path) -> list[list[str]]:
    """The ``detector_train`` command lines of the recipe for one fold (or all frames)."""
    exe = str(Path(sys.executable).parent / "detector_train")
    data = data_options(fold)
    s1 = [exe, *data, *shlex.split(args.stage1), *shlex.split(args.extra)]
    if args.bank and "--feature-bank" in s1:
        s1 += ["--bank-cache", str(args.bank / f"{out.name}.pt")]
    cmds = [[*s1, "--output", str(out / "stage1")]]
    first = out / "stage1" / "final.pt"
    if args.stage1_from:  # stage 1 as trained by another variant (same fold)
        cmds, first = [], args.work / args.stage1_from / out.name / "stage1" / "final.pt"
    if args.stage2:
        s2 = [exe, *data, *shlex.split(args.stage2), "--init", str(first)]
        if args.bank and "--feature-bank" in s2:
            s2 += ["--bank-cache", str(args.bank / f"{out.name}.pt")]
        cmds.append([*s2, "--output", str(out / "stage2")])
    return cmds


def run_fold(cmds: list[list[str]], log_path: Path) -> subprocess.Popen:
    """Run a fold's stages one after the other in a child shell (stdout to ``log_path``)."""
    script = " && ".join(shlex.join(c) for c in cmds)
    log = open(log_path, "w")  # noqa: SIM115 (the child owns it)
    return subprocess.Popen(["bash", "-c", script], stdout=log, stderr=subprocess.STDOUT)


def score(checkpoint: Path, specs: list[str], label: str) -> dict:
    from detector_node.loading import load_detector
    from tracking_bringup.detector_scoring import evaluate

    det = load_detector(str(checkpoint), "cpu", score_threshold=0.05)
    r = evaluate(det, specs, label)
    return {
        "ap70_moderate": r["kitti_ap_r40"]["moderate"]["0.7"],
        "ap50_moderate": r["kitti_ap_r40"]["moderate"]["0.5"],
        "orientation_accuracy": r["orientation_accuracy"],
        "pairs": r["orientation_pairs"],
        "correct": round(r["orientation_accuracy"] * r["orientation_pairs"]),
        "median_angle_error_deg": r["median_angle_error_deg"],
        "confusion": r["confusion"],
    }


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--name", required=True, help="recipe name (output folder)")
    p.add_argument("--stage1", default=STAGE1, help="detector_train options of stage 1")
    p.add_argument("--extra", default="", help="options added to stage 1")
    p.add_argument("--stage2", default="", help="options of stage 2 (--init stage 1 added)")
    p.add_argument(
        "--stage1-from",
        default="",
        help="skip stage 1: stage 2 starts from this variant's stage 1 (same folds, WORK/NAME)",
    )
    p.add_argument("--folds", default="1,2,3", help="folds to run (1-based)")
    p.add_argument("--work", type=Path, default=Path("/tmp/det_cv"))
    p.add_argument(
        "--bank",
        type=Path,
        help="folder of cached feature banks (one per fold; variants that train other heads on "
        "the same bank share it; a bank of other data or augmentation is rebuilt)",
    )
    p.add_argument("--parallel", type=int, default=1, help="folds trained at once")
    p.add_argument("--score-only", action="store_true", help="score existing fold checkpoints")
    p.add_argument("--final", action="store_true", help="train on all training frames instead")
    return p


def _train_folds(args, base: Path, folds, outs: dict, cmds: dict) -> int:
    """Write the commands to ``commands.sh`` and run the folds, ``--parallel`` at once: 0, or
    1 (one line) when a fold failed."""
    with open(base / "commands.sh", "w") as fh:
        for f in folds:
            fh.write(f"# {outs[f].name}\n" + "".join(shlex.join(c) + "\n" for c in cmds[f]))
    t0, cpu0 = time.time(), os.times()
    pending, running = list(folds), []
    while pending or running:
        while pending and len(running) < args.parallel:
            f = pending.pop(0)
            outs[f].mkdir(parents=True, exist_ok=True)
            running.append((f, run_fold(cmds[f], outs[f] / "train.out")))
        time.sleep(2)
        for item in list(running):
            if item[1].poll() is not None:
                running.remove(item)
                if item[1].returncode:
                    print(f"detector_cv: {outs[item[0]]}/train.out: failed", file=sys.stderr)
                    return 1
    cpu = os.times()
    used = cpu.children_user + cpu.children_system - cpu0.children_user - cpu0.children_system
    print(f"trained {len(folds)} run(s) in {time.time() - t0:.0f} s wall, {used:.0f} s CPU")
    return 0


def _score_folds(args, base: Path, folds, outs: dict) -> dict:
    """Score each fold's last stage on its scored part; the pooled figures, printed."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    summary: dict = {"name": args.name, "commands": str(base / "commands.sh"), "folds": {}}
    last = "stage2" if args.stage2 else "stage1"
    for f in folds:
        specs = real_split.cv_fold_sources(K, f)["scored"]
        label = f"fold {f + 1} ({args.name}), scored part"
        summary["folds"][f + 1] = score(outs[f] / last / "final.pt", specs, label)
    v = summary["folds"].values()
    ok, n = sum(x["correct"] for x in v), sum(x["pairs"] for x in v)
    summary["pooled_orientation"] = ok / max(n, 1)
    summary["pooled"] = f"{ok} / {n}"
    summary["mean_ap70_moderate"] = sum(x["ap70_moderate"] for x in v) / len(v)
    summary["mean_ap50_moderate"] = sum(x["ap50_moderate"] for x in v) / len(v)
    print(
        f"\n{args.name}: pooled 4-bin orientation {100 * summary['pooled_orientation']:.1f} % "
        f"({ok} of {n} pairs); mean AP|R40 moderate @0.7 "
        f"{100 * summary['mean_ap70_moderate']:.1f}, @0.5 {100 * summary['mean_ap50_moderate']:.1f}"
    )
    for k, x in summary["folds"].items():
        print(
            f"  fold {k}: orientation {100 * x['orientation_accuracy']:.1f} % ({x['correct']} / "
            f"{x['pairs']}), median {x['median_angle_error_deg']:.1f} deg, AP@0.7 mod "
            f"{100 * x['ap70_moderate']:.1f}, AP@0.5 mod {100 * x['ap50_moderate']:.1f}, "
            f"confusion {x['confusion']}"
        )
    return summary


def main() -> int:
    args = _parser().parse_args()
    if not (K / "README.md").is_file():
        print(f"detector_cv: real KITTI frames not found at {K}", file=sys.stderr)
        return 2
    base = args.work / args.name
    folds = [None] if args.final else [int(f) - 1 for f in args.folds.split(",")]
    outs = {f: base / ("final" if f is None else f"fold{f + 1}") for f in folds}
    cmds = {f: stage_commands(f, args, outs[f]) for f in folds}
    base.mkdir(parents=True, exist_ok=True)
    if not args.score_only and _train_folds(args, base, folds, outs, cmds):
        return 1
    if args.final:
        return 0
    summary = _score_folds(args, base, folds, outs)
    (base / "cv.json").write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
