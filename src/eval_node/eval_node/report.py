"""The evaluation report: Markdown + simple HTML, PNG figures (matplotlib Agg) and an overlay GIF.

:func:`write_report` takes the dict of :func:`eval_node.bag_evaluation.evaluate_bag` and writes
into ``out_dir``: ``report.md``, ``report.html``, ``pr_<set>.png`` (precision/recall per
difficulty, one curve per threshold), ``orientation_confusion.png``, ``bev_trajectories.png``
(bird's-eye view of tracks vs ground truth, camera 0) and ``overlay.gif`` (left images with
ground truth in red, tracks in green with ids and projected 3D boxes) when images are available
in the bag or under ``images_dir`` (a KITTI tracking root with ``image_02``).
:func:`results_table` is the compact text table printed by the CLI.
"""

from __future__ import annotations

import html
import math
from pathlib import Path

import numpy as np

from eval_node.bag_evaluation import DISTANCES, IOUS
from eval_node.detection_metrics import LEVELS, key

RED, GREEN = (230, 40, 40), (40, 220, 60)


def _pct(v) -> str:
    return "  n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{100 * v:5.1f}"


def _num(v, fmt="{:.3f}") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return fmt.format(v)


# ----------------------------------------------------------------------------- tables


def _ap_rows(title: str, table: dict, thresholds, unit: str, field: str = "") -> list[list[str]]:
    """One row per threshold: AP|R40 per level (``field`` "_actual_recall": at the actual
    recall; rows whose results lack it are left out)."""
    return [
        [f"{title} @ {key(t)}{unit}{', actual recall' if field else ''}"]
        + [_pct(table[key(t)][lv + field]) for lv in LEVELS]
        for t in thresholds
        if all(lv + field in table[key(t)] for lv in LEVELS)
    ]


def table_rows(res: dict) -> tuple[list[str], list[list[str]]]:
    """Header and rows of the AP table (percent)."""
    rows = _ap_rows("3D det", res["detections_3d"], DISTANCES, " m")
    rows += _ap_rows("tracks", res["tracks_3d"], DISTANCES, " m")
    rows += _ap_rows("2D det", res["detections_2d"], IOUS, " IoU")
    voc = res["detections_2d"].get("voc11_0.5")
    if voc:
        rows.append(["2D det VOC11 @ 0.5"] + [_pct(voc[lv]) for lv in LEVELS])
    counted = _counted(res)
    if all(f"{lv}_num_gt" in counted for lv in LEVELS):
        rows.append(["counted ground truth"] + [str(counted[f"{lv}_num_gt"]) for lv in LEVELS])
    if cap_note(res) is not None:  # the devkit's AP|R40 is capped: the actual-recall AP beside
        actual = "_actual_recall"
        rows += _ap_rows("3D det", res["detections_3d"], DISTANCES[:1], " m", actual)
        rows += _ap_rows("tracks", res["tracks_3d"], DISTANCES[:2], " m", actual)
        rows += _ap_rows("2D det", res["detections_2d"], IOUS, " IoU", actual)
    return ["metric (AP|R40 %)", *LEVELS], rows


def _counted(res: dict) -> dict:
    """The first 2D AP row: it holds the counted ground truth per level (``<level>_num_gt``)."""
    return next(iter(res["detections_2d"].values()), {})


def cap_note(res: dict) -> str | None:
    """A line saying where the devkit's interpolation caps AP|R40 (fewer than 40 counted
    ground-truth boxes: about num_gt / 40 at most), or None."""
    counted = _counted(res)
    few = [
        f"{lv} {counted[f'{lv}_num_gt']}"
        for lv in LEVELS
        if 0 < counted.get(f"{lv}_num_gt", 40) < 40
    ]
    if not few:
        return None
    return (
        "note: fewer than 40 counted ground-truth boxes (" + ", ".join(few) + "): the KITTI "
        "devkit's AP|R40 is then at most about num_gt / 40 (here a perfect detector scores that); "
        "the rows marked 'actual recall' take each operating point at its actual recall instead"
    )


def filter_rows(res: dict) -> tuple[list[str], list[list[str]]]:
    """Table 1 layout: 3D mAP at 1.5 m per difficulty for each filter."""
    rows = [
        [name] + [_pct(r[lv]) for lv in LEVELS] + [_num(r.get("fps"), "{:.0f}")]
        for name, r in res.get("filter_comparison", {}).items()
    ]
    return ["filter (3D AP|R40 @ 1.5 m)", *LEVELS, "tracker fps"], rows


def _text_table(header, rows) -> str:
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows, strict=False)]
    line = lambda r: "  ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=False))  # noqa: E731
    return "\n".join([line(header), line(["-" * w for w in widths])] + [line(r) for r in rows])


def _md_table(header, rows) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(out + ["| " + " | ".join(str(c).strip() for c in r) + " |" for r in rows])


def _html_table(header, rows) -> str:
    h = "".join(f"<th>{html.escape(str(c))}</th>" for c in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(c).strip())}</td>" for c in r) + "</tr>"
        for r in rows
    )
    return f"<table><tr>{h}</tr>{body}</table>"


def _pair(a, b, fmt: str = "{:.3f}") -> str:
    """``a / b`` with :func:`_num`'s missing-value text for either."""
    return f"{_num(a, fmt)} / {_num(b, fmt)}"


def _summary_rows(res: dict) -> list[list[str]]:
    t, v, o, th = res["tracking"], res["velocity"], res["orientation"], res["throughput"]
    matched = v.get("stability", {}).get("matched", {})
    rows = [
        ["MOTA (2D IoU 0.5)", _pct(t.get("mota"))],
        ["MOTP (2D IoU)", _pct(t.get("motp"))],
        ["HOTA (2D IoU)", _pct(t.get("hota"))],
        ["MOTA (3D IoU 0.25)", _pct(t.get("iou3d", {}).get("mota"))],
        ["HOTA (3D IoU)", _pct(t.get("iou3d", {}).get("hota"))],
        ["ID switches", _num(t.get("idsw"), "{:.0f}")],
        ["fragmentations", _num(t.get("frag"), "{:.0f}")],
        ["orientation accuracy", _pct(o.get("accuracy"))],
        ["velocity RMSE [m/s]", _num(v.get("rmse"))],
        ["velocity MAE [m/s]", _num(v.get("mae"))],
        ["velocity jitter [m/s per frame]", _num(v.get("velocity_jitter"))],
        [
            "position jitter ratio (tracks/GT, all tracks)",
            _num(v.get("stability", {}).get("ratio")),
        ],
        [
            "position jitter ratio (matched cars)",
            _num(matched.get("ratio")),
        ],
        [  # the metres behind the ratio: labels' own jitter differs by drive
            "position jitter, matched cars: tracks / GT [m]",
            _pair(matched.get("pred_rms_m"), matched.get("gt_rms_m")),
        ],
        ["frames", str(th["frames"])],
        ["throughput [frames/s]", _num(th.get("fps"), "{:.2f}")],
        ["latency mean [ms]", _num(th.get("latency_ms_mean"), "{:.1f}")],
    ]
    return rows


def results_table(res: dict) -> str:
    """Compact text summary (AP table, tracking figures, Table 1) for stdout."""
    parts = [
        f"run: {res['bag']}  sequence {res['sequence']}  ground truth from {res['gt_source']}",
        _text_table(*table_rows(res)),
        _text_table(["tracking / motion", "value"], _summary_rows(res)),
    ]
    note = cap_note(res)
    if note:
        parts.insert(2, note)
    if res.get("filter_comparison"):
        parts.append(_text_table(*filter_rows(res)))
    return "\n\n".join(parts)


# ----------------------------------------------------------------------------- figures


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_pr(curves: dict, title: str, unit: str, path: Path) -> None:
    """Precision/recall per difficulty (one panel each), one curve per threshold."""
    plt = _plt()
    fig, axes = plt.subplots(1, len(LEVELS), figsize=(12, 3.8), sharey=True)
    for ax, level in zip(axes, LEVELS, strict=False):
        for thr, c in curves.get(level, {}).items():
            r, p = np.asarray(c["recall"]), np.asarray(c["precision"])
            keep = (r > 0) | (p > 0)  # unsampled (zero-filled) points are not drawn
            ax.plot(r[keep], p[keep], marker=".", ms=3, label=f"{thr}{unit}")
        ax.set_title(f"{title} - {level}")
        ax.set_xlabel("recall")
        ax.set_xlim(0, 1.02)
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("precision")
    axes[-1].legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_confusion(confusion, path: Path) -> None:
    """4x4 orientation-bin confusion matrix (rows: ground truth, columns: prediction)."""
    plt = _plt()
    c = np.asarray(confusion, dtype=float)
    fig, ax = plt.subplots(figsize=(4.2, 3.8))
    ax.imshow(c, cmap="Blues")
    names = ["0", "45", "90", "135"]
    ax.set_xticks(range(4), names)
    ax.set_yticks(range(4), names)
    ax.set_xlabel("predicted bin [deg]")
    ax.set_ylabel("ground-truth bin [deg]")
    for i in range(4):
        for j in range(4):
            ax.text(j, i, f"{int(c[i, j])}", ha="center", va="center", fontsize=9)
    ax.set_title("orientation confusion")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_bev(trajectories: dict, path: Path) -> None:
    """Bird's-eye view (x right, z forward; camera 0) of ground-truth and track trajectories."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 6))
    for i, (_tid, pts) in enumerate(trajectories.get("gt", {}).items()):
        p = np.asarray(pts, float).reshape(-1, 2)
        ax.plot(p[:, 0], p[:, 1], "-", color="tab:red", lw=2.5, alpha=0.5,
                label="ground truth" if i == 0 else None)  # fmt: skip
    for i, (tid, pts) in enumerate(trajectories.get("tracks", {}).items()):
        p = np.asarray(pts, float).reshape(-1, 2)
        ax.plot(p[:, 0], p[:, 1], ".-", color="tab:green", ms=3, lw=1,
                label="tracks" if i == 0 else None)  # fmt: skip
        ax.annotate(str(tid), p[-1], fontsize=7, color="darkgreen")
    ax.plot([0], [0], "k^", label="camera")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title("bird's-eye view (camera 0)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


# ----------------------------------------------------------------------------- overlay GIF


def draw_overlay(image: np.ndarray, gt, preds, P: np.ndarray | None) -> np.ndarray:
    """Left image with ground-truth 2D boxes (red) and predictions (green: 2D box, id, projected
    3D box when ``P``, the camera-0-to-left-image matrix, is given)."""
    import cv2
    from vehicle_common.box3d import box_corners, box_edges, project_points

    img = np.ascontiguousarray(image.copy())
    for o in gt:
        if o.is_dontcare:
            continue
        x1, y1, x2, y2 = (int(round(v)) for v in o.bbox)
        cv2.rectangle(img, (x1, y1), (x2, y2), RED, 2)
    for o in preds:
        x1, y1, x2, y2 = (int(round(v)) for v in o.bbox)
        if x2 > x1 and y2 > y1:
            cv2.rectangle(img, (x1, y1), (x2, y2), GREEN, 1)
        if P is not None and o.location[2] > 0.5:
            corners = box_corners(o.dimensions, o.location, o.rotation_y)
            if (corners[:, 2] > 0.1).all():
                uv = project_points(P, corners)
                for a, b in box_edges():
                    pa, pb = tuple(int(v) for v in uv[a]), tuple(int(v) for v in uv[b])
                    cv2.line(img, pa, pb, GREEN, 1, cv2.LINE_AA)
        if o.track_id >= 0:
            cv2.putText(img, str(o.track_id), (x1, max(y1 - 3, 10)), cv2.FONT_HERSHEY_SIMPLEX,
                        0.5, GREEN, 1, cv2.LINE_AA)  # fmt: skip
    return img


def write_gif(frames: list[np.ndarray], path: Path, fps: float = 5.0, max_width: int = 640) -> None:
    """Animated GIF of RGB frames (downscaled to ``max_width``)."""
    import cv2
    from PIL import Image

    imgs = []
    for f in frames:
        h, w = f.shape[:2]
        if w > max_width:
            f = cv2.resize(
                f, (max_width, int(round(h * max_width / w))), interpolation=cv2.INTER_AREA
            )
        imgs.append(Image.fromarray(f))
    imgs[0].save(path, save_all=True, append_images=imgs[1:], duration=int(1000 / fps), loop=0)


def _overlay_frames(res: dict, run, images_dir, max_frames: int) -> list[np.ndarray]:
    from vehicle_common.bags.recorded_run import read_left_images
    from vehicle_common.kitti import read_calib, read_png

    frames = run.frames[:max_frames]
    P = run.P_left
    images = read_left_images(run.path, {f.stamp_ns for f in frames})
    out = []
    if images:
        for f in frames:
            if f.stamp_ns in images:
                out.append(draw_overlay(images[f.stamp_ns], f.gt, f.tracks, P))
        return out
    if images_dir is None:
        return []
    root, seq = Path(images_dir), res["sequence"]
    if P is None and (root / "calib" / f"{seq}.txt").is_file():
        P = read_calib(root / "calib" / f"{seq}.txt").P2
    for f in frames:
        p = root / "image_02" / seq / f"{f.frame:06d}.png"
        if p.is_file():
            out.append(draw_overlay(read_png(p), f.gt, f.tracks, P))
    return out


# ----------------------------------------------------------------------------- report


def write_report(
    results: dict,
    out_dir: str | Path,
    run=None,
    images_dir: str | Path | None = None,
    max_gif_frames: int = 60,
) -> dict[str, Path]:
    """Write the report files into ``out_dir``; returns ``{name: path}`` of what was written.
    ``run``: the RecordedRun (re-read from ``results["bag"]`` when None) for the GIF."""
    from vehicle_common.bags.recorded_run import read_run

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {}
    curves = results.get("curves", {})
    for name, title, unit in (
        ("detections_3d", "3D detections", " m"),
        ("tracks_3d", "tracks", " m"),
        ("detections_2d", "2D detections", " IoU"),
    ):
        files[f"pr_{name}"] = out / f"pr_{name}.png"
        plot_pr(curves.get(name, {}), title, unit, files[f"pr_{name}"])
    files["confusion"] = out / "orientation_confusion.png"
    plot_confusion(results["orientation"]["confusion"], files["confusion"])
    files["bev"] = out / "bev_trajectories.png"
    plot_bev(results.get("trajectories", {}), files["bev"])

    if run is None and Path(results["bag"]).exists():
        run = read_run(results["bag"])
    if run is not None:
        frames = _overlay_frames(results, run, images_dir, max_gif_frames)
        if frames:
            files["gif"] = out / "overlay.gif"
            write_gif(frames, files["gif"])

    sections = [
        ("Detection and localisation AP|R40 (KITTI devkit interpolation, %)", table_rows(results)),
        ("Tracking and motion", (["metric", "value"], _summary_rows(results))),
    ]
    if results.get("filter_comparison"):
        sections.append(("Filter comparison (Table 1)", filter_rows(results)))
    figs = [p for k, p in files.items() if k != "gif"] + ([files["gif"]] if "gif" in files else [])
    head = (
        f"Bag `{results['bag']}`, sequence {results['sequence']}, {results['frames']} frames, "
        f"ground truth from {results['gt_source']}."
    )
    md = [f"# Evaluation report\n\n{head}\n"]
    md += [f"## {title}\n\n{_md_table(*tab)}\n" for title, tab in sections]
    md.append("## Figures\n\n" + "\n\n".join(f"![{p.stem}]({p.name})" for p in figs) + "\n")
    files["md"] = out / "report.md"
    files["md"].write_text("\n".join(md))
    body = [f"<h1>Evaluation report</h1><p>{html.escape(head)}</p>"]
    body += [f"<h2>{html.escape(t)}</h2>{_html_table(*tab)}" for t, tab in sections]
    body += ["<h2>Figures</h2>"] + [f'<p><img src="{p.name}" alt="{p.stem}"></p>' for p in figs]
    style = "table{border-collapse:collapse}td,th{border:1px solid #999;padding:2px 8px}"
    files["html"] = out / "report.html"
    files["html"].write_text(
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>Evaluation report</title>"
        f"<style>{style}</style></head><body>{''.join(body)}</body></html>\n"
    )
    return files
