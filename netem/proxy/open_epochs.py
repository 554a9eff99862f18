"""What netem's lockstep core keeps per epoch and where it hands its outputs (:mod:`netem.proxy.lockstep`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

from netem.proxy.records import Record
from netem.proxy.routes import Link, Phase


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

    def records(self, phase: Phase, epoch: int, records: list[Record]) -> None:
        """The decision records of ``epoch`` of ``phase``, every receiver of it closed."""

    def record_chunks(self, phase: Phase, last_epoch: int, chunks: list[bytes]) -> None:
        """Records of closed epochs up to ``last_epoch``, encoded: one chunk an epoch."""


@dataclass
class Delayed:
    """A packet held for a later epoch (delay), delivered with that epoch's packets."""

    link: Link
    copies: int
    packet: bytes  # encoded by packet_json, with its sent epoch


@dataclass(slots=True)
class OpenEpoch:
    """An epoch of one phase into one receiver, not yet closed."""

    handled: set[int] = field(default_factory=set)
    packets: list[bytes] = field(default_factory=list)  # each encoded by packet_json
    lost: list[int] = field(default_factory=list)


__all__ = ["Delayed", "OpenEpoch", "Outbox"]
