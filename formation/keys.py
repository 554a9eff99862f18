"""Key expressions of a run; every key string of the testbed is built here.

Other modules read keys with :func:`parse` but build none; ``tests/unit/formation/test_key_literals.py``
scans the product for key literals outside this module. All keys live under
``formation/<run_id>/``. Formation links are ``i → j``
between agents; control links join agent ``i`` and the leader (endpoint 0).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from typing import NamedTuple

ROOT = "formation"
LEADER_ENDPOINT = 0  # the leader's end of a control link: its receiver id, netem's link end


def prefix(run_id: str) -> str:
    return f"{ROOT}/{run_id}"


def everything(run_id: str) -> str:
    return f"{ROOT}/{run_id}/**"


# -- what senders publish (netem subscribes) ------------------------------------------------
def agent_state(run_id: str, i: int | str) -> str:
    """Agent ``i``'s coordination packet ``x_i[k]`` (before netem)."""
    return f"{ROOT}/{run_id}/agent/{i}/state"


def agent_report(run_id: str, i: int | str) -> str:
    """Agent ``i``'s token report to the leader (before netem)."""
    return f"{ROOT}/{run_id}/agent/{i}/report"


def pool_bundle(run_id: str, pool: int | str, phase: str) -> str:
    """Lockstep: the messages of ``phase`` (``report``) of every agent of pool ``pool`` (its
    first agent's id) as one :class:`Bundle`; netem takes each part as if it came on
    :func:`agent_report`."""
    return f"{ROOT}/{run_id}/agent/pool/{pool}/{phase}"


def pool_states(run_id: str, pool: int | str) -> str:
    """Lockstep: the states of every agent of pool ``pool`` (its first agent's id) as one
    :class:`Bundle` an epoch; netem takes each part as if it came on :func:`agent_state`."""
    return f"{ROOT}/{run_id}/agent/pool/{pool}/state"


def leader_estimate_out(run_id: str) -> str:
    """The leader's whole estimate, for the recorder and observers (netem does not forward it)."""
    return f"{ROOT}/{run_id}/leader/estimate"


def leader_estimate_for(run_id: str, i: int | str) -> str:
    """What agent ``i`` uses of the estimate (before netem, which forwards it on link ``0 → i``)."""
    return f"{ROOT}/{run_id}/leader/estimate/{i}"


def leader_estimates(run_id: str) -> str:
    """Lockstep: every agent's part of the leader's estimate as one :class:`Bundle` (netem
    forwards each part on its link ``0 → i`` as if it came on :func:`leader_estimate_for`)."""
    return f"{ROOT}/{run_id}/leader/estimates"


# -- what netem delivers: per link in realtime, per receiver and epoch in lockstep -------------
def link_state(run_id: str, i: int | str, j: int | str) -> str:
    """Formation link ``i → j``: names its packets (counts, malformed ones); ``--passthrough``
    forwards on it."""
    return f"{ROOT}/{run_id}/link/{i}/{j}/state"


def link_report(run_id: str, i: int | str) -> str:
    """Control link ``i → 0`` (agent ``i``'s report to the leader), by name."""
    return f"{ROOT}/{run_id}/leader/report/{i}"


def link_estimate(run_id: str, i: int | str) -> str:
    """Control link ``0 → i`` (agent ``i``'s part of the estimate), by name."""
    return f"{ROOT}/{run_id}/link/{LEADER_ENDPOINT}/{i}/estimate"


def inbox(run_id: str, receiver: int | str, phase: str) -> str:
    """netem's :class:`Delivery` to ``receiver`` (0 = leader) in ``phase``: one per epoch in
    lockstep, one per wake-up that forwarded something to it in realtime."""
    return f"{ROOT}/{run_id}/inbox/{receiver}/{phase}"


def inbox_pool(run_id: str, pool: int | str, phase: str) -> str:
    """netem's :class:`DeliveryBatch` to the receivers of pool ``pool`` (its first agent's id)
    in ``phase``, lockstep: their deliveries of one epoch in one message."""
    return f"{ROOT}/{run_id}/inbox/pool/{pool}/{phase}"


# -- netem, clock, metrics, liveliness ---------------------------------------------------------
def netem_decision(run_id: str) -> str:
    return f"{ROOT}/{run_id}/netem/decision"


def netem_config(run_id: str) -> str:
    return f"{ROOT}/{run_id}/netem/config"


def netem_final(run_id: str) -> str:
    """Queryable of netem: which of the asker's last messages it still lacks (see netem.node)."""
    return f"{ROOT}/{run_id}/netem/final"


def netem_rejoin(run_id: str) -> str:
    """Queryable of netem: a restarted sender asks from which epoch it takes part again, and
    (an agent) its body's last state as netem forwarded it (see netem.node)."""
    return f"{ROOT}/{run_id}/netem/rejoin"


def netem_pool(run_id: str) -> str:
    """Queryable of netem: a pool process declares its agents, whose deliveries then come
    batched on :func:`inbox_pool` (see netem.node)."""
    return f"{ROOT}/{run_id}/netem/pool"


def netem_change(run_id: str) -> str:
    """Every accepted run-time change of a link model, as a record."""
    return f"{ROOT}/{run_id}/netem/change"


def status(run_id: str, role: str, ident: int | str) -> str:
    """Progress and counters a process publishes (epoch done, malformed payloads)."""
    return f"{ROOT}/{run_id}/status/{role}/{ident}"


def status_all(run_id: str) -> str:
    """Every process's status (a subscriber's key expression)."""
    return f"{ROOT}/{run_id}/status/**"


def metrics(run_id: str) -> str:
    return f"{ROOT}/{run_id}/metrics"


def alive(run_id: str, role: str, ident: int | str) -> str:
    """Liveliness token of a process: role is agent, leader, netem, recorder or pool."""
    return f"{ROOT}/{run_id}/alive/{role}/{ident}"


def alive_all(run_id: str) -> str:
    return f"{ROOT}/{run_id}/alive/**"


def body(run_id: str, i: int | str, what: str, type_name: str) -> str:
    """Agent ``i``'s body traffic as the agent saw it (``what``: ``pose`` in, ``command``
    out), a ROS 2 message of ``type_name`` (``geometry_msgs/msg/Twist``) in CDR; recorded."""
    return f"{ROOT}/{run_id}/body/{i}/{what}/{type_name}"


def scene(run_id: str) -> str:
    """Foxglove 3D scene written by the recorder."""
    return f"{ROOT}/{run_id}/viz/scene"


def frames(run_id: str) -> str:
    """The agents' frames (``foxglove.FrameTransforms``) written by the recorder."""
    return f"{ROOT}/{run_id}/viz/tf"


def log(run_id: str) -> str:
    """The run's log lines (``foxglove.Log``) written by the recorder."""
    return f"{ROOT}/{run_id}/viz/log"


def start(run_id: str) -> str:
    """Liveliness token netem declares once every process is up: epoch 0 may begin."""
    return f"{ROOT}/{run_id}/alive/clock/start"


def flush(run_id: str) -> str:
    """Queryable of the recorder: answers with its message counts per key (a flush barrier)."""
    return f"{ROOT}/{run_id}/recorder/counts"


def clock(run_id: str) -> str:
    """Queryable of netem in realtime mode: the run's start time and period."""
    return f"{ROOT}/{run_id}/clock"


def moved(key: str, old_prefix: str, new_prefix: str) -> str:
    """``key`` under ``new_prefix`` instead of ``old_prefix`` (a replay onto another run's keys);
    a key not under ``old_prefix`` stays as it is."""
    if key.startswith(old_prefix + "/"):
        return new_prefix + key[len(old_prefix) :]
    return key


def replay_control(prefix_key: str) -> str:
    """Queryable of a running replay under ``prefix_key`` (a run prefix): pause, resume, seek, rate."""
    return f"{prefix_key}/replay/control"


class ParsedKey(NamedTuple):
    """A key split by the function of this module that builds it."""

    kind: str  # that function's name (``agent_state``, ``inbox``, ``alive``, ...); "" if none
    run_id: str  # "" for a key outside ``formation/<run_id>/``
    args: tuple[str, ...]  # the function's other arguments, as the key writes them


_ANY = "\x00"  # a chunk a template leaves open
# The key functions, each with its number of arguments; the start token is an ``alive`` key.
_BUILDERS: tuple[tuple[Callable[..., str], int], ...] = (
    (agent_state, 2),
    (agent_report, 2),
    (pool_bundle, 3),
    (pool_states, 2),
    (leader_estimate_out, 1),
    (leader_estimate_for, 2),
    (leader_estimates, 1),
    (link_state, 3),
    (link_report, 2),
    (link_estimate, 2),
    (inbox, 3),
    (inbox_pool, 3),
    (netem_decision, 1),
    (netem_config, 1),
    (netem_final, 1),
    (netem_rejoin, 1),
    (netem_pool, 1),
    (netem_change, 1),
    (status, 3),
    (metrics, 1),
    (alive, 3),
    (scene, 1),
    (frames, 1),
    (log, 1),
    (flush, 1),
    (clock, 1),
    (body, 4),  # its last argument, a ROS 2 type, is three chunks: package/msg/Type
)
_TEMPLATES = sorted(  # the fewest open chunks first: a literal chunk wins over an open one
    (
        (fn.__name__, tuple(fn(*[_ANY] * (arity - 1), f"{_ANY}/msg/{_ANY}").split("/")))
        if fn is body
        else (fn.__name__, tuple(fn(*[_ANY] * arity).split("/")))
        for fn, arity in _BUILDERS
    ),
    key=lambda t: t[1].count(_ANY),
)


@lru_cache(maxsize=1 << 16)
def parse(key: str) -> ParsedKey:
    """The kind, run id and arguments of ``key`` (``kind`` "" when no function builds it)."""
    parts = tuple(key.split("/"))
    run_id = parts[1] if len(parts) > 2 and parts[0] == ROOT else ""
    for kind, template in _TEMPLATES:
        if len(parts) == len(template) and all(
            t in (_ANY, p) for t, p in zip(template, parts, strict=True)
        ):
            args = tuple(p for t, p in zip(template[2:], parts[2:], strict=True) if t == _ANY)
            if kind == body.__name__:
                args = (*args[:2], "/".join(parts[-3:]))
            return ParsedKey(kind, run_id, args)
    return ParsedKey("", run_id, ())
