"""The detector's PyTorch-free ONNX Runtime path and its user cache: the same detections as
the PyTorch module's sparse part, no torch import once cached, entries keyed by the checkpoint's
content and the input size, safe against corrupt files and concurrent writers."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import numpy as np
import pytest
from detector_node.loading import load_detector, onnxruntime_installed
from detector_node.onnx_cache import MAX_ENTRIES, OnnxCache, cache_dir

needs_ort = pytest.mark.skipif(not onnxruntime_installed(), reason="onnxruntime not installed")


def _same(a, b):
    assert len(a) == len(b) > 0
    for p, q in zip(a, b, strict=True):
        assert np.allclose(p.box, q.box, atol=1e-4)
        assert abs(p.score - q.score) < 1e-6
        assert p.orientation_bin == q.orientation_bin
        assert abs(p.observation_angle - q.observation_angle) < 1e-5
        assert abs(p.observation_angle_variance - q.observation_angle_variance) < 1e-6


def _scene() -> np.ndarray:
    """Noise with a dark block (with ``score_threshold`` 0 every heat-map peak is a detection:
    100 of them)."""
    rgb = np.random.default_rng(3).integers(0, 255, (375, 1242, 3), dtype=np.uint8)
    rgb[200:300, 400:600] = (40, 40, 60)  # something box-like
    return rgb


@needs_ort
def test_numpy_sparse_part_gives_the_torch_modules_detections(tmp_path, shared_kitti):
    """On real KITTI frames, at the checkpoint's framing and at another camera's (whole image,
    another input size: the orientation head's geometry mapped), and at a low threshold."""
    from detector_node.inference import CnnDetector
    from vehicle_common.kitti import read_png

    cache = OnnxCache(tmp_path)
    for size, roi in (((0, 0), None), ((960, 576), 0.0)):
        fast = load_detector("", "cpu", 0.05, *size, threads=1, roi_top=roi, cache=cache)
        ref = CnnDetector.from_checkpoint(
            "", "cpu", 0.05, *size, runtime="onnxruntime", threads=1, roi_top=roi
        )
        assert type(fast).__name__ == "OnnxCenterNetDetector"
        for k in (0, 7, 15):
            rgb = read_png(shared_kitti / f"tracking/training/image_02/0005/{k:06d}.png")
            _same(fast.detect(rgb), ref.detect(rgb))
        fast.score_threshold = ref.score_threshold = 0.0  # every peak: 100 detections
        _same(fast.detect(_scene()), ref.detect(_scene()))


@needs_ort
def test_a_cached_detector_starts_without_torch_and_builds_nothing(tmp_path):
    cold = load_detector("", "cpu", 0.0, threads=1, cache=OnnxCache(tmp_path))
    cold.detect(_scene())
    assert sorted(cold.source.built) == ["ONNX graph 896x224", "checkpoint info"]
    code = (
        "import sys, numpy as np\n"
        "from detector_node.loading import load_detector\n"
        "d = load_detector('', 'cpu', 0.0, threads=1)\n"
        "dets = d.detect(np.zeros((375, 1242, 3), np.uint8))\n"
        "print(d.runtime, d.source.built, 'torch' in sys.modules, 'onnx' in sys.modules)\n"
    )
    env = {**os.environ, "VEHICLE_DETECTOR_CACHE": str(tmp_path)}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.split() == ["onnxruntime", "[]", "False", "False"]


@needs_ort
def test_new_weights_under_the_same_name_are_a_new_entry(tmp_path):
    """The key is the checkpoint's content: retrained weights saved over the old file are not
    served the old graph."""
    import torch
    from detector_node.checkpoint import SHIPPED_CHECKPOINT

    path = tmp_path / "mine.pt"
    path.write_bytes(SHIPPED_CHECKPOINT.read_bytes())
    cache = OnnxCache(tmp_path / "cache")
    before = load_detector(str(path), "cpu", 0.0, threads=1, cache=cache).detect(_scene())
    state = torch.load(path, weights_only=True)
    key = next(k for k in state["state_dict"] if k.startswith("heat.pointwise.bias"))
    state["state_dict"][key] = state["state_dict"][key] + 2.0  # every heat logit + 2
    torch.save(state, path)
    again = load_detector(str(path), "cpu", 0.0, threads=1, cache=cache)
    after = again.detect(_scene())
    assert sorted(again.source.built) == ["ONNX graph 896x224", "checkpoint info"]
    # the new weights' scores (logits + 2), not the cached graph's
    assert after[0].score == pytest.approx(
        1 / (1 + np.exp(-(np.log(before[0].score / (1 - before[0].score)) + 2))), rel=1e-4
    )
    assert len(list((tmp_path / "cache").glob("*-onnx896x224.npz"))) == 2


@needs_ort
def test_a_corrupt_entry_is_removed_and_rebuilt(tmp_path):
    cache = OnnxCache(tmp_path)
    good = load_detector("", "cpu", 0.0, threads=1, cache=cache).detect(_scene())
    (entry,) = tmp_path.glob("*-onnx896x224.npz")
    data = bytearray(entry.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one flipped byte inside the graph's weights
    entry.write_bytes(bytes(data))
    cache = OnnxCache(tmp_path)
    det = load_detector("", "cpu", 0.0, threads=1, cache=cache)
    _same(det.detect(_scene()), good)
    assert det.source.built == ["ONNX graph 896x224"]
    assert any("corrupt cache entry" in p for p in cache.problems)
    entry.write_bytes(b"not a zip file")
    cache = OnnxCache(tmp_path)
    _same(load_detector("", "cpu", 0.0, threads=1, cache=cache).detect(_scene()), good)
    assert any("corrupt cache entry" in p for p in cache.problems)


def test_concurrent_writers_and_readers_see_whole_entries_only(tmp_path):
    """Writers racing on one entry (os.replace of complete temporary files): a reader gets the
    entry whole or not at all, never a partial or mixed one, and no temporary file is left."""
    arrays = [{"onnx": np.full(2_000_000, i, np.uint8)} for i in range(4)]
    stop = threading.Event()
    seen, bad = [], []

    def write(i):
        cache = OnnxCache(tmp_path)
        for _ in range(5):
            assert cache.write("entry", arrays[i])

    def read():
        cache = OnnxCache(tmp_path)
        while not stop.is_set():
            got = cache.read("entry")
            if got is None:
                continue
            values = np.unique(got["onnx"])
            (seen if len(values) == 1 and got["onnx"].size == 2_000_000 else bad).append(values)
            if cache.problems:
                bad.append(cache.problems)

    readers = [threading.Thread(target=read) for _ in range(2)]
    writers = [threading.Thread(target=write, args=(i,)) for i in range(4)]
    for t in readers + writers:
        t.start()
    for t in writers:
        t.join()
    stop.set()
    for t in readers:
        t.join()
    assert not bad and seen
    assert [p.name for p in tmp_path.iterdir()] == ["entry.npz"]


def test_cache_folder_and_pruning(tmp_path, monkeypatch):
    assert cache_dir({"VEHICLE_DETECTOR_CACHE": "off"}) is None
    assert cache_dir({"VEHICLE_DETECTOR_CACHE": str(tmp_path)}) == tmp_path
    assert cache_dir({"XDG_CACHE_HOME": "/x"}) == __import__("pathlib").Path(
        "/x/stereo_vehicle_tracking/detector"
    )
    cache = OnnxCache(tmp_path)
    for i in range(MAX_ENTRIES + 3):
        assert cache.write(f"e{i}", {"a": np.arange(3)})
        os.utime(tmp_path / f"e{i}.npz", (i, i))  # e0 oldest
    cache.write("last", {"a": np.arange(3)})
    names = {p.stem for p in tmp_path.glob("*.npz")}
    assert len(names) == MAX_ENTRIES and "last" in names and "e0" not in names
    # a folder that cannot be written: no cache, the problem said once per attempt
    blocked = tmp_path / "file"
    blocked.write_text("")
    nowhere = OnnxCache(blocked / "sub")
    assert not nowhere.write("x", {"a": np.arange(3)}) and nowhere.read("x") is None
    assert "cannot write the detector cache" in nowhere.problems[0]
