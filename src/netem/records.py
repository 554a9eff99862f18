"""netem's outgoing records as JSON, built from tuples instead of pydantic objects.

netem takes one decision per packet; building a ``Decision`` and ``Delivered`` model
per packet cost more than the forwarding itself. The hot path keeps plain tuples,
and these functions encode a whole batch or close at once with orjson. The JSON is
exactly what :class:`~formation.messages.DecisionBatch` and
:class:`~formation.messages.EpochClose` validate (the tests parse it with them).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, NamedTuple

import orjson

from netem.stack import Decision as ModelDecision


class Record(NamedTuple):
    """One decision on one packet, as the hot path keeps it."""

    source: int
    target: int
    link_class: str
    epoch: int
    seq: int
    decision: ModelDecision


class Forwarded(NamedTuple):
    """A packet delivered to a receiver within an epoch (``sent_epoch < epoch`` when delayed)."""

    source: int
    seq: int
    sent_epoch: int
    copies: int


def decision_batch(header: dict[str, Any], phase: str, records: Iterable[Record]) -> bytes:
    """A ``DecisionBatch`` payload: ``header`` from ``Service.header``, one entry per record."""
    return orjson.dumps(
        {
            **header,
            "kind": "decisions",
            "phase": phase,
            "decisions": [
                {
                    "source": r.source,
                    "target": r.target,
                    "link_class": r.link_class,
                    "epoch": r.epoch,
                    "seq": r.seq,
                    "verdict": r.decision.verdict,
                    "delay_epochs": r.decision.delay_epochs,
                    "delay_ms": float(r.decision.delay_ms),
                    "model": r.decision.model,
                    "state": r.decision.state,
                }
                for r in records
            ],
        }
    )


def epoch_close(
    header: dict[str, Any],
    receiver: int,
    phase: str,
    delivered: Iterable[Forwarded],
    lost: Iterable[int],
    dead: Iterable[int],
) -> bytes:
    """An ``EpochClose`` payload for ``receiver`` after ``phase``."""
    return orjson.dumps(
        {
            **header,
            "kind": "close",
            "receiver": receiver,
            "phase": phase,
            "delivered": [
                {"source": f.source, "seq": f.seq, "sent_epoch": f.sent_epoch, "copies": f.copies}
                for f in delivered
            ],
            "lost": sorted(lost),
            "dead": sorted(dead),
        }
    )
