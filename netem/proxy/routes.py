"""netem's links: the directed links of a scenario, their models, and the inbound keys' routes.

Three classes of link, each directed (docs/architecture.md "Wire"): ``formation`` links
``i → j`` carry coordination states, ``report`` links ``i → 0`` the token reports and
``estimate`` links ``0 → i`` the leader's estimates (0 is the leader). Each class
belongs to one lockstep phase.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Literal

from formation import keys
from formation.events import Membership
from formation.keys import LEADER_ENDPOINT
from formation.scenario import Scenario
from formation.wire_size import WireSizes
from netem.links.air_network import AirNetwork, air_of
from netem.links.capacity_network import CapacityNetwork, network_of
from netem.links.models import LinkModel

LinkClass = Literal["formation", "report", "estimate"]
Phase = Literal["state", "report", "estimate"]
Link = tuple[LinkClass, int, int]  # (class, source, target)
Route = tuple[Phase, int, int]  # an inbound key's (phase, source, target)
PHASE_OF: dict[LinkClass, Phase] = {
    "formation": "state",
    "report": "report",
    "estimate": "estimate",
}
# The keys netem takes in (by their formation.keys function) and the phase of each.
INBOUND: dict[str, Phase] = {
    "agent_state": "state",
    "agent_report": "report",
    "leader_estimate_for": "estimate",
}


class Links:
    """Every link of a scenario with its model, and who sends to whom."""

    def __init__(self, scenario: Scenario, seed: int) -> None:
        self.agents = list(range(1, scenario.n + 1))
        # Who takes part at each epoch, from the scenario's events (None: everyone, always).
        self.team: Membership | None = None if scenario.membership.everyone else scenario.membership
        # The capacity queues (None: every link has infinite capacity), over virtual time.
        self.capacity: CapacityNetwork | None = (
            network_of(scenario) if scenario.network.capacity else None
        )
        self.sizes = WireSizes(scenario) if scenario.network.capacity else None  # [B] nominal
        self.air: AirNetwork | None = air_of(scenario, seed)  # the shared 802.11 channel
        ap = scenario.network.access_point
        self.access_point = None if ap is None else list(ap)  # [m] control links' leader end
        self.models: dict[Link, LinkModel] = {}
        self.in_links: dict[int, list[int]] = defaultdict(list)
        self.out_links: dict[int, list[int]] = defaultdict(list)
        for a, b in scenario.directed_links:
            a, b = int(a), int(b)
            self.models[("formation", a, b)] = LinkModel(
                scenario.formation_link_models(a, b), seed, a, b
            )
            self.out_links[a].append(b)
            self.in_links[b].append(a)
        for i in self.agents:
            self.models[("report", i, LEADER_ENDPOINT)] = LinkModel(
                scenario.control_link_models(i, "report"), seed, i, LEADER_ENDPOINT
            )
            self.models[("estimate", LEADER_ENDPOINT, i)] = LinkModel(
                scenario.control_link_models(i, "estimate"), seed, LEADER_ENDPOINT, i
            )

    def senders(self, phase: Phase, receiver: int) -> list[int]:
        """Who sends ``receiver`` a packet of ``phase`` each epoch."""
        if phase == "state":
            return self.in_links[receiver]
        if phase == "report":
            return self.agents
        return [LEADER_ENDPOINT]


def link_key(run_id: str, link: Link) -> str:
    """The key a link's packets are forwarded on in realtime (and named by in lockstep)."""
    cls, src, dst = link
    if cls == "formation":
        return keys.link_state(run_id, src, dst)
    if cls == "report":
        return keys.link_report(run_id, src)
    return keys.link_estimate(run_id, dst)


class Routes:
    """The route of each inbound key, parsed once per key."""

    def __init__(self, agents: list[int]) -> None:
        self.agents = frozenset(agents)
        self._routes: dict[str, Route | None] = {}

    def of(self, key: str) -> Route | None:
        """``(phase, source, target)`` of an inbound key; None if not ours.

        ``agent/<i>/state`` and ``agent/<i>/report`` come from ``i`` (target unused, 0);
        ``leader/estimate/<i>`` from the leader to ``i``.
        """
        if key not in self._routes:
            kind, _, args = keys.parse(key)
            phase = INBOUND.get(kind)
            route: Route | None = None
            if phase is not None and args[0].isdigit() and int(args[0]) in self.agents:
                agent = int(args[0])
                route = (
                    ("estimate", LEADER_ENDPOINT, agent)
                    if phase == "estimate"
                    else (phase, agent, 0)
                )
            self._routes[key] = route
        return self._routes[key]
