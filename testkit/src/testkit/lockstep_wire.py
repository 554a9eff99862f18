"""A lockstep outbox that keeps what netem would publish, parsed back as a receiver would.

netem's lockstep core (``netem.proxy.lockstep``) sends through an outbox; this one encodes each
delivery and decision batch as the node would and parses the bytes again, so unit tests of
the core read the same messages as the integration tests.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from formation.messages import Decision, DecisionBatch, Delivery, decision_rows
from formation.scenario import Scenario
from netem.proxy.records import Record, decision_batch, decision_batch_of, delivery
from netem.proxy.routes import Phase


def header(epoch: int) -> dict[str, Any]:
    return {"run_id": "r", "sender": "netem", "seq": 0, "epoch": epoch, "stamp_ns": 1}


class Wire:
    """An outbox keeping every delivery and decision record, parsed from the bytes sent."""

    def __init__(self, receivers: dict[Phase, list[int]]) -> None:
        self.receivers = receivers  # who closes an epoch of each phase
        self.deliveries: list[Delivery] = []
        self.decisions: list[Decision] = []
        self.closed: Counter[tuple[str, int]] = Counter()  # (phase, epoch) → receivers closed
        self.early: list[tuple[str, int]] = []  # records out before every receiver closed

    def deliver(self, phase: Phase, receiver: int, epoch: int, packets: list[bytes],
                lost: list[int], dead: list[int]) -> None:  # fmt: skip
        wire = delivery(header(epoch), receiver, phase, packets, lost, dead)
        self.deliveries.append(Delivery.model_validate_json(wire))
        self.closed[(phase, epoch)] += 1

    def deliver_many(self, phase: Phase, epoch: int,
                     ready: list[tuple[int, list[bytes], list[int]]]) -> None:  # fmt: skip
        for receiver, packets, lost in ready:
            self.deliver(phase, receiver, epoch, packets, lost, [])

    def records(self, phase: Phase, epoch: int, records: list[Record]) -> None:
        self._batch(phase, decision_batch(header(epoch), phase, records))

    def record_batch(self, phase: Phase, last_epoch: int, body: bytes) -> None:
        self._batch(phase, decision_batch_of(header(last_epoch), body))

    def _batch(self, phase: Phase, wire: bytes) -> None:
        rows = decision_rows(DecisionBatch.model_validate_json(wire))
        live = len(self.receivers[phase])
        self.early += [(phase, d.epoch) for d in rows if self.closed[(phase, d.epoch)] < live]
        self.decisions += rows


def receivers(scenario: Scenario) -> dict[Phase, list[int]]:
    agents = list(range(1, scenario.n + 1))
    return {"state": agents, "report": [0], "estimate": agents}
