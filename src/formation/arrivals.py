"""A lockstep receiver's side of netem's epoch close (ARCHITECTURE.md "Time").

netem sends a receiver an ``EpochClose`` for a phase's epoch only when the close says
something (a loss, a delay, a duplicate, a dead sender). Without one, the epoch is
complete once every sender's packet of that epoch is here, unless a forwarded packet
carried ``CLOSE_FOLLOWS``. Agents and the leader both keep one :class:`Arrivals` per
phase they receive, so the rule lives in one place.
"""

from __future__ import annotations

from formation.codec import CLOSE_FOLLOWS, attachment_flags
from formation.messages import EpochClose

Delivered = tuple[int, int, int]  # (source, seq, sent epoch)


class Arrivals:
    """Packets of one phase into one receiver, by sent epoch, and netem's closes."""

    def __init__(self) -> None:
        self.arrived: dict[int, dict[int, int]] = {}  # sent epoch → source → seq
        self.closes: dict[int, EpochClose] = {}
        self.close_follows: set[int] = set()  # epochs netem flagged: wait for the close

    def packet(self, sent_epoch: int, source: int, seq: int, attachment: bytes | None) -> None:
        self.arrived.setdefault(sent_epoch, {})[source] = seq
        if attachment_flags(attachment) & CLOSE_FOLLOWS:
            self.close_follows.add(sent_epoch)

    def close(self, close: EpochClose, current: int) -> bool:
        """Keep ``close`` unless its epoch is before ``current`` (done without it)."""
        if close.epoch < current:
            return False
        self.closes[close.epoch] = close
        return True

    def delivered(self, epoch: int, senders: list[int]) -> list[Delivered] | None:
        """What netem delivered for ``epoch`` once all of it is here; None while waiting."""
        close = self.closes.get(epoch)
        if close is not None:
            listed = [(d.source, d.seq, d.sent_epoch) for d in close.delivered]
            here = all(self.arrived.get(e, {}).get(s) == q for s, q, e in listed)
            return listed if here else None
        got = self.arrived.get(epoch, {})
        # Counting first: called on every packet, a full check would cost O(senders) each time.
        if len(got) < len(senders) or epoch in self.close_follows:
            return None
        if any(s not in got for s in senders):
            return None
        return [(s, got[s], epoch) for s in senders]

    def forget(self, epoch: int) -> None:
        """Drop everything of epochs up to ``epoch`` (its phase is done)."""
        for e in [e for e in self.arrived if e <= epoch]:
            del self.arrived[e]
        for e in [e for e in self.closes if e <= epoch]:
            del self.closes[e]
        self.close_follows = {e for e in self.close_follows if e > epoch}
