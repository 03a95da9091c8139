"""2-fold cross-validation of the CenterNet's orientation head on the real TRAINING frames only.

A choice about the orientation head (a loss option, a recipe change) is made here, never on the
validation split (detector_node.real_split). The training frames with complete labels are cut
into two folds by whole keyframe sequences and object-frame ranges:

- fold A trains on object frames 30-59, 80-100, 154, 192, 463 and the keyframes of 0002 / 0006 /
  0011, and is scored on object frames 0-29 and the keyframes of 0004 / 0007 / 0009;
- fold B the other way round.

Both train on the supplementary crops as the shipped recipe does (never scored). Each fold
trains the shipped recipe (docs/detector.md: 896x224 below the top 25 %, orientation head only,
feature bank of 800 samples, 30 epochs) plus the variant's extra ``detector_train`` options, and
is scored as ``bench_detector.py`` scores validation: 4-bin accuracy of the continuous angle's
bin over the Cars matched at 2D IoU >= 0.5, and the median angle error. The pooled accuracy
over both folds decides.

Usage: python bench/orientation_cv.py --name NAME [--extra="--residual-overlap"]
       [--parallel] [--work /tmp/ori_cv]
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

from detector_node.real_split import partial_source

REPO = Path(__file__).resolve().parent.parent
K = REPO.parent / "shared" / "kitti"
sys.path.insert(0, str(REPO / "bench"))

OBJ_A, KEY_A = "30-59,80-100,154,192,463", "0002,0006,0011"
OBJ_B, KEY_B = "0-29", "0004,0007,0009"
RECIPE = (
    "--size centernet --input-width 896 --input-height 224 --roi-top 0.25 --orientation-only "
    "--feature-bank 800 --epochs 30 --epoch-samples 800 --batch-size 16 --warmup-epochs 1 "
    "--warmup-lr 3e-4 --lr 1e-3 --final-epochs 5 --final-lr 1e-4 --seed 0 --num-threads 1 "
    "--no-progress"
)


def folds() -> dict[str, tuple[list[str], list[str]]]:
    """fold -> (training sources with weights, scored sources)."""
    obj, key = K / "object" / "training", K / "tracking_keyframes"
    a = [f"{obj}:{OBJ_A}", f"{key}:{KEY_A}"]
    b = [f"{obj}:{OBJ_B}", f"{key}:{KEY_B}"]
    return {"A": (a, b), "B": (b, a)}


def train_command(train: list[str], extra: str, out: Path) -> list[str]:
    exe = Path(sys.executable).parent / "detector_train"
    return [
        str(exe),
        "--train",
        f"{train[0]}@0.5",
        f"{train[1]}@0.3",
        "--partial",
        f"{partial_source(K)}@0.2",
        *shlex.split(RECIPE),
        *shlex.split(extra),
        "--output",
        str(out),
    ]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--name", required=True, help="variant name (output folder)")
    p.add_argument("--extra", default="", help="detector_train options added to the recipe")
    p.add_argument("--work", type=Path, default=Path("/tmp/ori_cv"))
    p.add_argument("--parallel", action="store_true", help="train both folds at once")
    p.add_argument("--score-only", action="store_true", help="score existing fold checkpoints")
    args = p.parse_args()
    if not (K / "README.md").is_file():
        print(f"orientation_cv: real KITTI frames not found at {K}", file=sys.stderr)
        return 2
    fs = folds()
    outs = {f: args.work / args.name / f for f in fs}
    if not args.score_only:
        t0 = time.time()
        procs = []
        for f, (train, _) in fs.items():
            outs[f].mkdir(parents=True, exist_ok=True)
            log = open(outs[f] / "train.out", "w")  # noqa: SIM115 (closed below)
            cmd = train_command(train, args.extra, outs[f])
            procs.append((subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT), log))
            if not args.parallel:
                procs[-1][0].wait()
        for proc, log in procs:
            proc.wait()
            log.close()
            if proc.returncode:
                print(f"orientation_cv: training failed, see {log.name}", file=sys.stderr)
                return 1
        print(f"trained both folds in {time.time() - t0:.0f} s", flush=True)
    os.environ.setdefault("OMP_NUM_THREADS", "2")
    from bench_detector import evaluate
    from detector_node.inference import CnnDetector

    total_ok = total_n = 0
    summary = {"name": args.name, "extra": args.extra, "folds": {}}
    for f, (_, scored) in fs.items():
        det = CnnDetector.from_checkpoint(str(outs[f] / "final.pt"), "cpu", score_threshold=0.05)
        r = evaluate(det, scored, f"fold {f} ({args.name}), scored part")
        ok = round(r["orientation_accuracy"] * r["orientation_pairs"])
        total_ok += ok
        total_n += r["orientation_pairs"]
        summary["folds"][f] = {
            "accuracy": r["orientation_accuracy"],
            "pairs": r["orientation_pairs"],
            "correct": ok,
            "median_angle_error_deg": r["median_angle_error_deg"],
            "confusion": r["confusion"],
        }
    summary["pooled_accuracy"] = total_ok / max(total_n, 1)
    summary["pooled"] = f"{total_ok} / {total_n}"
    print(
        f"\n{args.name}: pooled 4-bin accuracy {100 * summary['pooled_accuracy']:.1f} % "
        f"({total_ok} of {total_n} pairs); per fold "
        + ", ".join(
            f"{k} {100 * v['accuracy']:.1f} % ({v['correct']} / {v['pairs']}, median "
            f"{v['median_angle_error_deg']:.1f} deg)"
            for k, v in summary["folds"].items()
        )
    )
    (args.work / args.name / "cv.json").write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
