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
from itertools import chain
from operator import itemgetter
from typing import Any, NamedTuple

import numpy as np
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

    Shared, as the models' decisions are (so :func:`judgement_json` encodes each once): a link's
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


def _judgement_json(d: Outcome | Queued) -> bytes:
    """A decision as the batch's ``Judgement`` it is recorded by."""
    fields = {
        "verdict": d.verdict,
        "delay_epochs": d.delay_epochs,
        "delay_ms": float(d.delay_ms),
        "model": d.model,
        "state": d.state,
    }
    if isinstance(d, Queued):
        fields.update(queue=d.queue, queue_depth=d.queue_depth, sojourn_ms=d.sojourn_ms)
    return orjson.dumps(fields)


_JUDGEMENT_JSON: dict[int, tuple[Outcome | Queued, bytes]] = {}  # by id; the entry keeps d alive


def judgement_json(d: Outcome | Queued) -> bytes:
    """A decision's ``Judgement``, encoded once (decisions are shared objects: a model
    memoises them per block)."""
    got = _JUDGEMENT_JSON.get(id(d))
    if got is None or got[0] is not d:
        if len(_JUDGEMENT_JSON) > 100_000:
            _JUDGEMENT_JSON.clear()
        got = _JUDGEMENT_JSON[id(d)] = (d, _judgement_json(d))
    return got[1]


class Template(NamedTuple):
    """The records of a stream's packet but its epoch and seq: per link recorded, its ends and
    its decision (an id of :meth:`RecordTemplates.judgement_id`)."""

    source: tuple[int, ...]
    target: tuple[int, ...]
    judgement: tuple[int, ...]
    source_json: bytes  # ``source`` in a JSON array, without its brackets
    target_json: bytes


def template_of(
    source: tuple[int, ...], target: tuple[int, ...], judgement: tuple[int, ...]
) -> Template:
    """A :class:`Template` of these records."""
    return Template(
        source, target, judgement, orjson.dumps(source)[1:-1], orjson.dumps(target)[1:-1]
    )


class RecordTemplates:
    """The records of each stream's packet (one per link) as a :class:`Template`: a packet's
    records are its template, its epoch and its seq, not encoded one by one.

    A decision's judgement gets an id (:meth:`judgement_id`, its JSON in :attr:`judgements`);
    a template is one per stream and tuple of its links' ids.
    """

    def __init__(self, streams: dict[int, tuple[Link, ...]]) -> None:
        self._ends = {sid: [(src, dst) for _, src, dst in links] for sid, links in streams.items()}
        self._ids: dict[bytes, int] = {}
        self.judgements: list[bytes] = []  # by id: each judgement's JSON
        self._of: dict[int, tuple[Outcome | Queued, int]] = {}  # by id; the entry keeps d alive
        self._templates: dict[tuple[int, tuple[int, ...]], Template] = {}
        self._rows: dict[int, tuple[tuple[Outcome | Queued | None, ...], Template]] = {}

    def judgement_id(self, d: Outcome | Queued) -> int:
        """An id of a decision's judgement."""
        known = self._of.get(id(d))
        if known is not None and known[0] is d:
            return known[1]
        encoded = judgement_json(d)
        got = self._ids.get(encoded)
        if got is None:
            got = self._ids[encoded] = len(self.judgements)
            self.judgements.append(encoded)
        if len(self._of) > 100_000:  # a backlog's sojourns are all different: kept few
            self._of.clear()
        self._of[id(d)] = (d, got)
        return got

    def row_template(self, stream: int, row: tuple[Outcome | Queued | None, ...]) -> Template:
        """The template of ``stream``'s packet with every link recorded as ``row`` decides
        (:meth:`template`), kept by the row (rows are shared objects)."""
        known = self._rows.get(id(row))
        if known is not None and known[0] is row:
            return known[1]
        got = self.template(stream, tuple(-1 if d is None else self.judgement_id(d) for d in row))
        if len(self._rows) > 100_000:
            self._rows.clear()
        self._rows[id(row)] = (row, got)  # the entry keeps the row alive: its id is not reused
        return got

    def template(self, stream: int, ids: tuple[int, ...]) -> Template:
        """The records of ``stream``'s packet, its links' judgements ``ids`` (-1: a link not
        recorded with it)."""
        got = self._templates.get((stream, ids))
        if got is None:
            if len(self._templates) > 100_000:  # queues' sojourns make many: kept few
                self._templates.clear()
            kept = [(end, j) for end, j in zip(self._ends[stream], ids, strict=True) if j >= 0]
            got = self._templates[(stream, ids)] = template_of(
                tuple(src for (src, _), _ in kept),
                tuple(dst for (_, dst), _ in kept),
                tuple(j for _, j in kept),
            )
        return got

    def single(self, source: int, target: int, d: Outcome | Queued) -> Template:
        """The template of one link's record."""
        return template_of((source,), (target,), (self.judgement_id(d),))


# A packet's records as a batch keeps them until it goes out: (template, seq).
Recorded = tuple[Template, int]


def batch_body(
    phase: str, judgements: list[bytes], epochs: list[tuple[int, list[Recorded]]]
) -> bytes:
    """A ``DecisionBatch``'s fields after its header: the records of each ``(epoch, packets)``
    as columns, their judgements (ids into ``judgements``) renumbered to the batch's own."""
    packets = list(chain.from_iterable(ps for _, ps in epochs))
    templates = list(map(_TEMPLATE, packets))
    counts = np.fromiter(map(len, map(_SOURCE, templates)), np.intp, len(templates))
    per_epoch = np.fromiter((len(ps) for _, ps in epochs), np.intp, len(epochs))
    epoch = np.repeat(np.repeat([k for k, _ in epochs], per_epoch), counts)
    seq = np.repeat(np.fromiter(map(_SEQ, packets), np.int64, len(packets)), counts)
    ids = np.fromiter(chain.from_iterable(map(_JUDGEMENT, templates)), np.int64, int(counts.sum()))
    # np.unique's answer, by counting: the ids are few and small
    used = np.flatnonzero(np.bincount(ids, minlength=len(judgements)))
    renumbered = np.zeros(len(judgements), np.int64)
    renumbered[used] = np.arange(len(used))
    index = renumbered[ids]
    source = orjson.Fragment(b"[%s]" % b",".join(map(_SOURCE_JSON, templates)))
    target = orjson.Fragment(b"[%s]" % b",".join(map(_TARGET_JSON, templates)))
    return _body(phase, [judgements[j] for j in used], source, target, epoch, seq, index)


_TEMPLATE, _SEQ = itemgetter(0), itemgetter(1)  # of a Recorded
_SOURCE, _JUDGEMENT = itemgetter(0), itemgetter(2)  # of a Template
_SOURCE_JSON, _TARGET_JSON = itemgetter(3), itemgetter(4)


def _body(
    phase: str,
    judgements: list[bytes],
    source: Any,
    target: Any,
    epoch: Any,
    seq: Any,
    index: Any,
) -> bytes:
    columns = {"source": source, "target": target, "epoch": epoch, "seq": seq, "judgement": index}
    return b'"kind":"decisions","phase":"%s","judgements":[%s],"records":%s}' % (
        phase.encode(),
        b",".join(judgements),
        orjson.dumps(columns, option=orjson.OPT_SERIALIZE_NUMPY),
    )


def records_body(phase: str, records: Iterable[Record]) -> bytes:
    """:func:`batch_body` of records one by one (realtime's, the queues' judged together)."""
    ids: dict[bytes, int] = {}
    source, target, epoch, seq, index = [], [], [], [], []
    for s, t, _, e, q, d in records:
        source.append(s)
        target.append(t)
        epoch.append(e)
        seq.append(q)
        encoded = judgement_json(d)
        index.append(ids.setdefault(encoded, len(ids)))
    return _body(phase, list(ids), source, target, epoch, seq, index)


def decision_batch(header: dict[str, Any], phase: str, records: Iterable[Record]) -> bytes:
    """A ``DecisionBatch`` payload: ``header`` from ``Service.header``, one record each."""
    return decision_batch_of(header, records_body(phase, records))


def decision_batch_of(header: dict[str, Any], body: bytes) -> bytes:
    """A ``DecisionBatch`` payload from its fields after the header (:func:`batch_body`)."""
    return b"%s,%s" % (orjson.dumps(header)[:-1], body)


def packet_json(source: int, seq: int, sent_epoch: int, copies: int, payload: Any) -> bytes:
    """One packet of a ``Delivery``, encoded once however many receivers' deliveries carry it."""
    return packet_json_of(source, seq, sent_epoch, copies, message_json(payload))


class Escaped:
    """A payload that came as the JSON string a ``DeliveredPacket``'s ``message`` holds
    (a bundle's part, :mod:`netem.bundle_parts`): ``json`` is that string, as orjson writes it."""

    __slots__ = ("json",)

    def __init__(self, json: bytes) -> None:
        self.json = json

    def to_bytes(self) -> bytes:
        """The payload itself (as a received ``ZBytes`` gives it)."""
        text: str = orjson.loads(self.json)
        return text.encode()


def message_json(payload: Any) -> bytes:
    """A payload as the JSON string a ``DeliveredPacket``'s ``message`` holds; the last one is
    kept, as a state is delivered on each of its out-links in turn."""
    global _LAST_MESSAGE
    if type(payload) is Escaped:
        return payload.json
    last = _LAST_MESSAGE  # one read: another thread may replace it
    if last[0] is payload:  # it holds that payload: its id is not reused
        return last[1]
    message = orjson.dumps(_text(payload))
    _LAST_MESSAGE = (payload, message)
    return message


_LAST_MESSAGE: tuple[Any, bytes] = (None, b"")


# A packet of one copy (packet_json_of), ``%d`` for its source, seq and sent epoch, ``%s`` for
# its message.
ONE_COPY = b'{"source":%d,"seq":%d,"sent_epoch":%d,"copies":1,"message":%s}'


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
