"""Capacities as the scenario names them: ``[[network.capacity]]`` (netem: ``netem.links.capacity``).

Each entry is a rate-limited queue on one scope:

- ``scope = "link"``, ``link = [i, j]``: the directed link ``i → j`` (``0`` is the leader's
  end of a control link: ``[3, 0]`` is agent 3's reports, ``[0, 3]`` its estimates);
- ``scope = "radio"``, ``agent = i``: every out-link of ``i`` shares its transmitter
  (``agent = 0``: the leader's estimates);
- ``scope = "medium"``, ``medium = "ap"``, ``links = [[i, j], ...]`` or ``"control"``,
  ``"formation"``, ``"all"``: the named set of links shares one queue (an access point, a
  channel). A link is in at most one medium.

A packet passes the queues of its link, of its sender's radio and of its medium, in that
order, after its link's loss models passed it (as in ``tc``, where netem's loss acts before
its rate). Parameters follow ``tc``: ``rate_bps``, ``burst_bytes`` (0: ``netem rate``; more:
``tbf``'s bucket), ``limit_packets`` / ``limit_bytes``, ``overhead_bytes``, ``policy``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from formation.keys import LEADER_ENDPOINT

Link = tuple[int, int]
SELECTORS = ("control", "formation", "all")


class Capacity(BaseModel):
    """One queue: where it sits (``scope``) and how it serves (``tc``'s parameters)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    scope: Literal["link", "radio", "medium"]
    link: Link | None = None  # scope "link"
    agent: int | None = Field(None, ge=0)  # scope "radio"
    medium: str | None = Field(None, min_length=1)  # scope "medium": its name
    links: tuple[Link, ...] | Literal["control", "formation", "all"] = ()  # scope "medium"
    rate_bps: float = Field(gt=0.0)  # [bit/s]
    burst_bytes: int = Field(0, ge=0)  # [B] 0: netem rate; > 0: tbf's bucket
    limit_packets: int | None = Field(None, ge=1)
    limit_bytes: int | None = Field(None, ge=1)  # [B]
    overhead_bytes: int = Field(0, ge=0)  # [B] per packet
    policy: Literal["tail", "oldest"] = "tail"

    @field_validator("links", mode="before")
    @classmethod
    def _selector(cls, v: object) -> object:
        if isinstance(v, str) and v not in SELECTORS:
            raise ValueError(f"expected [[i, j], ...] or one of {', '.join(SELECTORS)}")
        return v

    @property
    def name(self) -> str:
        """The queue's name in records and reports: ``link 3->0``, ``radio 3``, ``medium ap``."""
        if self.scope == "link" and self.link is not None:
            return f"link {self.link[0]}->{self.link[1]}"
        if self.scope == "radio":
            return f"radio {self.agent}"
        return f"medium {self.medium}"


def all_links(n: int, formation_links: Iterable[Sequence[int]]) -> dict[str, list[Link]]:
    """The run's directed links by kind: ``formation`` (both ways of each edge) and ``control``."""
    formation = [(int(i), int(j)) for i, j in formation_links]
    control = [(i, LEADER_ENDPOINT) for i in range(1, n + 1)]
    control += [(LEADER_ENDPOINT, i) for i in range(1, n + 1)]
    return {"formation": formation, "control": control, "all": formation + control}


def members(entry: Capacity, links: dict[str, list[Link]]) -> list[Link]:
    """The directed links an entry's queue serves, from :func:`all_links`."""
    if entry.scope == "link":
        return [entry.link] if entry.link is not None else []
    if entry.scope == "radio":
        return [lk for lk in links["all"] if lk[0] == entry.agent]
    if isinstance(entry.links, str):
        return list(links[entry.links])
    return [(int(i), int(j)) for i, j in entry.links]


def queues_of(
    capacities: Sequence[Capacity], links: dict[str, list[Link]]
) -> dict[Link, tuple[int, ...]]:
    """Per directed link, the indices into ``capacities`` of its queues: link, radio, medium."""
    order = {"link": 0, "radio": 1, "medium": 2}
    out: dict[Link, list[int]] = {}
    for k, entry in enumerate(capacities):
        for lk in members(entry, links):
            out.setdefault(lk, []).append(k)
    return {
        lk: tuple(sorted(ks, key=lambda k: order[capacities[k].scope])) for lk, ks in out.items()
    }


def capacity_problems(
    capacities: Sequence[Capacity], n: int, formation_links: Iterable[Sequence[int]]
) -> list[tuple[str, object, str]]:
    """The first problem of ``network.capacity`` as ``(field, value, problem)``; ``[]`` when none."""
    links = all_links(n, formation_links)
    known = set(links["all"])
    media: dict[str, int] = {}
    radios: dict[int, int] = {}
    linked: dict[Link, int] = {}
    in_medium: dict[Link, str] = {}
    for k, c in enumerate(capacities):
        at = f"network.capacity[{k}]"
        wrong = _scope_fields(c)
        if wrong:
            return [(f"{at}.{wrong[0]}", wrong[1], wrong[2])]
        if c.scope == "link" and c.link is not None:
            if c.link not in known:
                return [(f"{at}.link", list(c.link), _not_a_link(c.link, n))]
            if c.link in linked:
                return [(f"{at}.link", list(c.link), f"link also limited by [{linked[c.link]}]")]
            linked[c.link] = k
        if c.scope == "radio" and c.agent is not None:
            if c.agent > n:
                return [
                    (
                        f"{at}.agent",
                        c.agent,
                        f"agent does not exist (agents are 1..{n}, 0 the leader's end)",
                    )
                ]
            if c.agent in radios:
                return [(f"{at}.agent", c.agent, f"radio also limited by [{radios[c.agent]}]")]
            radios[c.agent] = k
        if c.scope == "medium" and c.medium is not None:
            if c.medium in media:
                return [
                    (f"{at}.medium", c.medium, f"medium already defined by [{media[c.medium]}]")
                ]
            media[c.medium] = k
            for q, lk in enumerate(members(c, links)):
                if lk not in known:
                    return [(f"{at}.links[{q}]", list(lk), _not_a_link(lk, n))]
                if lk in in_medium:
                    return [
                        (
                            f"{at}.links[{q}]",
                            list(lk),
                            f"link already in medium {in_medium[lk]!r}; a link is in one medium",
                        )
                    ]
                in_medium[lk] = c.medium
    return []


def unknown_medium(capacities: Sequence[Capacity], name: str) -> str | None:
    """Why ``name`` names no medium (the media there are), or None when one has that name."""
    names = sorted(c.medium for c in capacities if c.scope == "medium" and c.medium)
    if name in names:
        return None
    return f"unknown medium; the media are {names}" if names else "unknown medium; none defined"


def _scope_fields(c: Capacity) -> tuple[str, object, str] | None:
    """A field the scope needs and lacks, or one it does not take: ``(field, value, problem)``."""
    need = {"link": "link", "radio": "agent", "medium": "medium"}[c.scope]
    if getattr(c, need) is None:
        return (need, None, f"scope {c.scope!r} needs {need}")
    for other in ("link", "agent", "medium"):
        if other != need and getattr(c, other) is not None:
            return (other, getattr(c, other), f"scope {c.scope!r} does not take {other}")
    if c.scope != "medium" and c.links:
        return ("links", c.links, f"scope {c.scope!r} does not take links (a medium's)")
    if c.scope == "medium" and not c.links:
        return (
            "links",
            [],
            "a medium needs links: [[i, j], ...] or one of " + ", ".join(SELECTORS),
        )
    return None


def _not_a_link(link: Link, n: int) -> str:
    return (
        "not a link of the run (formation links join neighbours; "
        f"control links are [i, 0] and [0, i], agents 1..{n})"
    )


__all__ = [
    "SELECTORS",
    "Capacity",
    "Link",
    "all_links",
    "capacity_problems",
    "members",
    "queues_of",
    "unknown_medium",
]
