"""netem's outgoing records as JSON, built from tuples instead of pydantic objects.

netem takes one decision per packet; building a ``Decision`` and ``Delivered`` model
per packet cost more than the forwarding itself. The hot path keeps plain tuples,
and these functions encode a whole batch or close at once with orjson. The JSON is
exactly what :class:`~formation.messages.DecisionBatch` and
:class:`~formation.messages.EpochClose` validate (the tests parse it with them).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import orjson

from netem.stack import Decision as ModelDecision

# One decision on one packet, as the hot path keeps it (a plain tuple: built per packet):
# (source, target, link class, epoch, seq, the model's decision).
Record = tuple[int, int, str, int, int, ModelDecision]
# A packet delivered to a receiver within an epoch (sent epoch < epoch when delayed):
# (source, seq, sent epoch, copies).
Forwarded = tuple[int, int, int, int]


def decision_batch(header: dict[str, Any], phase: str, records: Iterable[Record]) -> bytes:
    """A ``DecisionBatch`` payload: ``header`` from ``Service.header``, one entry per record."""
    return orjson.dumps(
        {
            **header,
            "kind": "decisions",
            "phase": phase,
            "decisions": [
                {
                    "source": source,
                    "target": target,
                    "link_class": link_class,
                    "epoch": epoch,
                    "seq": seq,
                    "verdict": d.verdict,
                    "delay_epochs": d.delay_epochs,
                    "delay_ms": float(d.delay_ms),
                    "model": d.model,
                    "state": d.state,
                }
                for source, target, link_class, epoch, seq, d in records
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
                {"source": source, "seq": seq, "sent_epoch": sent_epoch, "copies": copies}
                for source, seq, sent_epoch, copies in delivered
            ],
            "lost": sorted(lost),
            "dead": sorted(dead),
        }
    )
