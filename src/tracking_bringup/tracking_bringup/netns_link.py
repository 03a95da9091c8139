"""Two "hosts" on one machine: two Linux network namespaces joined by a veth pair.

Used by the multi-host test and benchmark to run parts of the graph in separate network stacks,
so that their DDS traffic crosses a real (virtual) Ethernet link whose bytes can be counted and
which can be cut (link down/up) or degraded (``tc netem``). The namespaces, the link and its
addresses (a private /24 that exists only inside the two namespaces) are made by
:meth:`NetnsPair.create` and removed by :meth:`NetnsPair.destroy`; nothing on the machine's own
network is touched. Needs root and iproute2 (``ip``; ``tc`` for netem).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

IP = shutil.which("ip") or "/usr/sbin/ip"
TC = shutil.which("tc") or "/usr/sbin/tc"


class NetnsError(RuntimeError):
    """A namespace, link or qdisc command that failed (the message holds the command)."""


def _run(argv: list[str]) -> str:
    proc = subprocess.run(argv, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise NetnsError(f"{' '.join(argv)}: {proc.stderr.strip() or proc.returncode}")
    return proc.stdout


def namespaces_unavailable() -> str | None:
    """Why network namespaces cannot be made here (None when they can)."""
    if os.geteuid() != 0:
        return "network namespaces need root (run the test as root)"
    if not os.path.exists(IP):
        return "iproute2 'ip' not found"
    probe = f"stkprobe{os.getpid()}"
    try:
        _run([IP, "netns", "add", probe])
    except NetnsError as exc:
        return f"cannot create a network namespace: {exc}"
    with contextlib.suppress(NetnsError):
        _run([IP, "netns", "del", probe])
    return None


@dataclass
class NetnsPair:
    """Namespaces ``a`` and ``b``, veth ends ``veth_a`` (in a) and ``veth_b`` (in b) with the
    addresses ``addr_a`` and ``addr_b`` of ``subnet``.{1,2}/24, loopback up in both."""

    tag: str = field(default_factory=lambda: str(os.getpid()))
    subnet: str = "10.213.7"

    def __post_init__(self) -> None:
        self.a, self.b = f"stk{self.tag}a", f"stk{self.tag}b"
        self.veth_a, self.veth_b = f"vstk{self.tag}a"[:15], f"vstk{self.tag}b"[:15]
        self.addr_a, self.addr_b = f"{self.subnet}.1", f"{self.subnet}.2"
        self._made: list[str] = []

    def create(self) -> NetnsPair:
        try:
            for ns in (self.a, self.b):
                _run([IP, "netns", "add", ns])
                self._made.append(ns)
            _run([IP, "link", "add", self.veth_a, "type", "veth", "peer", "name", self.veth_b])
            for ns, dev, addr in (
                (self.a, self.veth_a, self.addr_a),
                (self.b, self.veth_b, self.addr_b),
            ):
                _run([IP, "link", "set", dev, "netns", ns])
                _run([IP, "-n", ns, "addr", "add", f"{addr}/24", "dev", dev])
                _run([IP, "-n", ns, "link", "set", dev, "up"])
                _run([IP, "-n", ns, "link", "set", "lo", "up"])
                # multicast (DDS "subnet" discovery) leaves through the link
                _run([IP, "-n", ns, "route", "add", "224.0.0.0/4", "dev", dev])
        except NetnsError:
            self.destroy()
            raise
        return self

    def destroy(self) -> None:
        """Delete both namespaces (which deletes the veth pair). Idempotent."""
        for ns in self._made:
            subprocess.run([IP, "netns", "del", ns], capture_output=True, check=False)
        self._made = []

    def __enter__(self) -> NetnsPair:
        return self.create()

    def __exit__(self, *exc) -> None:
        self.destroy()

    def command(self, ns: str, argv: list[str]) -> list[str]:
        """``argv`` run inside namespace ``ns`` (the environment passes through)."""
        return [IP, "netns", "exec", ns, *argv]

    def _dev(self, ns: str) -> str:
        return self.veth_a if ns == self.a else self.veth_b

    def link_bytes(self, ns: str) -> dict[str, int]:
        """Bytes and packets sent and received by the veth end in ``ns`` so far."""
        info = json.loads(_run([IP, "-n", ns, "-s", "-j", "link", "show", self._dev(ns)]))[0]
        stats = info["stats64"]
        return {
            "tx_bytes": int(stats["tx"]["bytes"]),
            "rx_bytes": int(stats["rx"]["bytes"]),
            "tx_packets": int(stats["tx"]["packets"]),
            "rx_packets": int(stats["rx"]["packets"]),
        }

    def set_link(self, up: bool) -> None:
        """Take the link down or up (both ends)."""
        for ns in (self.a, self.b):
            _run([IP, "-n", ns, "link", "set", self._dev(ns), "up" if up else "down"])

    def qdisc(self, ns: str, *args: str) -> None:
        """Set (or with no args remove) the root qdisc of the veth end in ``ns``, e.g.
        ``qdisc(a, "tbf", "rate", "1gbit", "burst", "256k", "latency", "10ms")`` for a gigabit
        link. (``netem`` needs the sch_netem kernel module, which not every kernel has.)"""
        dev = self._dev(ns)
        if args:
            _run([IP, "netns", "exec", ns, TC, "qdisc", "replace", "dev", dev, "root", *args])
        else:
            subprocess.run(
                [IP, "netns", "exec", ns, TC, "qdisc", "del", "dev", dev, "root"],
                capture_output=True,
                check=False,
            )

    def udp_errors(self, ns: str) -> dict[str, int]:
        """The UDP error counters of namespace ``ns`` (/proc/net/snmp): datagrams dropped for a
        full receive buffer (RcvbufErrors) or send buffer (SndbufErrors)."""
        lines = [
            ln.split()
            for ln in _run([IP, "netns", "exec", ns, "cat", "/proc/net/snmp"]).splitlines()
            if ln.startswith("Udp:")
        ]
        table = dict(zip(lines[0][1:], (int(v) for v in lines[1][1:]), strict=True))
        return {k: table.get(k, 0) for k in ("InErrors", "RcvbufErrors", "SndbufErrors")}


def launch_command(*args: str) -> list[str]:
    """``stereo_tracking_launch`` of this interpreter's environment with ``args``."""
    from tracking_bringup.launcher import resolve_executable

    return [resolve_executable("stereo_tracking_launch"), *args]


def run_two_host_graph(
    pair: NetnsPair,
    launch_args: list[str],
    log_dir: str | os.PathLike,
    timeout: float = 300.0,
    during=None,
) -> dict:
    """The lockstep graph split over the pair by the host profiles of the parameter file
    (``launch_args`` must name one that has them, e.g. the shipped one, with ``--params``):
    ``--host compute`` (detector, stereo depth) in b, ``--host camera`` (player, tracker,
    recorder) in a, each by its own ``stereo_tracking_launch`` with the other as static peer.
    Runs until the player is done (``during(pair)`` is called meanwhile, e.g. to cut the link),
    then stops host b. Returns the exit codes, the bytes a sent and received on the link, and
    the wall time."""
    log_dir = Path(log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    compute_cmd = launch_command(
        "--host", "compute", "--peers", pair.addr_a, "--log-dir", str(log_dir / "b"), *launch_args
    )
    camera_cmd = launch_command(
        "--host", "camera", "--peers", pair.addr_b, "--log-dir", str(log_dir / "a"), *launch_args
    )
    before = pair.link_bytes(pair.a)
    t0 = time.monotonic()
    with (
        open(log_dir / "launch_b.out", "wb") as out_b,
        open(log_dir / "launch_a.out", "wb") as out_a,
    ):
        compute = subprocess.Popen(
            pair.command(pair.b, compute_cmd), stdout=out_b, stderr=subprocess.STDOUT
        )
        try:
            camera = subprocess.Popen(
                pair.command(pair.a, camera_cmd), stdout=out_a, stderr=subprocess.STDOUT
            )
            try:
                if during is not None:
                    during(pair)
                camera_code = camera.wait(timeout=timeout)
            finally:
                if camera.poll() is None:
                    camera.send_signal(2)
                    camera.wait(timeout=60)
        finally:
            compute.send_signal(2)  # SIGINT: the launcher stops its nodes cleanly
            compute_code = compute.wait(timeout=60)
    elapsed = time.monotonic() - t0
    after = pair.link_bytes(pair.a)
    return {
        "camera_exit": camera_code,
        "compute_exit": compute_code,
        "tx_bytes": after["tx_bytes"] - before["tx_bytes"],
        "rx_bytes": after["rx_bytes"] - before["rx_bytes"],
        "wall_s": elapsed,
    }


def cut_link_after(log: Path, marker: str, seconds: float, cut: dict):
    """A ``during`` callback for run_two_host_graph: once ``marker`` is in ``log`` (e.g. the
    player's "frame 9:"), take the link down for ``seconds``; times go into ``cut``."""

    def during(pair: NetnsPair) -> None:
        def worker() -> None:
            deadline = time.monotonic() + 300
            while time.monotonic() < deadline:
                if log.is_file() and marker in log.read_text():
                    break
                time.sleep(0.02)
            pair.set_link(False)
            cut["down"] = time.monotonic()
            time.sleep(seconds)
            pair.set_link(True)
            cut["up"] = time.monotonic()

        threading.Thread(target=worker, daemon=True).start()

    return during


def frame_latencies(bag: Path) -> list[float]:
    """Per frame of a lockstep run's bag: ground truth received -> tracks received by the
    recorder (s), both on the camera host: the graph's latency for one frame, link included."""
    from rosbags.highlevel import AnyReader

    seen: dict[str, dict[int, int]] = {"/kitti/ground_truth": {}, "/vehicles/tracks": {}}
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic in seen]
        for conn, t, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            seen[conn.topic][stamp] = t
    gt, tracks = seen["/kitti/ground_truth"], seen["/vehicles/tracks"]
    return [(tracks[k] - gt[k]) / 1e9 for k in sorted(gt) if k in tracks]
