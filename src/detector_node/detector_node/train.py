"""``detector_train``: train the detector on KITTI object/tracking layouts.

Adam (0.9, 0.999), batch 8, the paper's schedule by default (warm-up epochs at 1e-4, bulk at
1e-3, final epochs at 1e-6), colour jitter and horizontal flip (no random crop), validation AP
each epoch, checkpoint every epoch (``last.pt`` with optimizer state for ``--resume``; ``best.pt``
weights + config only), fixed seeds, CPU or CUDA chosen automatically.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import time
from pathlib import Path

import numpy as np
import torch

from .anchors import kmeans_anchors
from .checkpoint import load_checkpoint, save_checkpoint
from .dataset import Sample, add_data_arguments, augment, load_sample, sources_from_args
from .inference import choose_device, decode_output, to_tensor
from .loss import LossWeights, detection_loss
from .model import YoloV2Passthrough, preset
from .validation import ApResult, FrameResult, evaluate_frames


def learning_rate(epoch: int, epochs: int, args: argparse.Namespace) -> float:
    """Piecewise-constant schedule: warm-up, bulk, final."""
    if epoch < args.warmup_epochs:
        return args.warmup_lr
    if epoch >= epochs - args.final_epochs:
        return args.final_lr
    return args.lr


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


@torch.no_grad()
def validate(
    model: YoloV2Passthrough,
    samples: list[Sample],
    device,
    batch: int = 8,
    iou_thresholds=(0.5, 0.7),
) -> list[ApResult]:
    """AP (input-pixel boxes) of the model on samples, at each IoU threshold."""
    model.eval()
    frames = []
    for i in range(0, len(samples), batch):
        chunk = samples[i : i + batch]
        raw = model(to_tensor([s.image for s in chunk], device))
        dets = decode_output(raw, model.config, score_threshold=0.01, nms_iou=0.45)
        for s, d in zip(chunk, dets, strict=True):
            frames.append(
                FrameResult(
                    det_boxes=np.array([x.box for x in d]).reshape(-1, 4),
                    det_scores=np.array([x.score for x in d]),
                    det_bins=np.array([x.orientation_bin for x in d], dtype=np.int64),
                    gt_boxes=s.boxes,
                    gt_bins=s.bins,
                    dontcare=s.dontcare,
                )
            )
    return [evaluate_frames(frames, t) for t in iou_thresholds]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="detector_train",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_data_arguments(p)
    p.add_argument("--output", type=Path, required=True, help="folder for last.pt / best.pt / log")
    p.add_argument("--size", choices=["tiny", "full"], default="tiny")
    p.add_argument("--width", type=float, help="channel multiplier (default: preset's)")
    p.add_argument("--depth", type=int, help="layers kept per stage (default: preset's)")
    p.add_argument("--input-width", type=int, help="network input width (default: preset's)")
    p.add_argument("--input-height", type=int, help="network input height (default: preset's)")
    p.add_argument(
        "--anchors",
        type=Path,
        help="anchors JSON from detector_anchors (default: k-means on --train)",
    )
    p.add_argument("--epochs", type=int, default=30)
    p.add_argument("--batch-size", type=int, default=8)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--warmup-lr", type=float, default=1e-4)
    p.add_argument("--warmup-epochs", type=int, default=2)
    p.add_argument("--final-lr", type=float, default=1e-6)
    p.add_argument("--final-epochs", type=int, default=2)
    p.add_argument("--no-flip", action="store_true", help="disable horizontal flips")
    p.add_argument("--no-jitter", action="store_true", help="disable colour jitter")
    p.add_argument(
        "--balance-orientation",
        action="store_true",
        help="weight the orientation loss by 1/sqrt(bin frequency) of the training boxes",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    p.add_argument("--num-threads", type=int, default=2, help="torch CPU threads")
    p.add_argument("--resume", type=Path, help="last.pt to continue from")
    p.add_argument("--no-progress", action="store_true", help="no tqdm bar (log lines only)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``detector_train``."""
    from vehicle_common.kitti import KittiFormatError

    args = build_parser().parse_args(argv)
    try:
        return _train(args)
    except (KittiFormatError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def _train(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    torch.set_num_threads(max(1, args.num_threads))
    seed_everything(args.seed)
    device = choose_device(args.device)
    overrides = {
        k: v
        for k, v in {
            "width": args.width,
            "depth": args.depth,
            "input_width": args.input_width,
            "input_height": args.input_height,
            "positive_types": tuple(args.types),
        }.items()
        if v is not None
    }
    config = preset(args.size, **overrides)
    train_refs = sources_from_args(args.train)
    val_refs = sources_from_args(args.val) if args.val else []
    t0 = time.time()

    def load(r):
        return load_sample(r, config.input_width, config.input_height, config.positive_types)

    train_samples = [load(r) for r in tqdm(train_refs, desc="load train", disable=args.no_progress)]
    val_samples = [load(r) for r in val_refs]
    print(
        f"data: {len(train_samples)} train frames, {len(val_samples)} val frames, "
        f"loaded in {time.time() - t0:.1f} s, device {device}",
        flush=True,
    )

    start_epoch, best_ap, history = 0, -1.0, []
    if args.resume:
        model, state = load_checkpoint(args.resume, device)
        config = model.config
        start_epoch = int(state.get("epoch", -1)) + 1
        best_ap = float(state.get("best_ap", -1.0))
        history = json.loads(state.get("history", "[]"))
    else:
        if args.anchors:
            try:
                anchors = json.loads(args.anchors.read_text())["anchors"]
            except (OSError, ValueError, KeyError) as exc:
                raise ValueError(f"{args.anchors}: cannot read anchors ({exc})") from None
        else:
            wh = np.concatenate(
                [
                    np.stack([s.boxes[:, 2] - s.boxes[:, 0], s.boxes[:, 3] - s.boxes[:, 1]], 1)
                    for s in train_samples
                ]
            )
            anchors, miou = kmeans_anchors(wh, k=5, seed=args.seed)
            print(
                f"k-means anchors (input px): {np.round(anchors, 1).tolist()} mean IoU {miou:.3f}",
                flush=True,
            )
        config = preset(args.size, **{**overrides, "anchors": tuple(map(tuple, anchors))})
        model = YoloV2Passthrough(config).to(device)
    weights = LossWeights()
    if args.balance_orientation:
        counts = np.bincount(np.concatenate([s.bins for s in train_samples]), minlength=4)
        inv = 1.0 / np.sqrt(np.maximum(counts, 1) / max(counts.sum(), 1))
        weights.orientation_bin_weights = tuple(float(v) for v in inv / inv.mean())
        print(
            f"orientation bin counts {counts.tolist()}, loss weights "
            f"{np.round(weights.orientation_bin_weights, 3).tolist()}",
            flush=True,
        )
    opt = torch.optim.Adam(model.parameters(), lr=args.lr, betas=(0.9, 0.999))
    if args.resume and "optimizer" in state:
        opt.load_state_dict(state["optimizer"])
    args.output.mkdir(parents=True, exist_ok=True)
    log_path = args.output / "train_log.jsonl"
    train_start = time.time()
    for epoch in range(start_epoch, args.epochs):
        lr = learning_rate(epoch, args.epochs, args)
        for g in opt.param_groups:
            g["lr"] = lr
        model.train()
        rng = np.random.default_rng([args.seed, epoch])
        torch.manual_seed(args.seed * 1000 + epoch)
        order = rng.permutation(len(train_samples))
        sums: dict[str, float] = {}
        nb = 0
        bar = tqdm(
            range(0, len(order), args.batch_size),
            desc=f"epoch {epoch + 1}/{args.epochs}",
            disable=args.no_progress,
            leave=False,
        )
        for start in bar:
            batch = [
                augment(train_samples[i], rng, flip=not args.no_flip, jitter=not args.no_jitter)
                for i in order[start : start + args.batch_size]
            ]
            raw = model(to_tensor([s.image for s in batch], device))
            loss, terms = detection_loss(
                raw,
                [s.boxes for s in batch],
                [s.bins for s in batch],
                [s.dontcare for s in batch],
                config,
                weights,
            )
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            nb += 1
            for k, v in {"loss": loss.item(), **terms}.items():
                sums[k] = sums.get(k, 0.0) + v
            bar.set_postfix({k: f"{v / nb:.3f}" for k, v in sums.items()})
        means = {k: round(v / max(nb, 1), 4) for k, v in sums.items()}
        entry = {
            "epoch": epoch + 1,
            "lr": lr,
            **means,
            "elapsed_s": round(time.time() - train_start, 1),
        }
        if val_samples:
            r50, r70 = validate(model, val_samples, device)
            entry.update(
                ap50=round(r50.ap, 4),
                ap70=round(r70.ap, 4),
                orientation_acc=round(r50.orientation_accuracy, 4),
            )
        history.append(entry)
        print(json.dumps(entry), flush=True)
        with log_path.open("a") as f:
            f.write(json.dumps(entry) + "\n")
        score = entry.get("ap50", -means.get("loss", 0.0))
        extra = {"epoch": epoch, "history": json.dumps(history), "seed": args.seed}
        if score >= best_ap:
            best_ap = score
            save_checkpoint(args.output / "best.pt", model, {**extra, "metrics": json.dumps(entry)})
        save_checkpoint(
            args.output / "last.pt",
            model,
            {**extra, "best_ap": best_ap, "optimizer": opt.state_dict()},
        )
    print(
        f"done: {time.time() - train_start:.1f} s of training, best {best_ap:.4f}, "
        f"checkpoints in {args.output}",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
