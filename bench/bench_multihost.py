"""What the graph costs on the wire between two hosts, measured on two network namespaces joined
by a veth pair (tracking_bringup.netns_link; needs root and iproute2).

Usage: sudo .venv/bin/python bench/bench_multihost.py [link|graph|transport|all] [--frames N]
       [--kitti-root DIR --sequence 0005 --detector oracle] [--outage S] [--profile NAME=XML]

``link``: 10 Hz stereo (two 1242x375 rgb8 images per frame, as the player publishes them) from
"host" a to "host" b, reliable QoS depth 5 as in the graph, for each transport profile (Fast DDS
built-in transports; the project's multi-host UDP profile; the latter with the LOCALHOST
discovery range) on the plain veth and on a 1 Gbit/s link (``tc tbf``; this kernel has no
netem): pairs delivered, latency (publish -> both images received; one clock, same machine),
bytes/s on the link, bytes sent per payload byte, datagrams dropped by a full receive buffer.
``graph``: the lockstep graph on one host (in namespace a) and split over the two hosts (player,
tracker, recorder on a; detector and stereo depth on b), and once more with the link down for
``--outage`` seconds after frame 9: frames tracked, per-frame latency (ground truth -> tracks at
the recorder), bytes per frame on the link.
``transport`` (not in ``all``): the graph split over the two hosts once per image transport of
the player (raw, png, jpeg q=90, jpeg q=75; the consumers follow, graph.plan): frames tracked,
per-frame latency, bytes per frame on the link and the link's rate at 10 Hz, CPU seconds of
both hosts' processes (with the load average), and the tracks' CLEAR-MOT/HOTA and 3D AP from
the recorded bag (evaluate bag) beside raw's.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tracking_bringup.dds import MULTIHOST_PROFILE, DiscoverySettings
from tracking_bringup.netns_link import NetnsPair, namespaces_unavailable

WIDTH, HEIGHT = 1242, 375
TOPICS = ("/stereo/left/image_rect", "/stereo/right/image_rect")


# -- the two ends of the link probe (run inside the namespaces) ----------------------------------


def _publisher(frames: int, hz: float) -> None:
    import numpy as np
    import rclpy
    from rclpy.duration import Duration
    from sensor_msgs.msg import Image

    rclpy.init()
    node = rclpy.create_node("link_probe_pub")
    pubs = [node.create_publisher(Image, t, 5) for t in TOPICS]
    deadline = time.monotonic() + 60
    while any(p.get_subscription_count() < 1 for p in pubs) and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    rng = np.random.default_rng(0)
    data = rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8).tobytes()  # incompressible
    t0 = time.monotonic()
    for k in range(frames):
        while time.monotonic() < t0 + k / hz:
            rclpy.spin_once(node, timeout_sec=max(0.0, t0 + k / hz - time.monotonic()))
        now = time.time_ns()
        for i, p in enumerate(pubs):
            msg = Image(height=HEIGHT, width=WIDTH, encoding="rgb8", step=WIDTH * 3, data=data)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 10**9)
            msg.header.frame_id = f"{k}:{i}"
            p.publish(msg)
    for p in pubs:
        p.wait_for_all_acked(Duration(seconds=10))
    rclpy.shutdown()


def _subscriber(frames: int, out: str) -> None:
    import rclpy
    from sensor_msgs.msg import Image

    rclpy.init()
    node = rclpy.create_node("link_probe_sub")
    arrived: dict[int, list[int]] = {}
    sent: dict[int, int] = {}

    def on_image(msg: Image) -> None:
        k = int(msg.header.frame_id.split(":")[0])
        sent[k] = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        arrived.setdefault(k, []).append(time.time_ns())

    for t in TOPICS:
        node.create_subscription(Image, t, on_image, 5)
    hard = time.monotonic() + 60 + frames / 10.0
    last = time.monotonic() + 60
    while (
        time.monotonic() < min(last, hard) and sum(len(v) == 2 for v in arrived.values()) < frames
    ):
        n = len(arrived)
        rclpy.spin_once(node, timeout_sec=0.1)
        if len(arrived) != n:
            last = time.monotonic() + 5  # 5 s after the last image: the rest is lost
    latency = [(max(v) - sent[k]) / 1e6 for k, v in arrived.items() if len(v) == 2]
    Path(out).write_text(json.dumps({"pairs": len(latency), "latency_ms": latency}))
    rclpy.shutdown()


# -- the benchmark -----------------------------------------------------------------------------


def _env(profile: str | None, peer: str, discovery_range: str) -> dict[str, str]:
    """The probe's DDS environment: the launcher's "peers" settings (SUBNET range + the other
    end as static peer), with ``profile`` (None: Fast DDS's built-in transports) and the
    discovery range ``discovery_range``."""
    env = DiscoverySettings("peers", (peer,)).environment()
    env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
    if profile:
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = profile
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = discovery_range
    return env


def link_run(
    pair: NetnsPair, profile: str | None, frames: int, discovery_range: str, hz: float = 10.0
) -> dict:
    """One probe run a -> b; returns delivery, latency and link bytes."""
    me = [sys.executable, str(Path(__file__).resolve())]
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "sub.json")
        sub = subprocess.Popen(
            pair.command(pair.b, [*me, "_sub", "--frames", str(frames), "--out", out]),
            env=_env(profile, pair.addr_a, discovery_range),
        )
        before = pair.link_bytes(pair.a)
        err0 = pair.udp_errors(pair.b)
        t0 = time.monotonic()
        pub = subprocess.run(
            pair.command(pair.a, [*me, "_pub", "--frames", str(frames), "--hz", str(hz)]),
            env=_env(profile, pair.addr_b, discovery_range),
            check=False,
            timeout=frames / hz + 120,
        )
        elapsed = time.monotonic() - t0
        after = pair.link_bytes(pair.a)
        err1 = pair.udp_errors(pair.b)
        try:
            sub.wait(timeout=90)
        except subprocess.TimeoutExpired:
            sub.kill()
            sub.wait()
        result = json.loads(Path(out).read_text()) if Path(out).is_file() else {"pairs": 0}
    lat = sorted(result.get("latency_ms", []))
    return {
        "publisher_exit": pub.returncode,
        "pairs": result["pairs"],
        "frames": frames,
        "latency_ms_median": statistics.median(lat) if lat else None,
        "latency_ms_p95": lat[int(0.95 * (len(lat) - 1))] if lat else None,
        "latency_ms_max": lat[-1] if lat else None,
        "tx_bytes": after["tx_bytes"] - before["tx_bytes"],
        "rx_bytes": after["rx_bytes"] - before["rx_bytes"],
        "wire_MB_per_s": (after["tx_bytes"] - before["tx_bytes"]) / (frames / hz) / 1e6,
        "elapsed_s": elapsed,
        "rcvbuf_drops": err1["RcvbufErrors"] - err0["RcvbufErrors"],
    }


LINKS = {
    "veth": (),
    "1 Gbit/s (tbf)": ("tbf", "rate", "1gbit", "burst", "256k", "latency", "20ms"),
}
#: name: (Fast DDS profile or None for the built-in transports, discovery range); the launcher's
#: "peers" mode is SUBNET + static peers; LOCALHOST + static peers is shown for the record
PROFILES = {
    "Fast DDS built-in": (None, "SUBNET"),
    "multihost profile": (str(MULTIHOST_PROFILE), "SUBNET"),
    "multihost, LOCALHOST": (str(MULTIHOST_PROFILE), "LOCALHOST"),
}


def bench_link(frames: int) -> None:
    payload = 2 * WIDTH * HEIGHT * 3
    print(f"\n10 Hz stereo, {frames} frames, {payload / 1e6:.2f} MB per pair, a -> b over veth")
    print(
        f"{'link':24s} {'profile':20s} {'pairs':>9s} {'lat med':>8s} {'p95':>8s} {'max':>8s} "
        f"{'MB/s wire':>9s} {'overhead':>8s} {'rcvbuf drops':>12s}"
    )
    with NetnsPair(tag=f"b{os.getpid() % 10000}") as pair:
        for link, netem in LINKS.items():
            for ns in (pair.a, pair.b):
                pair.qdisc(ns, *netem)
            for name, (profile, discovery_range) in PROFILES.items():
                r = link_run(pair, profile, frames, discovery_range)

                def fmt(v):
                    return f"{v:8.1f}" if v is not None else "     n/a"

                print(
                    f"{link:24s} {name:20s} {r['pairs']:4d}/{frames:<4d} "
                    f"{fmt(r['latency_ms_median'])} {fmt(r['latency_ms_p95'])} "
                    f"{fmt(r['latency_ms_max'])} {r['wire_MB_per_s']:9.2f} "
                    f"{r['tx_bytes'] / max(1, r['pairs'] * payload):8.3f} {r['rcvbuf_drops']:12d}",
                    flush=True,
                )


def _graph_data(tmp: str, frames: int, kitti_root: str | None, sequence: str, backend: str):
    """(dataset root, sequence, launcher arguments) of a lockstep run of ``frames`` frames: the
    KITTI root's sequence, or a synthetic one written into ``tmp``."""
    from tracking_bringup.environment import PARAMS_FILE

    if kitti_root:
        root = Path(kitti_root)
    else:
        from kitti_player_node.synthetic import generate_sequence

        root, sequence = Path(tmp) / "data", "0000"
        generate_sequence(root, sequence=sequence, frames=frames, seed=3)
    args = ["--params", str(PARAMS_FILE)]
    for p in (
        f"kitti_player.dataset_root:={root}",
        f"kitti_player.sequence:='{sequence}'",
        f"kitti_player.last_frame:={frames - 1}",
        "kitti_player.lockstep:=true",
        f"vehicle_detector.backend:={backend}",
    ):
        args += ["-p", p]
    return root, sequence, args


def bench_graph(
    frames: int,
    kitti_root: str | None,
    sequence: str,
    backend: str,
    outage: float,
    transport_profile: str | None = None,
) -> None:
    from tracking_bringup.netns_link import (
        cut_link_after,
        frame_latencies,
        launch_command,
        run_two_host_graph,
    )

    with tempfile.TemporaryDirectory() as tmp:
        root, sequence, args = _graph_data(tmp, frames, kitti_root, sequence, backend)
        two = ["--transport-profile", transport_profile] if transport_profile else []
        print(f"\nlockstep graph, {sequence} ({frames} frames, {backend} detector)")
        print(f"{'run':28s} {'frames':>6s} {'frame latency med':>18s} {'max':>7s} {'MB/frame':>9s}")
        with NetnsPair(tag=f"g{os.getpid() % 10000}") as pair:
            bag1 = Path(tmp) / "bag_one"
            one = args + ["-p", f"bag_recorder.output:={bag1}", "--log-dir", f"{tmp}/logs1"]
            subprocess.run(pair.command(pair.a, launch_command(*one)), check=True, timeout=900)
            bag2 = Path(tmp) / "bag_two"
            result = run_two_host_graph(
                pair,
                [*args, *two, "-p", f"bag_recorder.output:={bag2}"],
                Path(tmp) / "logs2",
                timeout=900,
            )
            runs = [
                ("one host (shared memory)", bag1, None),
                ("two hosts (veth, UDP)", bag2, result),
            ]
            if outage > 0:
                bag3, logs3, cut = Path(tmp) / "bag_cut", Path(tmp) / "logs3", {}
                during = cut_link_after(logs3 / "a" / "kitti_player.log", "frame 9:", outage, cut)
                res3 = run_two_host_graph(
                    pair,
                    [*args, *two, "-p", f"bag_recorder.output:={bag3}"],
                    logs3,
                    timeout=900,
                    during=during,
                )
                summary = [
                    ln.split("]: ")[-1]
                    for ln in (logs3 / "a" / "kitti_player.log").read_text().splitlines()
                    if "done:" in ln
                ]
                print(f"link down {outage:.1f} s after frame 9: player {summary}")
                runs.append((f"two hosts, {outage:.0f} s outage", bag3, res3))
            for name, bag, wire in runs:
                lat = sorted(frame_latencies(bag))
                mb = (
                    f"{(wire['tx_bytes'] + wire['rx_bytes']) / frames / 1e6:9.2f}"
                    if wire
                    else "        -"
                )
                print(
                    f"{name:28s} {len(lat):6d} {statistics.median(lat):18.3f} {lat[-1]:7.3f} {mb}",
                    flush=True,
                )


TRANSPORTS = {
    "raw": ["kitti_player.image_transport:=raw"],
    "png": ["kitti_player.image_transport:=png"],
    "jpeg q=90": ["kitti_player.image_transport:=jpeg", "kitti_player.jpeg_quality:=90"],
    "jpeg q=75": ["kitti_player.image_transport:=jpeg", "kitti_player.jpeg_quality:=75"],
}


def bench_transport(frames: int, kitti_root: str | None, sequence: str, backend: str) -> None:
    """The split graph once per image transport (see the module docstring)."""
    import resource

    from eval_node.bag_evaluation import evaluate_bag
    from tracking_bringup.netns_link import frame_latencies, run_two_host_graph

    with tempfile.TemporaryDirectory() as tmp:
        root, sequence, args = _graph_data(tmp, frames, kitti_root, sequence, backend)
        print(
            f"\nlockstep graph over two hosts, {sequence} ({frames} frames, {backend} detector), "
            f"load average {os.getloadavg()[0]:.2f}"
        )
        print(
            f"{'images':10s} {'frames':>6s} {'latency med':>11s} {'max':>6s} {'MB/frame':>8s} "
            f"{'Mbit/s@10Hz':>11s} {'CPU s':>6s} {'MOTA':>6s} {'HOTA':>6s} "
            f"{'tracks AP@1.5m mod':>18s}"
        )
        labels = root / "label_02"
        with NetnsPair(tag=f"t{os.getpid() % 10000}") as pair:
            for name, extra in TRANSPORTS.items():
                bag = Path(tmp) / f"bag_{name.replace(' ', '_')}"
                cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
                wire = run_two_host_graph(
                    pair,
                    [
                        *args,
                        *[a for e in extra for a in ("-p", e)],
                        "-p",
                        f"bag_recorder.output:={bag}",
                    ],
                    Path(tmp) / f"logs_{name.replace(' ', '_')}",
                    timeout=900,
                )
                cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
                cpu = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
                lat = sorted(frame_latencies(bag))
                res = evaluate_bag(
                    bag,
                    labels_dir=labels if labels.is_dir() else None,
                    sequence=sequence,
                    run_filters=False,
                )
                per_frame = (wire["tx_bytes"] + wire["rx_bytes"]) / frames
                print(
                    f"{name:10s} {len(lat):6d} {statistics.median(lat):11.3f} {lat[-1]:6.3f} "
                    f"{per_frame / 1e6:8.2f} {per_frame * 8 * 10 / 1e6:11.1f} {cpu:6.1f} "
                    f"{100 * res['tracking']['mota']:6.1f} {100 * res['tracking']['hota']:6.1f} "
                    f"{100 * res['tracks_3d']['1.5']['moderate']:18.1f}",
                    flush=True,
                )
        print(f"load average at the end {os.getloadavg()[0]:.2f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "what",
        nargs="?",
        default="all",
        choices=("link", "graph", "transport", "all", "_pub", "_sub"),
    )
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--hz", type=float, default=10.0)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    parser.add_argument("--kitti-root", help="graph: a KITTI tracking root instead of synthetic")
    parser.add_argument("--sequence", default="0005")
    parser.add_argument("--transport-profile", help="graph: Fast DDS profile of the two hosts")
    parser.add_argument("--outage", type=float, default=1.0, help="graph: link down (s), 0: no")
    parser.add_argument("--detector", default="cnn", choices=("cnn", "oracle"))
    parser.add_argument(
        "--profile",
        action="append",
        default=[],
        metavar="NAME=XML",
        help="link: compare this Fast DDS profile too (repeatable)",
    )
    args = parser.parse_args(argv)
    if args.what == "_pub":
        _publisher(args.frames, args.hz)
        return 0
    if args.what == "_sub":
        _subscriber(args.frames, args.out)
        return 0
    # a domain of its own: nothing else on the machine sees the benchmark's graphs
    os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 80))
    reason = namespaces_unavailable()
    if reason:
        print(f"error: {reason}", file=sys.stderr)
        return 2
    for item in args.profile:
        name, _, path = item.partition("=")
        PROFILES[name] = (path, "SUBNET")
    if args.what in ("link", "all"):
        bench_link(args.frames)
    frames = args.frames
    if args.kitti_root:
        seq = Path(args.kitti_root) / "image_02" / args.sequence
        frames = min(frames, len(list(seq.glob("*.png"))))
    if args.what == "transport":
        bench_transport(frames, args.kitti_root, args.sequence, args.detector)
    if args.what in ("graph", "all"):
        bench_graph(
            frames,
            args.kitti_root,
            args.sequence,
            args.detector,
            args.outage,
            args.transport_profile,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
