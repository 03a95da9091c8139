"""DDS discovery and transport settings of the graph: one host (the default) or several hosts.

One host: discovery limited to this host (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) and the
shared-memory profile (``config/fastdds_profile.xml``), see :mod:`tracking_bringup.environment`.

Several hosts (``--discovery subnet`` or ``--discovery peers --peers A,B``): participants find
each other by multicast on the local subnet, and with "peers" also by unicast to a static list
of peer addresses (``ROS_STATIC_PEERS``: works across routers and on networks that filter
multicast), and exchange data through the UDP profile ``config/fastdds_multihost.xml`` (large
socket buffers so a 1.4 MB image pair is not dropped by the receiving socket; shared memory stays
on for processes on the same host). README, "Across machines", has the measured figures.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

from tracking_bringup.environment import CONFIG_DIR, graph_environment

MULTIHOST_PROFILE = CONFIG_DIR / "fastdds_multihost.xml"
DISCOVERY_MODES = ("localhost", "subnet", "peers")
#: RTPS well-known ports (DDS-RTPS 2.x, section 9.6.1.1): PB + DG * domain + offset
PORT_BASE, DOMAIN_GAIN, PARTICIPANT_GAIN = 7400, 250, 2
#: s the player waits after its subscriptions matched before frame 0, across hosts: a remote
#: volatile reader that matches the player's writer only after the first frame was sent drops it
#: (seen in 2 of 4 two-host runs without a wait; README, "Across machines")
MULTIHOST_SETTLE_TIME = 3.0
_PEER = re.compile(r"^[A-Za-z0-9_.:-]+$")


class DdsSettingsError(ValueError):
    """A discovery mode, peer address or profile that cannot be used."""


@dataclass(frozen=True)
class DiscoverySettings:
    """How the graph's DDS participants find each other and carry data.

    ``mode``: "localhost" (one host; shared memory), "subnet" (multicast discovery on the local
    network) or "peers" (unicast discovery of the hosts in ``peers`` as well, for networks that
    do not pass multicast).
    ``peers``: addresses or host names of the other hosts ("subnet" adds them as unicast peers
    too). ``profile``: the Fast DDS XML profile (default: the one of the mode).
    """

    mode: str = "localhost"
    peers: tuple[str, ...] = ()
    profile: str | None = None

    def __post_init__(self) -> None:
        if self.mode not in DISCOVERY_MODES:
            raise DdsSettingsError(
                f"discovery: {self.mode!r} is not one of {', '.join(DISCOVERY_MODES)}"
            )
        bad = [p for p in self.peers if not _PEER.match(p)]
        if bad:
            raise DdsSettingsError(f"peers: not an address or host name: {', '.join(bad)}")
        if self.mode == "peers" and not self.peers:
            raise DdsSettingsError(
                "peers: discovery 'peers' needs at least one peer address (--peers A,B)"
            )
        if self.mode == "localhost" and self.peers:
            raise DdsSettingsError("peers: given with discovery 'localhost' (use subnet or peers)")
        if self.profile is not None and not os.path.isfile(self.profile):
            raise DdsSettingsError(f"{self.profile}: Fast DDS profile file not found")

    @property
    def multihost(self) -> bool:
        return self.mode != "localhost"

    def environment(self, base: dict[str, str] | None = None) -> dict[str, str]:
        """``base`` (default: os.environ) with the DDS variables of these settings.

        "localhost" keeps what ``base`` already sets (as :func:`graph_environment` does); the
        multi-host modes set the discovery range, the static peers and the UDP profile
        explicitly, since an inherited one-host value would silently keep the hosts apart."""
        env = dict(os.environ if base is None else base)
        if self.multihost:
            # "peers" keeps the SUBNET range and adds the static peers: with LOCALHOST + static
            # peers, Fast DDS (Jazzy) sent every image twice over the link (measured: 2.07x the
            # payload on the wire against 1.03x; README, "Across machines"). The static peers
            # make discovery work where multicast does not pass.
            env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
            # AUTO: the publish mode of the XML profile (synchronous unless a profile paces)
            env.setdefault("RMW_FASTRTPS_PUBLICATION_MODE", "AUTO")
            env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(self.profile or MULTIHOST_PROFILE)
            if self.peers:
                env["ROS_STATIC_PEERS"] = ";".join(self.peers)
            else:
                env.pop("ROS_STATIC_PEERS", None)
        elif self.profile:
            env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(self.profile)
        return graph_environment(env)


def rtps_ports(domain_id: int, participants: int = 4) -> dict[str, list[int]]:
    """UDP ports DDS uses in ``domain_id`` (to open in a firewall): the multicast discovery
    port, and per participant index ``i`` (one per process on a host) its unicast discovery and
    unicast user-data ports."""
    if not 0 <= domain_id <= 232:
        raise DdsSettingsError(f"ROS_DOMAIN_ID: {domain_id} is not in 0..232")
    base = PORT_BASE + DOMAIN_GAIN * domain_id
    return {
        "multicast_discovery": [base],
        "multicast_user": [base + 1],
        "unicast_discovery": [base + 10 + PARTICIPANT_GAIN * i for i in range(participants)],
        "unicast_user": [base + 11 + PARTICIPANT_GAIN * i for i in range(participants)],
    }
