"""Malformed and forged payloads for every kind of key of a run (issue 20, "never trusts the wire").

:func:`forgeries` gives ``(key, payload)`` pairs; each one must be skipped by every reader
of a recording and counted on its channel. They are built so that a reader that trusted
them would visibly go wrong: a state that claims to be agent 2 at ``[42, 42]``, a leader
estimate and decisions from someone else, metrics and scenes not written by the recorder.
"""

from __future__ import annotations

import json
from typing import Any

from formation import keys
from formation.scenario import Scenario


def _head(run_id: str, sender: str, epoch: int) -> dict[str, Any]:
    return {"run_id": run_id, "sender": sender, "seq": 0, "epoch": epoch, "stamp_ns": 1}


def _state(run_id: str, sender: str, epoch: int, agent: int, pos: Any) -> bytes:
    body = {**_head(run_id, sender, epoch), "kind": "state", "agent": agent, "position": pos}
    return json.dumps(body).encode()


def forgeries(run_id: str, s: Scenario, epoch: int = 7) -> list[tuple[str, bytes]]:
    """Every kind of key the testbed has (agent, link, inbox, leader, netem, metrics, status,
    scene, liveliness, control, an unknown one), each with a payload no reader may trust."""
    n, d = s.n, s.dimension
    far = [42.0] * d
    k = epoch
    est = {
        **_head(run_id, "agent/1", k), "kind": "estimate",
        "positions": [far] * n, "covariances": [[[1.0] + [0.0] * (d - 1)] * d] * n,
        "observable": [True] * n, "tree": [], "healthy": [], "components": 5,
        "rigidity_rank": 0, "rigid": False, "x_ref": far, "v_ref": [0.0] * d,
        "reports_received": n,
    }  # fmt: skip
    a, b = (int(v) for v in s.directed_links[0])
    every = [(e, int(i), int(j)) for e in range(s.epochs) for i, j in s.directed_links]
    decisions = {
        **_head(run_id, "agent/1", k), "kind": "decisions", "phase": "state",
        "judgements": [{"verdict": "drop"}],
        "records": {"source": [i for _, i, _ in every], "target": [j for _, _, j in every],
                    "epoch": [e for e, _, _ in every], "seq": [e for e, _, _ in every],
                    "judgement": [0] * len(every)},
    }  # fmt: skip
    metrics = {
        **_head(run_id, "recorder", k), "kind": "metrics", "formation_error_m": 99.0,
        "shape_error_m": 99.0, "positions": [far] * n,
    }  # fmt: skip
    status = {**_head(run_id, "agent/2", k), "kind": "status", "role": "agent", "state": "done"}
    delivery = {
        **_head(run_id, "netem", k), "kind": "delivery", "receiver": 2, "phase": "state",
        "packets": [], "lost": [],
    }  # fmt: skip
    alive = {"kind": "liveliness", "key": keys.alive(run_id, "agent", 2), "role": "agent",
             "ident": "2", "alive": False}  # fmt: skip
    return [
        # the agents' keys: empty, not JSON, wrong fields, [1e308, "x"], another agent's id
        (keys.agent_state(run_id, 1), b""),
        (keys.agent_state(run_id, 1), b"not json at all"),
        (keys.agent_state(run_id, 1), json.dumps({"wrong": "fields"}).encode()),
        (keys.agent_state(run_id, 1), _state(run_id, "agent/1", k, 1, [1e308, "x"])),
        (keys.agent_state(run_id, 1), _state(run_id, "agent/1", k, 2, far)),  # claims agent 2
        (keys.agent_state(run_id, 1), _state(run_id, "agent/1", s.epochs + 50, 1, far)),
        (keys.agent_state(run_id, n + 7), _state(run_id, f"agent/{n + 7}", k, n + 7, far)),
        (keys.agent_report(run_id, 1), b'[1e308, "x"]'),
        (keys.link_state(run_id, a, b), _state(run_id, f"agent/{b}", k, b, far)),
        (keys.inbox(run_id, 1, "state"), json.dumps(delivery).encode()),  # for 2 on 1's inbox
        (keys.inbox(run_id, 1, "report"), b"{}"),
        # the leader's and netem's keys, from someone else
        (keys.leader_estimate_out(run_id), json.dumps(est).encode()),
        (keys.leader_estimate_for(run_id, 1), b"\x00\xff"),
        (keys.link_estimate(run_id, 1), b"null"),
        (keys.netem_decision(run_id), json.dumps(decisions).encode()),
        (keys.netem_change(run_id), b'{"kind": "link_change"}'),
        # the recorder's own channels, the statuses, liveliness, a key nobody uses
        (keys.metrics(run_id), json.dumps(metrics).encode()),
        (keys.scene(run_id), json.dumps({"entities": [], "deletions": []}).encode()),
        (keys.scene(run_id), b"not a scene"),
        (keys.status(run_id, "agent", 1), json.dumps(status).encode()),
        (keys.status(run_id, "netem", 0), b""),
        (keys.alive(run_id, "agent", 1), json.dumps(alive).encode()),
        (f"{keys.prefix(run_id)}/nobody/publishes/here", b"{}"),
    ]


__all__ = ["forgeries"]
