"""What netem's lockstep core puts out, on the bus: deliveries on ``inbox/<receiver>/<phase>``,
decision records on ``netem/decision``."""

from __future__ import annotations

from formation import keys
from formation.codec import now_ns
from formation.keys import LEADER_ENDPOINT
from netem.proxy.records import (
    Record,
    decision_batch,
    decision_batch_of,
    delivery_head,
    delivery_of,
)
from netem.proxy.routes import Phase
from shell import Publisher, Service


class ZenohOutbox:
    """Publishes the lockstep core's outputs: deliveries on ``inbox/<receiver>/<phase>``,
    decision records on ``netem/decision``."""

    def __init__(self, service: Service) -> None:
        self.service = service
        # (phase, receiver) → key, publisher, the delivery's fields before its packets
        self._inboxes: dict[tuple[Phase, int], tuple[str, Publisher, bytes]] = {}
        self._decision_key = keys.netem_decision(service.run_id)
        self._header = service.header_format()

    def declare(self, agents: list[int]) -> None:
        """Declare every inbox's publisher now, before the clock starts (as
        :meth:`~shell.service.Service.declare_publishers`)."""
        for i in agents:
            for phase in ("state", "estimate"):
                self._inbox(phase, i)
        self._inbox("report", LEADER_ENDPOINT)
        self.service.publisher(self._decision_key)

    def _inbox(self, phase: Phase, receiver: int) -> tuple[str, Publisher, bytes]:
        out = self._inboxes.get((phase, receiver))
        if out is None:
            key = keys.inbox(self.service.run_id, receiver, phase)
            head = delivery_head(self._header, receiver, phase)
            out = self._inboxes[(phase, receiver)] = (key, self.service.publisher(key), head)
        return out

    def deliver(
        self,
        phase: Phase,
        receiver: int,
        epoch: int,
        packets: list[bytes],
        lost: list[int],
        dead: list[int],
    ) -> None:
        service = self.service
        key, pub, head = self._inbox(phase, receiver)  # two thousand an epoch: spliced
        fields = head % (service.next_seq(key), epoch, now_ns())
        pub.put(delivery_of(fields, packets, lost, dead))
        service.sent[key] += 1

    def records(self, phase: Phase, epoch: int, records: list[Record]) -> None:
        key = self._decision_key
        self.service.put(key, decision_batch(self.service.header(key, epoch), phase, records))

    def record_batch(self, phase: Phase, last_epoch: int, body: bytes) -> None:
        key = self._decision_key
        self.service.put(key, decision_batch_of(self.service.header(key, last_epoch), body))
