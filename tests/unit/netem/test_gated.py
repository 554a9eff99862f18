"""Distance models on the state links: the core's decisions are the model's, packet by packet.

The core decides a state's links from its stream's row (taken ahead, before the distance
layers) and asks the model only for a link out of reach (:mod:`netem.proxy.decision_rows`);
every record must be ``LinkModel.decide(epoch, distance_m=length)`` at the length the
positions sent give, and every delivery must carry the packets those records pass.
Senders interleave epochs, a position is sometimes unreadable, a sender sometimes dies.
"""

from __future__ import annotations

import json
import math
import random
from collections import defaultdict
from typing import Any

import numpy as np
import pytest

from formation.messages import DecisionBatch, decision_rows
from formation.scenario import Scenario
from netem.links.matrix import link_length
from netem.proxy.lockstep import LockstepCore
from netem.proxy.progress import Progress
from netem.proxy.records import (
    Ledger,
    Record,
    decision_batch,
    decision_batch_of,
    judgement_json,
)
from netem.proxy.routes import Links, Phase

EPOCHS = 40
NETWORKS: dict[str, dict[str, Any]] = {
    "logistic": {"formation_default": [{"model": "logistic", "d50_m": 1.2, "width_m": 0.1}]},
    "logistic, range to an access point": {
        "formation_default": [{"model": "logistic", "d50_m": 1.2, "width_m": 0.1}],
        "control_default": [{"model": "range", "max_range_m": 1.0}],
        "access_point": [0.0, 0.2],
    },
    "bernoulli, range, logistic": {
        "formation_default": [
            {"model": "bernoulli", "p_loss": 0.05},
            {"model": "range", "max_range_m": 1.9},
            {"model": "logistic", "d50_m": 1.5, "width_m": 0.2},
        ]
    },
    "log_distance, correlated shadowing": {
        "formation_default": [
            {
                "model": "log_distance",
                "sigma_db": 4.0,
                "shadowing_correlation": 0.5,
                "path_loss_d0_db": 40.0,
                "sensitivity_dbm": -45.0,
            },
        ]
    },
    "range, duplicate": {
        "formation_default": [
            {"model": "range", "max_range_m": 1.2},
            {"model": "duplicate", "p": 0.02},
        ]
    },
}


class Bytes:
    """An outbox keeping each receiver's deliveries and each epoch's records, as encoded."""

    def __init__(self) -> None:
        self.deliveries: dict[tuple[Phase, int], list[tuple[Any, ...]]] = defaultdict(list)
        self.records_of: dict[int, list[Any]] = defaultdict(list)

    def deliver(self, phase: Phase, receiver: int, epoch: int, packets: list[bytes],
                lost: list[int], dead: list[int]) -> None:  # fmt: skip
        self.deliveries[(phase, receiver)].append((epoch, b",".join(packets), lost, dead))

    def deliver_many(self, phase: Phase, epoch: int,
                     ready: list[tuple[int, list[bytes], list[int]]]) -> None:  # fmt: skip
        for receiver, packets, lost in ready:
            self.deliver(phase, receiver, epoch, packets, lost, [])

    def records(self, phase: Phase, epoch: int, records: list[Record]) -> None:
        self._add(decision_batch(HEADER, phase, records))

    def record_batch(self, phase: Phase, last_epoch: int, body: bytes) -> None:
        self._add(decision_batch_of(HEADER, body))

    def _add(self, batch: bytes) -> None:
        for r in decision_rows(DecisionBatch.model_validate_json(batch)):
            self.records_of[r.epoch].append(r.model_dump())


HEADER = {"run_id": "r", "sender": "netem", "seq": 0, "epoch": 0, "stamp_ns": 1}
Sent = dict[tuple[int, int], list[float] | None]  # (agent, epoch) → position sent, None: unreadable


def drive(scenario: Scenario, seed: int) -> tuple[Bytes, LockstepCore, Sent]:
    """Every state of ``scenario``'s agents, senders up to ``lag`` epochs apart, one maybe dying."""
    rng = random.Random(seed)
    links, wire = Links(scenario, seed), Bytes()
    lock = LockstepCore(links, EPOCHS, Progress(links.agents, EPOCHS, lambda: None), Ledger(), wire)
    n, noise = scenario.n, np.random.default_rng(seed)
    x = [
        (scenario.offsets[:, :2] * (0.6 + 0.1 * np.sin(k / 5.0)) + noise.normal(0, 0.05, (n, 2)))
        for k in range(EPOCHS + 1)
    ]
    lag, victim = rng.choice([0, 1, 2]), rng.randrange(1, n + 1)
    die_at = rng.choice([None, rng.randrange(3, EPOCHS * n - 3)])
    next_epoch, sent, positions = dict.fromkeys(range(1, n + 1), 0), 0, {}
    while True:
        low = min(next_epoch.values())
        senders = [i for i, k in next_epoch.items() if k <= min(EPOCHS, low + lag)]
        senders = [i for i in senders if not (i == victim and victim in lock.dead)]
        if not senders:
            break
        i = rng.choice(senders)
        k = next_epoch[i]
        next_epoch[i] += 1
        state = {"agent": i, "epoch": k, "position": x[k][i - 1].tolist()}
        unreadable = rng.random() < 0.01
        positions[(i, k)] = None if unreadable else state["position"]
        lock.packet(("state", i, 0), k, k, b"{" if unreadable else json.dumps(state).encode())
        sent += 1
        if sent == die_at:
            lock.sender_died(victim)
        if rng.random() < 0.3:
            lock.flush()
    lock.flush()
    return wire, lock, positions


def model_json(links: Links, link: tuple[str, int, int], epoch: int,
               sent: Sent) -> dict[str, Any]:  # fmt: skip
    """The record fields of the model's decision of ``link``'s packet at its true length."""
    _, src, dst = link
    a, b = sent.get((src, epoch)), sent.get((dst, epoch))
    length = math.inf if a is None or b is None else link_length(a, b)
    d = links.models[link].decide(epoch, distance_m=length)
    return json.loads(judgement_json(d))  # type: ignore[no-any-return]


def counts(lock: LockstepCore) -> dict[Any, int]:
    """Packets forwarded per link, links with none left out."""
    return {link: n for link, n in lock.forwarded().items() if n}


@pytest.mark.parametrize("network", NETWORKS)
def test_distance_decisions_are_the_models_packet_by_packet(paper: Scenario, network: str) -> None:
    scenario = paper.with_overrides(network=NETWORKS[network], epochs=EPOCHS)
    fields = ("verdict", "delay_epochs", "delay_ms", "model", "state")
    dropped = 0
    for seed in range(12):
        wire, lock, sent = drive(scenario, seed)
        reference = Links(scenario, seed)
        passed: dict[tuple[int, int, int], int] = {}  # (src, dst, epoch) → copies delivered
        forwarded: dict[Any, int] = defaultdict(int)
        for epoch, records in wire.records_of.items():
            for r in records:
                link = ("formation", r["source"], r["target"])
                want = model_json(reference, link, epoch, sent)
                assert {f: r[f] for f in fields} == want, (seed, r)
                copies = 0 if r["verdict"] == "drop" else 1 + (r["verdict"] == "duplicate")
                passed[(r["source"], r["target"], epoch)] = copies
                forwarded[link] += copies
                dropped += not copies
        for (_, receiver), got in wire.deliveries.items():
            for epoch, packets, lost, _ in got:
                sources = [p["source"] for p in json.loads(b"[" + packets + b"]")]
                for src in sources:
                    assert passed[(src, receiver, epoch)] >= 1, (seed, src, receiver, epoch)
                for src in lost:
                    assert passed[(src, receiver, epoch)] == 0, (seed, src, receiver, epoch)
        assert {k: v for k, v in forwarded.items() if v} == counts(lock), seed
    assert dropped > 0  # some out of reach
