"""netem's outgoing records as JSON, built from tuples instead of pydantic objects.

netem takes one decision per packet; building an ``Outcome`` and ``DeliveredPacket`` model
per packet cost more than the forwarding itself. The hot path keeps plain tuples,
and these functions encode a whole batch or delivery at once with orjson. The JSON is
exactly what :class:`~formation.messages.DecisionBatch` and
:class:`~formation.messages.Delivery` validate (the tests parse it with them). The
:class:`Ledger` keeps the records until their batch goes out, and counts what was forwarded.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Iterable
from typing import Any, NamedTuple

import orjson

from netem.links.layer_stack import Outcome
from netem.proxy.routes import Link, Phase


class Queued(NamedTuple):
    """A packet's decision after its capacity queues: the model's, or the queue's drop
    (``model`` its reason), with the queue, its depth [packets] and the sojourn [ms]."""

    delivered: bool
    delay_epochs: int
    delay_ms: float
    copies: int
    verdict: str
    model: str
    state: str
    reordered: bool
    queue: str
    queue_depth: int
    sojourn_ms: float


def queued(d: Outcome, reason: str, queue: str, depth: int, sojourn_ms: float) -> Queued:
    """The decision on a packet the model ``d`` passed, once its queues judged it.

    Shared, as the models' decisions are (so :func:`record_tail` encodes each once): a link's
    sojourns take few values, those of its packet sizes rounded at each binade of the clock.
    """
    key = (id(d), reason, queue, depth, sojourn_ms)
    got = _QUEUED.get(key)
    if got is not None and got[0] is d:
        return got[1]
    if not reason:
        q = Queued(*d, queue, depth, sojourn_ms)
    else:
        q = Queued(False, 0, 0.0, 0, "drop", reason, d.state, False, queue, depth, sojourn_ms)
    if len(_QUEUED) > 20_000:  # a backlog's sojourns are all different: kept few
        _QUEUED.clear()
    _QUEUED[key] = (d, q)  # the entry keeps d alive: its id is not reused
    return q


_QUEUED: dict[tuple[int, str, str, int, float], tuple[Outcome, Queued]] = {}


# One decision on one packet, as the hot path keeps it (a plain tuple: built per packet):
# (source, target, link class, epoch, seq, the model's decision, or the queues').
Record = tuple[int, int, str, int, int, Outcome | Queued]


class Ledger:
    """What netem decided and forwarded: records not yet published, packets per link.

    A node has one, which its lockstep and realtime paths both write to.
    """

    def __init__(self) -> None:
        self.decisions: defaultdict[tuple[Phase, int], list[Record]] = defaultdict(list)
        self.forwarded: Counter[Link] = Counter()  # packets delivered per link


def _decision_json(d: Outcome | Queued) -> bytes:
    """The fields of a record that come from the decision, as JSON after ``"seq":N``."""
    fields = {
        "verdict": d.verdict,
        "delay_epochs": d.delay_epochs,
        "delay_ms": float(d.delay_ms),
        "model": d.model,
        "state": d.state,
    }
    if isinstance(d, Queued):
        fields.update(queue=d.queue, queue_depth=d.queue_depth, sojourn_ms=d.sojourn_ms)
    return orjson.dumps(fields).replace(b"{", b",", 1)


# A link's records differ only in epoch, seq and decision; decisions are shared objects
# (a model memoises them per block), so both halves are encoded once and spliced.
_LINK_JSON: dict[tuple[int, int, str], bytes] = {}
_DECISION_JSON: dict[int, tuple[Outcome | Queued, bytes]] = {}  # by id; the entry keeps d alive


def record_head(source: int, target: int, link_class: str) -> bytes:
    """A record's JSON up to (not including) ``,"epoch":``."""
    head = _LINK_JSON.get((source, target, link_class))
    if head is None:
        head = _LINK_JSON[(source, target, link_class)] = orjson.dumps(
            {"source": source, "target": target, "link_class": link_class}
        )[:-1]
    return head


def record_tail(d: Outcome | Queued) -> bytes:
    """A record's JSON after ``"seq":N``: the fields that come from the decision."""
    tail = _DECISION_JSON.get(id(d))
    if tail is None or tail[0] is not d:
        if len(_DECISION_JSON) > 100_000:
            _DECISION_JSON.clear()
        tail = _DECISION_JSON[id(d)] = (d, _decision_json(d))
    return tail[1]


class RecordTemplates:
    """The records of each stream's packet (one per link) as a ``%`` template of ``(epoch, seq)``
    per link recorded: records that differ only in those are spliced, not encoded one by one.

    A decision's encoded fields (:func:`record_tail`) get an id (:meth:`tail_id`); a template is
    one per stream and tuple of its links' ids.
    """

    def __init__(self, streams: dict[int, tuple[Link, ...]]) -> None:
        self._heads = {
            sid: [record_head(src, dst, cls).replace(b"%", b"%%") for cls, src, dst in links]
            for sid, links in streams.items()
        }
        self._tail_ids: dict[bytes, int] = {}
        self._tails: list[bytes] = []
        self._of: dict[int, tuple[Outcome | Queued, int]] = {}  # by id; the entry keeps d alive
        self._templates: dict[tuple[int, tuple[int, ...]], tuple[bytes, int]] = {}
        self._rows: dict[int, tuple[tuple[Outcome | Queued | None, ...], tuple[bytes, int]]] = {}

    def tail_id(self, d: Outcome | Queued) -> int:
        """An id of a decision's encoded fields."""
        known = self._of.get(id(d))
        if known is not None and known[0] is d:
            return known[1]
        tail = record_tail(d)
        got = self._tail_ids.get(tail)
        if got is None:
            got = self._tail_ids[tail] = len(self._tails)
            self._tails.append(tail)
        if len(self._of) > 100_000:  # a backlog's sojourns are all different: kept few
            self._of.clear()
        self._of[id(d)] = (d, got)
        return got

    def row_template(
        self, stream: int, row: tuple[Outcome | Queued | None, ...]
    ) -> tuple[bytes, int]:
        """The template of ``stream``'s packet with every link recorded as ``row`` decides
        (:meth:`template`), kept by the row (rows are shared objects)."""
        known = self._rows.get(id(row))
        if known is not None and known[0] is row:
            return known[1]
        got = self.template(stream, tuple(-1 if d is None else self.tail_id(d) for d in row))
        if len(self._rows) > 100_000:
            self._rows.clear()
        self._rows[id(row)] = (row, got)  # the entry keeps the row alive: its id is not reused
        return got

    def template(self, stream: int, tails: tuple[int, ...]) -> tuple[bytes, int]:
        """The records of ``stream``'s packet, its links' decisions ``tails`` (ids; -1: a link
        not recorded with it), and how many links it records."""
        got = self._templates.get((stream, tails))
        if got is None:
            if len(self._templates) > 100_000:  # queues' sojourns make many: kept few
                self._templates.clear()
            parts = [
                head + b',"epoch":%d,"seq":%d' + self._tails[t].replace(b"%", b"%%")
                for head, t in zip(self._heads[stream], tails, strict=True)
                if t >= 0
            ]
            got = self._templates[(stream, tails)] = (b",".join(parts), len(parts))
        return got


def record_json(record: Record) -> bytes:
    """One record, encoded."""
    s, t, c, e, q, d = record
    return b'%s,"epoch":%d,"seq":%d%s' % (record_head(s, t, c), e, q, record_tail(d))


def decision_batch(header: dict[str, Any], phase: str, records: Iterable[Record]) -> bytes:
    """A ``DecisionBatch`` payload: ``header`` from ``Service.header``, one entry per record."""
    return decision_batch_of(header, phase, [record_json(r) for r in records])


def decision_batch_of(header: dict[str, Any], phase: str, records: list[bytes]) -> bytes:
    """A ``DecisionBatch`` payload from records already encoded (comma-joined groups allowed)."""
    head = orjson.dumps({**header, "kind": "decisions", "phase": phase})[:-1]
    return b'%s,"decisions":[%s]}' % (head, b",".join(records))


def packet_json(source: int, seq: int, sent_epoch: int, copies: int, payload: Any) -> bytes:
    """One packet of a ``Delivery``, encoded once however many receivers' deliveries carry it."""
    return packet_json_of(source, seq, sent_epoch, copies, message_json(payload))


def message_json(payload: Any) -> bytes:
    """A payload as the JSON string a ``DeliveredPacket``'s ``message`` holds; the last one is
    kept, as a state is delivered on each of its out-links in turn."""
    global _LAST_MESSAGE
    last = _LAST_MESSAGE  # one read: another thread may replace it
    if last[0] is payload:  # it holds that payload: its id is not reused
        return last[1]
    message = orjson.dumps(_text(payload))
    _LAST_MESSAGE = (payload, message)
    return message


_LAST_MESSAGE: tuple[Any, bytes] = (None, b"")


def packet_json_of(source: int, seq: int, sent_epoch: int, copies: int, message: bytes) -> bytes:
    """:func:`packet_json` with the message already encoded (:func:`message_json`)."""
    return b'{"source":%d,"seq":%d,"sent_epoch":%d,"copies":%d,"message":%s}' % (
        source,
        seq,
        sent_epoch,
        copies,
        message,
    )


def delivery(
    header: dict[str, Any],
    receiver: int,
    phase: str,
    packets: Iterable[bytes],
    lost: Iterable[int],
    dead: Iterable[int],
) -> bytes:
    """A ``Delivery`` payload for ``receiver``: the packets of ``phase`` (:func:`packet_json`)
    it gets this epoch, spliced."""
    head = orjson.dumps({**header, "kind": "delivery", "receiver": receiver, "phase": phase})
    return delivery_of(head[:-1], packets, lost, dead)


def delivery_head(header_format: bytes, receiver: int, phase: str) -> bytes:
    """A ``Delivery``'s fields before its packets, ``%d`` for the header's seq, epoch and
    stamp_ns (:meth:`shell.Service.header_format`): made once per receiver and phase."""
    return header_format + b',"kind":"delivery","receiver":%d,"phase":"%s"' % (
        receiver,
        phase.encode(),
    )


def delivery_of(
    head: bytes, packets: Iterable[bytes], lost: Iterable[int], dead: Iterable[int]
) -> bytes:
    """:func:`delivery` from its fields before the packets, encoded (``head``)."""
    return b'%s,"packets":[%s],"lost":%s,"dead":%s}' % (
        head,
        b",".join(packets),
        _ids(lost),
        _ids(dead),
    )


def _ids(ids: Iterable[int]) -> bytes:
    return orjson.dumps(sorted(ids)) if ids else b"[]"


def _text(payload: Any) -> str:
    """A payload as the JSON string it should be; bytes that are not UTF-8 stay visible as such."""
    raw = payload if isinstance(payload, bytes) else payload.to_bytes()
    return raw.decode("utf-8", "replace")
