"""Gated epochs (distance models on the state links) equal the full path, byte for byte.

A state epoch whose links all pass before their distance layers is gathered and judged
at once by its lengths (:mod:`netem.proxy.clean_epochs`); it must give the deliveries and decision
records that deciding packet by packet gives. The reference is the same core without the
clean path (``setup_clean`` not called): every packet decided on its own as it is routed.
Senders interleave epochs, a position is sometimes unreadable, a sender sometimes dies.
"""

from __future__ import annotations

import json
import random
from collections import defaultdict
from typing import Any

import numpy as np
import pytest

from formation.scenario import Scenario
from netem.proxy.lockstep import LockstepCore
from netem.proxy.progress import Progress
from netem.proxy.records import Ledger, Record, record_head, record_tail
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

    def records(self, phase: Phase, epoch: int, records: list[Record]) -> None:
        for s, t, c, e, q, d in records:
            self._add(b'%s,"epoch":%d,"seq":%d%s' % (record_head(s, t, c), e, q, record_tail(d)))

    def clean_records(self, phase: Phase, last_epoch: int, chunks: list[bytes]) -> None:
        for chunk in chunks:
            for r in json.loads(b"[" + chunk + b"]"):
                self.records_of[r["epoch"]].append(r)

    def _add(self, record: bytes) -> None:
        r = json.loads(record)
        self.records_of[r["epoch"]].append(r)


def drive(scenario: Scenario, seed: int, clean: bool) -> tuple[Bytes, LockstepCore]:
    """Every state of ``scenario``'s agents, senders up to ``lag`` epochs apart, one maybe dying."""
    rng = random.Random(seed)
    links, wire = Links(scenario, seed), Bytes()
    lock = LockstepCore(links, EPOCHS, Progress(links.agents, EPOCHS, lambda: None), Ledger(), wire)
    if clean:
        lock.setup_clean()
    n, noise = scenario.n, np.random.default_rng(seed)
    x = [
        (scenario.offsets[:, :2] * (0.6 + 0.1 * np.sin(k / 5.0)) + noise.normal(0, 0.05, (n, 2)))
        for k in range(EPOCHS + 1)
    ]
    lag, victim = rng.choice([0, 1, 2]), rng.randrange(1, n + 1)
    die_at = rng.choice([None, rng.randrange(3, EPOCHS * n - 3)])
    next_epoch, sent = dict.fromkeys(range(1, n + 1), 0), 0
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
        lock.packet(
            ("state", i, 0), k, k, b"{" if rng.random() < 0.01 else json.dumps(state).encode()
        )
        sent += 1
        if sent == die_at:
            lock.sender_died(victim)
        if rng.random() < 0.3:
            lock.flush_clean()
    lock.flush_clean()
    return wire, lock


def counts(lock: LockstepCore) -> dict[Any, int]:
    """Packets forwarded per link, links with none left out."""
    return {link: n for link, n in lock.forwarded().items() if n}


@pytest.mark.parametrize("network", NETWORKS)
def test_gated_epochs_equal_the_full_path(paper: Scenario, network: str) -> None:
    scenario = paper.with_overrides(network=NETWORKS[network], epochs=EPOCHS)
    gated = slow = 0
    for seed in range(12):
        full, reference = drive(scenario, seed, clean=False)
        fast, lock = drive(scenario, seed, clean=True)
        assert fast.deliveries == full.deliveries, seed
        assert fast.records_of == full.records_of, seed
        assert counts(lock) == counts(reference), seed
        gated += len(lock.clean["state"].done)
        slow += len(lock.clean["state"].slow)
    assert gated > 0 and slow > 0  # both paths taken
