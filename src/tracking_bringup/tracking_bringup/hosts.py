"""Which nodes of the graph run on which host: host profiles in the parameter file.

A host profile names the nodes one host starts, and optionally its discovery settings. The
profiles live in the parameter file under the launcher's own section (a node name no process
uses, so every node ignores it)::

    stereo_tracking_launch:
      ros__parameters:
        hosts:
          camera:                      # stereo_tracking_launch --host camera
            nodes: ["kitti_player", "vehicle_tracker", "bag_recorder"]
            discovery: "peers"         # localhost | subnet | peers
            peers: ["10.0.0.2"]        # the other host(s)
          compute:
            nodes: ["vehicle_detector", "stereo_depth"]
            discovery: "peers"
            peers: ["10.0.0.1"]
        image_transport: "jpeg"        # the images on the link: raw | png | jpeg

The whole graph is the union of the profiles' nodes: the player waits for the subscriptions of
every node in it, wherever it runs, before its first frame. ``image_transport`` (optional)
becomes the player's parameter on every host started with ``--host``, so that the launchers on
both sides agree on the image topics (the consumers' ``image_transport`` follows the player's:
graph.plan).
"""

from __future__ import annotations

from dataclasses import dataclass

from vehicle_common.image_transport import PLAYER_TRANSPORTS

from tracking_bringup import graph
from tracking_bringup.dds import DISCOVERY_MODES, MULTIHOST_SETTLE_TIME, DiscoverySettings
from tracking_bringup.parameter_file import (
    LAUNCH_SECTION,
    Files,
    ParameterFileError,
    as_files,
    describe,
    read_file,
)


class HostProfileError(ValueError):
    """A host profile that is missing or malformed (the message names the field)."""


@dataclass(frozen=True)
class HostProfile:
    """The nodes one host runs and how its participants discover the other hosts."""

    name: str
    nodes: tuple[str, ...]
    discovery: str | None = None
    peers: tuple[str, ...] = ()


def _launch_section(params_file: Files) -> dict:
    """The launcher's section (``stereo_tracking_launch.ros__parameters``) of the file; of
    several files (``parameter_file.layers``) the first's updated key by key by the later."""
    out = {}
    for path in as_files(params_file):
        try:
            data = read_file(path)
        except ParameterFileError as exc:
            raise HostProfileError(str(exc)) from None
        out.update((data.get(LAUNCH_SECTION) or {}).get("ros__parameters") or {})
    return out


def read_image_transport(params_file: Files) -> str | None:
    """The host profiles' ``image_transport`` (None when not given)."""
    value = _launch_section(params_file).get("image_transport")
    if value is not None and value not in PLAYER_TRANSPORTS:
        raise HostProfileError(
            f"{describe(params_file)}: {LAUNCH_SECTION}.ros__parameters.image_transport: "
            f"{value!r} is not one of {', '.join(PLAYER_TRANSPORTS)}"
        )
    return value


def read_host_profiles(params_file: Files) -> dict[str, HostProfile]:
    """Every host profile of ``params_file`` (empty when it defines none)."""
    section = _launch_section(params_file)
    hosts = section.get("hosts") or {}
    where = f"{describe(params_file)}: {LAUNCH_SECTION}.ros__parameters.hosts"
    if not isinstance(hosts, dict):
        raise HostProfileError(f"{where}: expected a mapping of host names")
    known = {n.name for n in graph.PIPELINE}
    profiles = {}
    for name, body in hosts.items():
        if not isinstance(body, dict):
            raise HostProfileError(f"{where}.{name}: expected a mapping with 'nodes'")
        nodes = body.get("nodes")
        if not isinstance(nodes, list) or not nodes or not all(isinstance(n, str) for n in nodes):
            raise HostProfileError(f"{where}.{name}.nodes: expected a non-empty list of names")
        unknown = [n for n in nodes if n not in known]
        if unknown:
            raise HostProfileError(
                f"{where}.{name}.nodes: unknown node(s) {', '.join(unknown)}; "
                f"known: {', '.join(sorted(known))}"
            )
        peers = body.get("peers") or []
        if not isinstance(peers, list) or not all(isinstance(p, str) for p in peers):
            raise HostProfileError(f"{where}.{name}.peers: expected a list of addresses")
        discovery = body.get("discovery")
        if discovery is not None and not isinstance(discovery, str):
            raise HostProfileError(f"{where}.{name}.discovery: expected a string")
        profiles[str(name)] = HostProfile(str(name), tuple(nodes), discovery, tuple(peers))
    return profiles


def host_profile(params_file: Files, name: str) -> tuple[HostProfile, list[str]]:
    """The profile ``name`` and the whole graph's node names (the union of all profiles, in
    data-flow order)."""
    profiles = read_host_profiles(params_file)
    if name not in profiles:
        have = ", ".join(profiles) or "none"
        raise HostProfileError(
            f"{describe(params_file)}: no host profile {name!r} in "
            f"{LAUNCH_SECTION}.ros__parameters.hosts (defined: {have})"
        )
    union = {n for p in profiles.values() for n in p.nodes}
    return profiles[name], [n.name for n in graph.PIPELINE if n.name in union]


@dataclass(frozen=True)
class LaunchPlan:
    """What one launcher starts (``nodes``), the whole graph across hosts (``graph_nodes``,
    whose subscriptions the player waits for) and the DDS settings."""

    nodes: list[str] | None
    graph_nodes: list[str] | None
    discovery: DiscoverySettings
    image_transport: str | None = None  # of the host profiles: the player's, on every host

    @property
    def overrides(self) -> list[str]:
        """Parameter overrides the plan implies (before the user's ``-p``, which win): across
        hosts the player lets discovery settle before its first frame; the host profiles'
        ``image_transport`` is the player's (also where it runs elsewhere: the consumers'
        follows it); the image consumers subscribe RELIABLE when the graph's player runs on
        another host."""
        player = graph.PLAYER.name
        out = []
        if self.discovery.multihost and (self.nodes is None or player in self.nodes):
            out.append(f"{player}.match_settle_time:={MULTIHOST_SETTLE_TIME}")
        if self.image_transport is not None:
            out.append(f"{player}.image_transport:={self.image_transport}")
        if self.graph_nodes and player in self.graph_nodes and self.nodes:
            # the graph's player on another host: lockstep loses no frame (graph.plan)
            out += [
                f"{n}.camera_reliability:=reliable"
                for n in graph.IMAGE_CONSUMERS
                if n in self.nodes and player not in self.nodes
            ]
        return out


def add_arguments(parser) -> None:
    """The launcher's options for node subsets, host profiles and discovery."""
    parser.add_argument(
        "--host",
        help=f"host profile of the parameter file ({LAUNCH_SECTION}.ros__parameters.hosts.NAME): "
        "its nodes and discovery settings",
    )
    parser.add_argument(
        "--graph",
        help="comma-separated nodes of the whole graph across hosts, whose subscriptions the "
        "player waits for (default: the union of the host profiles with --host, else every node)",
    )
    parser.add_argument(
        "--discovery",
        choices=DISCOVERY_MODES,
        help="localhost (default: one host, shared memory), subnet (multicast on the local "
        "network) or peers (unicast to --peers); the last two use the UDP profile",
    )
    parser.add_argument("--peers", help="comma-separated addresses of the other hosts")
    parser.add_argument("--transport-profile", help="Fast DDS XML profile instead of the default")


def _names(text: str | None) -> list[str] | None:
    return [n.strip() for n in text.split(",") if n.strip()] if text else None


def launch_plan(args) -> LaunchPlan:
    """The plan of the parsed options (``args.params``, ``args.nodes`` and those of
    :func:`add_arguments`); raises ValueError (HostProfileError, DdsSettingsError) with one
    line naming the option or field at fault."""
    nodes, graph_nodes = _names(args.nodes), _names(args.graph)
    discovery, peers = args.discovery, _names(args.peers)
    transport = None
    if args.host:
        transport = read_image_transport(args.params)
        if nodes:
            raise HostProfileError("--nodes and --host: give one of them")
        profile, union = host_profile(args.params, args.host)
        nodes = list(profile.nodes)
        graph_nodes = graph_nodes or union
        discovery = discovery or profile.discovery
        peers = peers if peers is not None else list(profile.peers)
    if graph_nodes is not None:
        graph.by_name(graph_nodes)  # unknown names: ValueError naming them
        missing = [n for n in nodes or [] if n not in graph_nodes]
        if missing:
            raise HostProfileError(
                f"--graph: does not hold the started node(s) {', '.join(missing)}"
            )
    settings = DiscoverySettings(
        mode=discovery or ("peers" if peers else "localhost"),
        peers=tuple(peers or ()),
        profile=args.transport_profile,
    )
    return LaunchPlan(
        nodes=nodes, graph_nodes=graph_nodes, discovery=settings, image_transport=transport
    )
