"""The graph across two "hosts": two network namespaces joined by a veth pair (made and removed
here; addresses only inside them). Player, tracker and recorder run in one, detector and stereo
depth in the other, each started by its own launcher with static-peer discovery and the UDP
profile. The lockstep run tracks every frame and records the same messages as the one-host run;
a one-second link outage is survived with nothing lost."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest
from tracking_bringup.environment import PARAMS_FILE
from tracking_bringup.netns_link import (
    NetnsPair,
    cut_link_after,
    frame_latencies,
    launch_command,
    namespaces_unavailable,
    run_two_host_graph,
)

from tracking_bringup import graph

pytestmark = pytest.mark.slow

SYNTH_FRAMES = 12
IMAGE_BYTES = 1242 * 375 * 3
#: images per frame on the link: the left one to the detector and to stereo depth (one unicast
#: copy per subscribing process), the right one to stereo depth
IMAGES_ON_LINK = 3
#: topics whose messages are a deterministic function of the frames (lockstep, one message per
#: frame): the bag of the two-host run must hold exactly the same ones as the one-host run
DETERMINISTIC = (
    graph.LEFT_INFO,
    graph.RIGHT_INFO,
    graph.GROUND_TRUTH,
    graph.CLOCK,
    graph.DETECTIONS_2D,
    graph.DETECTIONS_3D,
    graph.TRACKS,
    graph.TRACK_MARKERS,
)


@pytest.fixture(scope="module")
def netns_pair():
    reason = namespaces_unavailable()
    if reason:
        pytest.skip(f"two-host test needs network namespaces: {reason}")
    with NetnsPair() as pair:
        yield pair


@pytest.fixture(scope="module")
def synthetic_root(tmp_path_factory) -> Path:
    from kitti_player_node.synthetic import generate_sequence

    root = tmp_path_factory.mktemp("multihost_data")
    return generate_sequence(root, sequence="0000", frames=SYNTH_FRAMES, seed=3)


def _overrides(
    root: Path, sequence: str, bag: Path, backend: str, params: Path = PARAMS_FILE
) -> list[str]:
    pairs = [
        f"kitti_player.dataset_root:={root}",
        f"kitti_player.sequence:='{sequence}'",
        "kitti_player.lockstep:=true",
        "kitti_player.lockstep_timeout:=30.0",  # a loaded 2-core machine; a timeout is counted
        f"vehicle_detector.backend:={backend}",
        f"bag_recorder.output:={bag}",
    ]
    return ["--params", str(params), *[a for p in pairs for a in ("-p", p)]]


def _messages(bag: Path) -> dict[str, list[bytes]]:
    """Per topic, the recorded messages in order, in canonical CDR: deserialised and serialised
    again, since the publishers' CDR leaves alignment padding bytes uninitialised (two runs of
    the same message differ there and nowhere else)."""
    from rosbags.highlevel import AnyReader

    out: dict[str, list[bytes]] = {}
    with AnyReader([bag]) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            canonical = reader.typestore.serialize_cdr(msg, conn.msgtype)
            out.setdefault(conn.topic.lstrip("/"), []).append(bytes(canonical))  # relative names
    return out


def _one_host(tmp: Path, root: Path, sequence: str, backend: str) -> Path:
    bag = tmp / "bag_one_host"
    cmd = launch_command(
        "--log-dir", str(tmp / "logs_one"), *_overrides(root, sequence, bag, backend)
    )
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return bag


def _player_summary(log_dir: Path) -> tuple[int, int, int]:
    text = (log_dir / "a" / "kitti_player.log").read_text()
    m = re.search(r"done: (\d+) frames published, (\d+) dropped, (\d+) lockstep timeouts", text)
    assert m, text[-2000:]
    return int(m[1]), int(m[2]), int(m[3])


def _check_split_run(pair, tmp: Path, root: Path, sequence: str, frames: int, backend: str):
    bag = tmp / "bag_two_hosts"
    result = run_two_host_graph(pair, _overrides(root, sequence, bag, backend), tmp / "logs_two")
    assert result["camera_exit"] == 0, (tmp / "logs_two" / "launch_a.out").read_text()
    assert result["compute_exit"] == 0, (tmp / "logs_two" / "launch_b.out").read_text()
    assert _player_summary(tmp / "logs_two") == (frames, 0, 0)
    # the images really crossed the link (not shared memory), each copy once (no resending)
    payload = frames * IMAGES_ON_LINK * IMAGE_BYTES
    assert payload <= result["tx_bytes"] < 1.3 * payload, result
    two = _messages(bag)
    assert len(two[graph.TRACKS]) == frames  # every frame tracked
    one = _messages(_one_host(tmp, root, sequence, backend))
    for topic in DETERMINISTIC:
        assert len(two.get(topic, [])) == frames, topic
        assert two[topic] == one[topic], f"{topic}: two-host messages differ from one host"


def test_synthetic_sequence_split_over_two_hosts(netns_pair, synthetic_root, tmp_path):
    _check_split_run(netns_pair, tmp_path, synthetic_root, "0000", SYNTH_FRAMES, "cnn")


def test_kitti_0005_split_over_two_hosts(netns_pair, kitti_tracking_root, tmp_path):
    frames = len(list((kitti_tracking_root / "image_02" / "0005").glob("*.png")))
    _check_split_run(netns_pair, tmp_path, kitti_tracking_root, "0005", frames, "oracle")


def _compressed_payload(root: Path, sequence: str, transport: str, quality: int = 90) -> int:
    """Bytes of the compressed images that cross the link for the whole sequence (the left
    image once per subscribing process on the other host, the right one once)."""
    from vehicle_common.image_conversion import numpy_to_compressed
    from vehicle_common.kitti import TrackingSequence

    seq = TrackingSequence.open(root, sequence)
    total = 0
    for f in seq.frame_ids:
        left, right = seq.read_stereo(f)
        sizes = [len(numpy_to_compressed(img, transport, quality).data) for img in (left, right)]
        total += (IMAGES_ON_LINK - 1) * sizes[0] + sizes[1]
    return total


@pytest.mark.parametrize("transport", ["png", "jpeg"])
def test_compressed_images_over_two_hosts(netns_pair, synthetic_root, tmp_path, transport):
    """The multi-host profile's image_transport (here png or jpeg, in the parameter file's
    launcher section) reaches both hosts: the compressed images cross the link, each copy once,
    every frame is tracked; PNG is lossless, so the recorded outputs equal the one-host run
    with raw images."""
    params = tmp_path / "params.yaml"
    text = PARAMS_FILE.read_text()
    shipped = 'image_transport: "raw"  # multi-host'
    assert shipped in text
    params.write_text(text.replace(shipped, f'image_transport: "{transport}"  # multi-host'))
    bag = tmp_path / "bag_two_hosts"
    args = _overrides(synthetic_root, "0000", bag, "cnn", params)
    result = run_two_host_graph(netns_pair, args, tmp_path / "logs")
    assert result["camera_exit"] == 0, (tmp_path / "logs" / "launch_a.out").read_text()
    assert result["compute_exit"] == 0, (tmp_path / "logs" / "launch_b.out").read_text()
    assert _player_summary(tmp_path / "logs") == (SYNTH_FRAMES, 0, 0)
    payload = _compressed_payload(synthetic_root, "0000", transport)
    assert payload < 0.8 * SYNTH_FRAMES * IMAGES_ON_LINK * IMAGE_BYTES  # smaller than raw
    assert payload <= result["tx_bytes"] < 1.3 * payload, result
    two = _messages(bag)
    assert len(two[graph.TRACKS]) == SYNTH_FRAMES
    if transport == "png":
        one = _messages(_one_host(tmp_path, synthetic_root, "0000", "cnn"))
        for topic in DETERMINISTIC:
            assert two[topic] == one[topic], f"{topic}: PNG two-host messages differ from raw"


def test_link_down_for_one_second_recovers(netns_pair, synthetic_root, tmp_path):
    """The link goes down for 1 s mid-run: the reliable streams repair what was lost, lockstep
    resumes, every frame is tracked; the stall and any lockstep timeout are reported."""
    bag = tmp_path / "bag"
    log_a = tmp_path / "logs" / "a" / "kitti_player.log"
    cut: dict[str, float] = {}
    during = cut_link_after(log_a, "frame 9:", 1.0, cut)  # 10 frames out, 2 to go

    result = run_two_host_graph(
        netns_pair,
        _overrides(synthetic_root, "0000", bag, "oracle"),
        tmp_path / "logs",
        during=during,
    )
    assert "up" in cut, "the link was never cut"
    assert result["camera_exit"] == 0 and result["compute_exit"] == 0
    published, dropped, timeouts = _player_summary(tmp_path / "logs")
    assert (published, dropped) == (SYNTH_FRAMES, 0)
    tracks = _messages(bag)[graph.TRACKS]
    # every frame tracked, no lockstep timeout
    assert timeouts == 0 and len(tracks) >= SYNTH_FRAMES
    # the frame in flight waited for the link: the outage hit the data flow, and was repaired
    assert max(frame_latencies(bag)) >= 0.8
