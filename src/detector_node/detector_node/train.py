"""``detector_train``: train the detector on KITTI object/tracking layouts.

Data: real frames (``--train``), supplementary crops with incomplete labels (``--partial``) and
synthetic frames (``--synthetic``), each ``SOURCE[@WEIGHT]``, mixed by weight
(:mod:`detector_node.training_data`) with the augmentations of :mod:`detector_node.augmentation`.
``--init`` starts from a checkpoint's weights (e.g. synthetic pre-training); anchors come from
k-means on the real (``--train``) boxes unless ``--anchors``.

Adam (0.9, 0.999), batch 8, the paper's schedule by default (warm-up epochs at 1e-4, bulk at
1e-3, final epochs at 1e-6), validation AP each epoch, checkpoint every epoch (``last.pt`` with
optimizer state for ``--resume``; ``best.pt`` weights + config only, best validation AP@0.5;
``final.pt`` weights + config of the last epoch), fixed seeds, CPU or CUDA chosen automatically.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from vehicle_common.output_paths import make_output_dir

from .anchors import kmeans_anchors
from .augmentation import crop_roi_top, resize_sample
from .centernet import centernet_loss
from .checkpoint import load_checkpoint, save_checkpoint
from .dataset import (
    Sample,
    add_data_arguments,
    frames_from_source,
    load_full_sample,
    load_sample,
    parse_weighted_source,
    sample_alphas,
    sample_view,
    sources_from_args,
)
from .inference import choose_device, decode_output, to_tensor
from .loss import LossWeights, detection_loss
from .model import YoloV2Passthrough, preset
from .training_data import AugmentConfig, Source, TrainingMix
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


def anchor_box_sizes(sources: list[Source], config) -> np.ndarray:
    """Widths/heights (N, 2) in network-input px of the boxes of the ``real`` sources (all
    sources when there is none), for the k-means anchors."""
    use = [s for s in sources if s.kind == "real"] or sources
    wh = []
    for src in use:
        for x in src.samples:
            h, w = x.image.shape[:2]
            sx, sy = config.input_width / w, config.input_height / h
            b = x.boxes
            wh.append(np.stack([(b[:, 2] - b[:, 0]) * sx, (b[:, 3] - b[:, 1]) * sy], 1))
    wh = np.concatenate(wh) if wh else np.zeros((0, 2))
    return wh[(wh > 1).all(axis=1)]


def _val_sample(ref, config, types):
    """A validation frame at network resolution, framed as inference frames it (the top
    ``config.roi_top`` of the image left out)."""
    if not config.roi_top:
        return load_sample(ref, config.input_width, config.input_height, types)
    framed = crop_roi_top(load_full_sample(ref, types), config.roi_top)
    return resize_sample(framed, config.input_width, config.input_height)


def _centernet_model(args: argparse.Namespace, config, device):
    """The CenterNet detector: from ``--init`` (a CenterNet checkpoint, input size of
    ``config``) or from the pretrained package."""
    from .pretrained import pretrained_centernet

    if args.init:
        model, _ = load_checkpoint(args.init, device)
        if model.config.size != "centernet":
            raise ValueError(f"{args.init}: not a centernet checkpoint")
        model.config = config
        print(f"initialised from {args.init}", flush=True)
        return model
    model = pretrained_centernet(config, args.pretrained).to(device)
    print(f"initialised from the pretrained package ({args.pretrained or 'setup cache'})")
    return model


@dataclass
class BankItem:
    """One augmented training sample reduced to its fixed (frozen-backbone) feature."""

    feature: torch.Tensor  # (128, H/4, W/4) float16
    boxes: np.ndarray
    alphas: np.ndarray
    dontcare: np.ndarray
    view: np.ndarray  # (N, 2) Sample.view


def _feature_bank(model, mix: TrainingMix, args: argparse.Namespace, device) -> list[BankItem]:
    """``--feature-bank N`` augmented samples drawn once from the training mix (same pipeline and
    weights as the epochs), passed through the frozen graph; the epochs then train the heads on
    these stored features (float16). With ``--bank-cache FILE`` the bank is read from FILE when
    FILE holds the bank of the same data, augmentation, seed, size and initial weights, else
    built and written there (recipes that differ only in how the heads train share it)."""
    key = _bank_key(model, args)
    if args.bank_cache and args.bank_cache.is_file():
        stored = torch.load(args.bank_cache, weights_only=True)
        if stored.get("key") == key:
            bank = [
                BankItem(f, b.numpy(), a.numpy(), d.numpy(), v.numpy())
                for f, b, a, d, v in zip(*(stored[k] for k in "fbadv"), strict=True)
            ]
            print(f"feature bank: {len(bank)} samples read from {args.bank_cache}", flush=True)
            return bank
        print(f"feature bank: {args.bank_cache} holds another bank: rebuilt", flush=True)
    rng = np.random.default_rng([args.seed, 7919])
    order = mix.draw(args.feature_bank, rng)
    bank: list[BankItem] = []
    t0 = time.time()
    model.eval()
    with torch.no_grad():
        for start in range(0, len(order), args.batch_size):
            batch = [mix.make(k, i, rng) for k, i in order[start : start + args.batch_size]]
            size = args.micro_batch if args.micro_batch > 0 else len(batch)
            f = torch.cat(
                [
                    model.features(to_tensor([s.image for s in batch[j : j + size]], device))
                    for j in range(0, len(batch), size)
                ]
            )
            for s, fi in zip(batch, f, strict=True):
                bank.append(
                    BankItem(fi.half().cpu(), s.boxes, sample_alphas(s), s.dontcare, sample_view(s))
                )
    print(f"feature bank: {len(bank)} samples in {time.time() - t0:.1f} s", flush=True)
    if args.bank_cache:
        stored = {
            "key": key,
            "f": [it.feature for it in bank],
            "b": [torch.from_numpy(np.asarray(it.boxes, np.float32)) for it in bank],
            "a": [torch.from_numpy(np.asarray(it.alphas, np.float32)) for it in bank],
            "d": [torch.from_numpy(np.asarray(it.dontcare, np.float32)) for it in bank],
            "v": [torch.from_numpy(np.asarray(it.view, np.float32)) for it in bank],
        }
        args.bank_cache.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.bank_cache.with_suffix(".tmp")
        torch.save(stored, tmp)
        tmp.replace(args.bank_cache)
    return bank


def _bank_key(model, args: argparse.Namespace) -> str:
    """What a feature bank depends on: data and weights, augmentation, seed, size, the graph's
    weights (a checksum)."""
    names = (
        "train partial synthetic types seed feature_bank input_width input_height roi_top "
        "no_flip no_jitter crop_probability min_scale max_scale paste_probability paste_max"
    )
    opts = {k: getattr(args, k, None) for k in names.split()}
    with torch.no_grad():
        weights = sum(float(p.double().abs().sum()) for p in model.graph.parameters())
    key = {**opts, "graph_weights": round(weights, 3), "format": 2}  # 2: with the boxes' view
    return json.dumps(key, sort_keys=True, default=str)


def _centernet_batch_loss(
    model,
    f: torch.Tensor,
    items,
    rng,
    orientation_weight: float,
    bin_weights=None,
    residual_overlap: bool = False,
    normalisers=None,
    bin_smoothing: float = 0.0,
    true_view: bool = False,
):
    """CenterNet loss of a batch of features ``f`` and their samples (boxes, alphas, DontCare);
    the orientation head sees the ground-truth boxes with each edge moved by up to 5 % of the
    box size (as the predicted boxes it meets at inference); ``bin_weights``: those of
    ``--balance-orientation`` (None: unweighted); ``residual_overlap``: those of
    ``--residual-overlap`` (MultiBin's overlapping bins); ``normalisers``: the whole batch's
    when ``items`` is one of its micro-batches (:func:`~detector_node.centernet.loss_normalisers`);
    ``bin_smoothing``: that of ``--orientation-smoothing``; ``true_view``: the orientation head
    is told where each box was seen (``Sample.view``), not where it is in the input
    (``--true-view``)."""
    boxes = [it.boxes for it in items]
    alphas = [sample_alphas(it) if isinstance(it, Sample) else it.alphas for it in items]
    view = None
    if true_view:  # the rows the loss evaluates: the boxes with a known angle
        known = np.isfinite(np.concatenate([np.asarray(a, float) for a in alphas]))
        views = np.concatenate(
            [sample_view(it) if isinstance(it, Sample) else it.view for it in items]
        )
        view = torch.from_numpy(views.reshape(-1, 2)[known].astype(np.float32)).to(f.device)

    def orientation(batch_idx: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
        wh = (gt[:, 2:] - gt[:, :2]).repeat(1, 2)
        noise = torch.from_numpy(rng.uniform(-0.05, 0.05, gt.shape).astype(np.float32))
        return model.orientation_at(f, batch_idx, gt + noise.to(gt.device) * wh, view)

    return centernet_loss(
        model.dense(f),
        boxes,
        alphas,
        [it.dontcare for it in items],
        {"bin": orientation_weight, "residual": orientation_weight},
        orientation,
        bin_weights,
        residual_overlap,
        normalisers,
        bin_smoothing,
    )


def _centernet_step(model, batch, bank: bool, args, bin_weights, rng, device):
    """Loss terms of one CenterNet batch, its gradients accumulated (``backward``): the whole
    batch at once, or with ``--micro-batch M`` in micro-batches of M samples whose losses,
    normalised by the whole batch's denominators, sum to the batch's (less memory: the large
    intermediate maps stay below glibc's mmap threshold and are reused, 2-4x less CPU time)."""
    size = args.micro_batch if args.micro_batch > 0 else len(batch)
    norm = None
    if size < len(batch):
        from .centernet import STRIDE, loss_normalisers

        gh, gw = model.config.input_height // STRIDE, model.config.input_width // STRIDE
        norm = loss_normalisers(
            [it.boxes for it in batch],
            [it.alphas if bank else sample_alphas(it) for it in batch],
            [it.dontcare for it in batch],
            gh,
            gw,
            bin_weights,
            args.residual_overlap,
        )
    sums: dict[str, float] = {}
    for start in range(0, len(batch), size):
        items = batch[start : start + size]
        if bank:
            f = torch.stack([it.feature for it in items]).to(device).float()
            f = f.contiguous(memory_format=torch.channels_last)  # 2x faster depthwise heads
        else:
            f = model.features(to_tensor([s.image for s in items], device))
        loss, terms = _centernet_batch_loss(
            model,
            f,
            items,
            rng,
            args.orientation_weight,
            bin_weights,
            args.residual_overlap,
            norm,
            args.orientation_smoothing,
            args.true_view,
        )
        loss.backward()
        for k, v in {"loss": loss.item(), **terms}.items():
            sums[k] = sums.get(k, 0.0) + v
    return sums


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="detector_train",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_data_arguments(p)
    p.add_argument("--output", type=Path, required=True, help="folder for last.pt / best.pt / log")
    p.add_argument(
        "--size",
        choices=["tiny", "full", "centernet"],
        default="tiny",
        help="tiny / full (the paper's YOLOv2) or centernet (pretrained MobileNetV3 CenterNet "
        "of @vladmandic/human 3.3.6, installed by scripts/setup.sh, or --init / --pretrained)",
    )
    p.add_argument(
        "--pretrained",
        type=Path,
        help="centernet: the package's centernet.json (default: the cache of scripts/setup.sh)",
    )
    p.add_argument(
        "--feature-bank",
        type=int,
        default=0,
        help="centernet with --freeze-backbone: draw this many augmented samples once, store "
        "their graph features and train the heads on them (0 = fresh samples every step)",
    )
    p.add_argument(
        "--bank-cache",
        type=Path,
        help="file for the feature bank: read when it holds the same bank, else written",
    )
    p.add_argument(
        "--orientation-only",
        action="store_true",
        help="centernet: train the new orientation head only (graph, heat and box heads fixed)",
    )
    p.add_argument(
        "--freeze-backbone",
        action="store_true",
        help="centernet: train the heads only (the pretrained graph stays fixed)",
    )
    p.add_argument("--width", type=float, help="channel multiplier (default: preset's)")
    p.add_argument("--depth", type=int, help="layers kept per stage (default: preset's)")
    p.add_argument("--input-width", type=int, help="network input width (default: preset's)")
    p.add_argument("--input-height", type=int, help="network input height (default: preset's)")
    p.add_argument(
        "--roi-top",
        type=float,
        default=0.0,
        help="fraction of each frame's height at the top left out before the resize, in "
        "training and at inference (stored in the checkpoint; DetectorConfig.roi_top)",
    )
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
    p.add_argument(
        "--synthetic",
        nargs="*",
        default=[],
        metavar="ROOT[:SEQ,...][@W]",
        help="synthetic frames (network resolution; flip + photometric augmentation only)",
    )
    p.add_argument(
        "--partial",
        nargs="*",
        default=[],
        metavar="ROOT[@W]",
        help="native-resolution crops with incomplete Car labels (object_crops352 layout)",
    )
    p.add_argument("--init", type=Path, help="checkpoint whose weights start the training")
    p.add_argument(
        "--epoch-samples",
        type=int,
        help="samples drawn per epoch (default: frames of all sources together)",
    )
    p.add_argument("--no-flip", action="store_true", help="disable horizontal flips")
    p.add_argument(
        "--no-jitter", action="store_true", help="disable photometric jitter, blur and noise"
    )
    p.add_argument("--crop-probability", type=float, default=0.6, help="scale jitter + crop")
    p.add_argument("--min-scale", type=float, default=0.6, help="smallest crop / frame size")
    p.add_argument("--max-scale", type=float, default=1.0, help="largest crop / frame size")
    p.add_argument(
        "--paste-probability", type=float, default=0.5, help="copy-paste of real car crops"
    )
    p.add_argument("--paste-max", type=int, default=3, help="most cars pasted per frame")
    p.add_argument(
        "--balance-orientation",
        action="store_true",
        help="weight the orientation loss by 1/sqrt(bin frequency) of the training boxes",
    )
    p.add_argument(
        "--residual-overlap",
        action="store_true",
        help="centernet: train the angle residual of both bins within 45 deg of the true angle "
        "(MultiBin's overlapping bins), not only the true bin's",
    )
    p.add_argument(
        "--orientation-weight", type=float, default=1.0, help="weight of the orientation loss"
    )
    p.add_argument(
        "--orientation-smoothing",
        type=float,
        default=0.0,
        help="centernet: label smoothing of the 4-bin targets: this share goes to the two "
        "neighbouring bins (0 and 135 deg are neighbours across the 180-deg fold), the nearer "
        "one taking more (0 = one-hot)",
    )
    p.add_argument(
        "--true-view",
        action="store_true",
        help="centernet: give the orientation head where each training box was seen in its "
        "frame (before scale jitter, crops and pastes moved it), as inference sees it",
    )
    p.add_argument(
        "--micro-batch",
        type=int,
        default=0,
        help="centernet: run each batch in micro-batches of this many samples, the gradients "
        "accumulated (same loss as the whole batch, less memory and CPU; 0 = whole batch)",
    )
    p.add_argument(
        "--ema",
        type=float,
        default=0.0,
        help="decay of an exponential moving average of the weights (e.g. 0.995; 0 = off); "
        "validation, best.pt and final.pt then use the averaged weights",
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


def _setup_process(args: argparse.Namespace):
    """Output folder, threads, allocator, seeds; the device."""
    make_output_dir(args.output)  # before the data is loaded: a bad path fails at once
    torch.set_num_threads(max(1, args.num_threads))
    try:  # large maps freed and allocated every step: keep them in the heap for reuse
        from vehicle_common.malloc_policy import keep_freed_memory

        keep_freed_memory()
    except RuntimeError:  # not glibc
        pass
    seed_everything(args.seed)
    return choose_device(args.device)


def _config_overrides(args: argparse.Namespace) -> dict:
    """The model-preset fields set on the command line."""
    return {
        k: v
        for k, v in {
            "width": args.width,
            "depth": args.depth,
            "input_width": args.input_width,
            "input_height": args.input_height,
            "roi_top": args.roi_top,
            "positive_types": tuple(args.types),
        }.items()
        if v is not None
    }


def _load_source(spec: str, kind: str, config) -> Source:
    """One ``SOURCE[@WEIGHT]`` of kind real / partial / synthetic with its samples."""
    source, weight = parse_weighted_source(spec)
    refs = frames_from_source(source)
    if not refs:
        raise ValueError(f"{source}: no frames found")
    types = config.positive_types
    if kind == "synthetic":
        samples = [load_sample(r, config.input_width, config.input_height, types) for r in refs]
    else:
        samples = [load_full_sample(r, types) for r in refs]
    return Source(source, kind, samples, weight)


def _load_data(args: argparse.Namespace, config, device) -> tuple[list[Source], list[Sample]]:
    """The training sources and the validation samples (one line on what was loaded)."""
    t0 = time.time()
    sources = (
        [_load_source(x, "real", config) for x in args.train]
        + [_load_source(x, "partial", config) for x in args.partial]
        + [_load_source(x, "synthetic", config) for x in args.synthetic]
    )
    val_refs = sources_from_args(args.val) if args.val else []
    val_samples = [_val_sample(r, config, config.positive_types) for r in val_refs]
    n_train = sum(len(s.samples) for s in sources)
    print(
        f"data: {n_train} train frames, {len(val_samples)} val frames, "
        f"loaded in {time.time() - t0:.1f} s, device {device}",
        flush=True,
    )
    return sources, val_samples


@dataclass
class _Start:
    """Where the epochs start: 0 and no history, or a resumed run's (``state``: its
    checkpoint)."""

    epoch: int = 0
    best_ap: float = -1.0
    history: list = field(default_factory=list)
    state: dict = field(default_factory=dict)


def _anchors(args: argparse.Namespace, sources: list[Source], config) -> list:
    """``--anchors`` FILE's, else k-means on the training boxes (printed)."""
    if args.anchors:
        try:
            return json.loads(args.anchors.read_text())["anchors"]
        except (OSError, ValueError, KeyError) as exc:
            raise ValueError(f"{args.anchors}: cannot read anchors ({exc})") from None
    anchors, miou = kmeans_anchors(anchor_box_sizes(sources, config), k=5, seed=args.seed)
    print(
        f"k-means anchors (input px): {np.round(anchors, 1).tolist()} mean IoU {miou:.3f}",
        flush=True,
    )
    return anchors


def _yolo_model(args: argparse.Namespace, config, overrides: dict, sources, device):
    """The YOLOv2 detector (``config`` with its anchors), from ``--init``'s weights when
    given."""
    anchors = _anchors(args, sources, config)
    config = preset(args.size, **{**overrides, "anchors": tuple(map(tuple, anchors))})
    model = YoloV2Passthrough(config).to(device)
    if args.init:
        init_model, _ = load_checkpoint(args.init, device)
        ic = init_model.config
        if (ic.width, ic.depth) != (config.width, config.depth):
            raise ValueError(
                f"{args.init}: width/depth {ic.width}/{ic.depth} differ from "
                f"{config.width}/{config.depth}"
            )
        model.load_state_dict(init_model.state_dict())
        print(f"initialised from {args.init}", flush=True)
    return model


def _start_model(args: argparse.Namespace, config, overrides: dict, sources, device):
    """(model, start): a new CenterNet or YOLOv2 model of ``config``, or ``--resume``'s."""
    if args.size == "centernet" and not args.resume:
        return _centernet_model(args, config, device), _Start()
    if args.resume:
        model, state = load_checkpoint(args.resume, device)
        start = _Start(
            int(state.get("epoch", -1)) + 1,
            float(state.get("best_ap", -1.0)),
            json.loads(state.get("history", "[]")),
            state,
        )
        return model, start
    return _yolo_model(args, config, overrides, sources, device), _Start()


def _freeze_parts(model, args: argparse.Namespace) -> None:
    """``--freeze-backbone`` / ``--orientation-only`` (CenterNet): fixed parts take no gradient;
    ``--orientation-only`` implies ``--freeze-backbone``."""
    if model.config.size == "centernet" and (args.freeze_backbone or args.orientation_only):
        args.freeze_backbone = True
        fixed = [model.graph] + ([model.heat, model.box] if args.orientation_only else [])
        for part in fixed:
            for prm in part.parameters():
                prm.requires_grad_(False)


def _training_mix(sources: list[Source], config, args: argparse.Namespace) -> TrainingMix:
    return TrainingMix(
        sources,
        config.input_width,
        config.input_height,
        AugmentConfig(
            flip=not args.no_flip,
            photometric=not args.no_jitter,
            crop_probability=args.crop_probability,
            min_scale=args.min_scale,
            max_scale=args.max_scale,
            paste_probability=args.paste_probability,
            paste_max=args.paste_max,
            roi_top=config.roi_top,
        ),
    )


def _loss_weights(args: argparse.Namespace, sources: list[Source]) -> LossWeights:
    """The loss weights; ``--balance-orientation``: bin weights 1 / sqrt(frequency), mean 1."""
    weights = LossWeights(orientation=args.orientation_weight)
    if args.balance_orientation:
        bins = np.concatenate([x.bins for s in sources for x in s.samples])
        counts = np.bincount(bins[bins >= 0], minlength=4)
        inv = 1.0 / np.sqrt(np.maximum(counts, 1) / max(counts.sum(), 1))
        weights.orientation_bin_weights = tuple(float(v) for v in inv / inv.mean())
        print(
            f"orientation bin counts {counts.tolist()}, loss weights "
            f"{np.round(weights.orientation_bin_weights, 3).tolist()}",
            flush=True,
        )
    return weights


def _optimizer(model, args: argparse.Namespace, start: _Start) -> torch.optim.Optimizer:
    """Adam; for the CenterNet the new orientation head at the full rate, the pretrained parts
    at 1/5 (a group's ``scale``); a resumed run's state loaded."""
    if model.config.size == "centernet":
        new = list(model.orientation.parameters())
        ids = {id(q) for q in new}
        old = [q for q in model.parameters() if q.requires_grad and id(q) not in ids]
        groups = [{"params": new, "scale": 1.0}, {"params": old, "scale": 0.2}]
    else:
        groups = [{"params": [q for q in model.parameters() if q.requires_grad], "scale": 1.0}]
    opt = torch.optim.Adam(groups, lr=args.lr, betas=(0.9, 0.999))
    if args.resume and "optimizer" in start.state:
        opt.load_state_dict(start.state["optimizer"])
    return opt


@dataclass
class _Trainer:
    """The parts of a run the epochs use."""

    args: argparse.Namespace
    model: torch.nn.Module
    opt: torch.optim.Optimizer
    mix: TrainingMix
    weights: LossWeights
    bank: list[BankItem] | None
    epoch_samples: int
    device: object
    ema: object = None

    @property
    def eval_model(self):
        """What is validated and saved as best / final: the EMA's average when ``--ema``."""
        return self.ema.module if self.ema is not None else self.model

    def epoch(self, epoch: int) -> tuple[float, dict[str, float]]:
        """Train one epoch: (its learning rate, the mean of each loss term)."""
        from tqdm import tqdm

        args = self.args
        lr = learning_rate(epoch, args.epochs, args)
        for g in self.opt.param_groups:
            g["lr"] = lr * g.get("scale", 1.0)
        self.model.train()
        rng = np.random.default_rng([args.seed, epoch])
        torch.manual_seed(args.seed * 1000 + epoch)
        order = self.mix.draw(self.epoch_samples, rng)
        if self.bank is not None:
            order = rng.permutation(len(self.bank))[: min(self.epoch_samples, len(self.bank))]
        sums: dict[str, float] = {}
        nb = 0
        bar = tqdm(
            range(0, len(order), args.batch_size),
            desc=f"epoch {epoch + 1}/{args.epochs}",
            disable=args.no_progress,
            leave=False,
        )
        for start in bar:
            chunk = order[start : start + args.batch_size]
            if self.model.config.size == "centernet":
                terms = self._centernet_batch(chunk, rng)
            else:
                terms = self._yolo_batch(chunk, rng)
            if self.ema is not None:
                self.ema.update_parameters(self.model)
            nb += 1
            for k, v in terms.items():
                sums[k] = sums.get(k, 0.0) + v
            bar.set_postfix({k: f"{v / nb:.3f}" for k, v in sums.items()})
        return lr, {k: round(v / max(nb, 1), 4) for k, v in sums.items()}

    def _centernet_batch(self, chunk, rng) -> dict[str, float]:
        self.opt.zero_grad(set_to_none=True)
        if self.bank is not None:
            batch = [self.bank[j] for j in chunk]
        else:
            batch = [self.mix.make(k, i, rng) for k, i in chunk]
        terms = _centernet_step(
            self.model,
            batch,
            self.bank is not None,
            self.args,
            self.weights.orientation_bin_weights,
            rng,
            self.device,
        )
        self.opt.step()
        return terms

    def _yolo_batch(self, chunk, rng) -> dict[str, float]:
        batch = [self.mix.make(k, i, rng) for k, i in chunk]
        raw = self.model(to_tensor([s.image for s in batch], self.device))
        loss, terms = detection_loss(
            raw,
            [s.boxes for s in batch],
            [s.bins for s in batch],
            [s.dontcare for s in batch],
            self.model.config,
            self.weights,
        )
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        self.opt.step()
        return {"loss": loss.item(), **terms}


def _trainer(args: argparse.Namespace, model, sources, start: _Start, device) -> _Trainer:
    """The optimizer, mix, loss weights, feature bank and EMA of a run."""
    _freeze_parts(model, args)
    mix = _training_mix(sources, model.config, args)
    print(mix.summary(), flush=True)
    n_train = sum(len(s.samples) for s in sources)
    weights = _loss_weights(args, sources)
    bank = None
    if model.config.size == "centernet" and args.feature_bank:
        if not args.freeze_backbone:
            raise ValueError("--feature-bank needs --freeze-backbone (the features are fixed)")
        bank = _feature_bank(model, mix, args, device)
    opt = _optimizer(model, args, start)
    trainer = _Trainer(args, model, opt, mix, weights, bank, args.epoch_samples or n_train, device)
    if args.ema:
        from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

        trainer.ema = AveragedModel(
            model, multi_avg_fn=_ema_of_floats(get_ema_multi_avg_fn(args.ema)), use_buffers=True
        )
    return trainer


def _ema_of_floats(ema_fn):
    """``--ema``'s average of the floating-point parameters and buffers (``ema_fn``, torch's
    per-dtype group); integer buffers (the CenterNet graph's int32 constants, BatchNorm's
    counters) are copied from the model, never averaged: averaged, a shape constant of 3
    truncated to 2 and the saved checkpoint failed ("concat on axis 2 not supported")."""

    def average(averaged: list, current: list, n_averaged) -> None:
        if averaged and not averaged[0].is_floating_point():
            torch._foreach_copy_(averaged, current)
        else:
            ema_fn(averaged, current, n_averaged)

    return average


def _end_epoch(
    trainer: _Trainer, start: _Start, epoch: int, entry: dict, val_samples: list[Sample]
) -> None:
    """Validate, log (stdout and ``train_log.jsonl``) and save ``best.pt`` / ``last.pt``."""
    args, eval_model = trainer.args, trainer.eval_model
    if val_samples:
        r50, r70 = validate(eval_model, val_samples, trainer.device)
        entry.update(
            ap50=round(r50.ap, 4),
            ap70=round(r70.ap, 4),
            orientation_acc=round(r50.orientation_accuracy, 4),
        )
    start.history.append(entry)
    print(json.dumps(entry), flush=True)
    with (args.output / "train_log.jsonl").open("a") as f:
        f.write(json.dumps(entry) + "\n")
    score = entry.get("ap50", -entry.get("loss", 0.0))
    extra = {"epoch": epoch, "history": json.dumps(start.history), "seed": args.seed}
    if score >= start.best_ap:
        start.best_ap = score
        save_checkpoint(
            args.output / "best.pt", eval_model, {**extra, "metrics": json.dumps(entry)}
        )
    save_checkpoint(
        args.output / "last.pt",
        trainer.model,
        {**extra, "best_ap": start.best_ap, "optimizer": trainer.opt.state_dict()},
    )


def _train(args: argparse.Namespace) -> int:
    device = _setup_process(args)
    overrides = _config_overrides(args)
    config = preset(args.size, **overrides)
    sources, val_samples = _load_data(args, config, device)
    model, start = _start_model(args, config, overrides, sources, device)
    trainer = _trainer(args, model, sources, start, device)
    train_start = time.time()
    for epoch in range(start.epoch, args.epochs):
        lr, means = trainer.epoch(epoch)
        elapsed = round(time.time() - train_start, 1)
        entry = {"epoch": epoch + 1, "lr": lr, **means, "elapsed_s": elapsed}
        _end_epoch(trainer, start, epoch, entry, val_samples)
    final = {"epoch": args.epochs - 1, "seed": args.seed}
    save_checkpoint(args.output / "final.pt", trainer.eval_model, final)
    print(
        f"done: {time.time() - train_start:.1f} s of training, best {start.best_ap:.4f}, "
        f"checkpoints in {args.output}",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
