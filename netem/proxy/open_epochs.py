"""What netem's lockstep core keeps per epoch and where it hands its outputs (:mod:`netem.proxy.lockstep`)."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from typing import Protocol

from netem.proxy.records import Record, Recorded, RecordTemplates, Template, batch_body
from netem.proxy.routes import Link, Phase

FLUSH_CHUNKS = 64  # epochs' records per batch (at least one batch per 0.2 s wake-up)


class Outbox(Protocol):
    """Where the core's outputs go; the node publishes each as it comes."""

    def deliver(
        self,
        phase: Phase,
        receiver: int,
        epoch: int,
        packets: list[bytes],
        lost: list[int],
        dead: list[int],
    ) -> None:
        """``receiver``'s delivery of ``phase`` and ``epoch`` (its close)."""

    def deliver_many(
        self, phase: Phase, epoch: int, ready: list[tuple[int, list[bytes], list[int]]]
    ) -> None:
        """:meth:`deliver` of each ``(receiver, packets, lost)`` in turn, none dead."""

    def records(self, phase: Phase, epoch: int, records: list[Record]) -> None:
        """The decision records of ``epoch`` of ``phase``, every receiver of it closed."""

    def record_batch(self, phase: Phase, last_epoch: int, body: bytes) -> None:
        """Records of closed epochs up to ``last_epoch``: a batch's fields after its header
        (:func:`~netem.proxy.records.batch_body`)."""


@dataclass
class Delayed:
    """A packet held for a later epoch (delay), delivered with that epoch's packets."""

    link: Link
    copies: int
    packet: bytes  # encoded by packet_json, with its sent epoch


class OpenEpoch:
    """An epoch of one phase into one receiver, not yet closed."""

    __slots__ = ("handled", "lost", "packets")

    def __init__(self) -> None:  # one per receiver and epoch: plain slots are built fastest
        self.handled: set[int] = set()
        self.packets: list[bytes] = []  # each encoded by packet_json
        self.lost: list[int] = []


class RecordBatches:
    """Each epoch's records until every receiver of it closed, then its phase's batch until it
    goes out: every :data:`FLUSH_CHUNKS` epochs, at the last epoch or when flushed. An epoch
    that recorded nothing goes out at once, empty (records stay in epoch order)."""

    def __init__(
        self, outbox: Outbox, epochs: int, templates: dict[Phase, RecordTemplates]
    ) -> None:
        self.outbox, self.epochs, self.templates = outbox, epochs, templates
        self.pending: defaultdict[tuple[Phase, int], list[Recorded]] = defaultdict(list)
        # phase → (newest epoch, its epochs' records)
        self.batches: dict[Phase, tuple[int, list[tuple[int, list[Recorded]]]]] = {}

    def add(self, phase: Phase, epoch: int, template: Template, seq: int) -> None:
        """The records of a packet of ``epoch``: its ``template`` and ``seq``."""
        self.pending[(phase, epoch)].append((template, seq))

    def add_many(self, phase: Phase, epoch: int, recorded: list[Recorded]) -> None:
        """:meth:`add` of each ``(template, seq)``."""
        self.pending[(phase, epoch)] += recorded

    def close(self, phase: Phase, epoch: int) -> None:
        """Every receiver of ``epoch`` closed: its records join the phase's batch."""
        records = self.pending.pop((phase, epoch), None)
        if not records:
            self.flush(phase)
            self.outbox.records(phase, epoch, [])
            return
        _, epochs = self.batches.get(phase, (-1, []))
        epochs.append((epoch, records))
        self.batches[phase] = (epoch, epochs)
        if len(epochs) >= FLUSH_CHUNKS or epoch >= self.epochs - 1:
            self.flush(phase)

    def flush(self, phase: Phase | None = None) -> None:
        """Hand out the batch of ``phase`` (None: of every phase)."""
        for p in [phase] if phase is not None else list(self.batches):
            last, epochs = self.batches.get(p, (-1, []))
            if epochs:
                body = batch_body(p, self.templates[p].judgements, epochs)
                self.outbox.record_batch(p, last, body)
                self.batches[p] = (last, [])


__all__ = ["FLUSH_CHUNKS", "Delayed", "OpenEpoch", "Outbox", "RecordBatches"]
