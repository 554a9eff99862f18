"""Epochs in which every link of a phase passes: delivered with no per-packet decisions.

In such an epoch every receiver gets exactly one packet from each of its senders,
so a packet only joins its receivers' deliveries and its ``(stream, seq)`` is kept.
Whether an epoch is clean depends only on the links' models, so it is computed
ahead, vectorised, for a block of epochs, together with each stream's records as a
template that needs only the epoch and the seq. If something else happens in the
middle of a clean epoch (an agent dies, a packet is held), :meth:`CleanEpochs.go_slow`
hands what was kept to the lockstep core, which turns it into per-packet records
(``records``) and open epochs.

With a distance model on a state link (``gated``) an epoch is clean when every link
passes before its distance layers (known ahead) and every length is within its reach:
its packets are kept as they come (:meth:`CleanEpochs.gather`, in the order the core
routes them) and, once all are in, judged at once (:meth:`CleanEpochs.within_reach`:
``length <= reach`` per link, the reach computed ahead for the block) and handed out as a
clean epoch's (:meth:`CleanEpochs.open_gate`), or decided as the full path would, each
link's decision at its length (:meth:`CleanEpochs.judged`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, Literal, NamedTuple

import numpy as np
import numpy.typing as npt

from formation.keys import LEADER_ENDPOINT
from netem.links.capacity_network import Fixed
from netem.links.layer_stack import Outcome
from netem.links.models import LinkModel
from netem.proxy.records import (
    Ledger,
    Record,
    RecordTemplates,
    packet_json,
    queued,
)
from netem.proxy.routes import Link, Links, Phase

Deliver = Callable[[int, int, list[bytes]], None]  # (receiver, epoch, its packets)
# A link's capacity queues in closed form for ``size`` epochs from ``start``: False when it
# has none, None when they have no closed form there (its epochs are never clean).
Judge = Callable[[Link, int, int], Fixed | Literal[False] | None]


class CleanStream(NamedTuple):
    """Where one inbound key's packets go: its links, their receivers and models."""

    links: tuple[Link, ...]
    receivers: tuple[int, ...]
    models: tuple[LinkModel, ...]


@dataclass
class Gathering:
    """A clean epoch whose packets are coming: who sent, who got its delivery."""

    seqs: dict[int, int] = field(default_factory=dict)  # stream → seq of its packet
    packets: dict[int, bytes] = field(default_factory=dict)  # stream → its packet, encoded
    waiting: dict[int, list[bytes]] = field(default_factory=dict)  # receiver → packets so far
    delivered: set[int] = field(default_factory=set)  # receivers whose delivery went out
    payloads: dict[int, Any] = field(default_factory=dict)  # stream → payload (gated epochs)


class CleanEpochs:
    """One phase's streams, its clean epochs and the records of those epochs."""

    def __init__(
        self,
        streams: dict[int, CleanStream],
        need: dict[int, int],
        block: int = 1024,
        gate: bool = False,
        queues: Judge | None = None,
    ) -> None:
        self.streams = streams
        self.queues = queues  # the closed form of each link's capacity queues, if it has some
        self.gate = gate  # may judge distance models by the epoch's lengths (the state phase)
        self.links = tuple(link for s in streams.values() for link in s.links)  # reach's rows
        self._models = tuple(m for s in streams.values() for m in s.models)  # as links
        self._reach: dict[int, list[list[float]]] = {}  # block → epoch → each link's [m]
        self._base: dict[int, list[tuple[list[int], list[Outcome | None]]]] = {}  # (codes, table)
        self.need = need  # receiver → packets it gets in a clean epoch (one per sender)
        self.expected = len(streams)  # packets per epoch: one per stream
        self.gathering: dict[int, Gathering] = {}  # epoch → its packets so far
        self.done: set[int] = set()  # epochs finished here: no receiver has anything open
        self.slow: set[int] = set()  # epochs the node handles packet by packet
        self.receivers = {sid: s.receivers for sid, s in streams.items()}
        self._width = {sid: len(s.links) for sid, s in streams.items()}
        self.flags: dict[int, bool] = {}  # epoch → clean, for the blocks computed: a plain lookup
        self.chunks: list[bytes] = []  # encoded records of finished epochs, not yet published
        self.last_done = -1
        self._block = block
        # block → stream → its records' template: one for the block, or one per epoch
        self._blocks: dict[int, dict[int, bytes | list[bytes]]] = {}
        self._records = RecordTemplates({sid: s.links for sid, s in streams.items()})
        self.gated = False
        self.invalidate()

    def clean(self, epoch: int) -> bool:
        """Does every link of the phase pass packet 0 of ``epoch`` straight through?"""
        flag = self.flags.get(epoch)
        if flag is None:
            self._compute(epoch // self._block)
            flag = self.flags[epoch]
        return flag

    def mark_slow(self, epoch: int) -> None:
        """``epoch`` is handled packet by packet from now on (it counts as not clean)."""
        self.slow.add(epoch)
        self.flags[epoch] = False

    def take(self, stream: int, epoch: int, seq: int, payload: Any, deliver: Deliver) -> bool:
        """Add ``stream``'s packet to its receivers' deliveries of clean ``epoch``.

        ``deliver`` gets each receiver whose senders' packets are all here. True when
        this was the epoch's last packet: its records are then in :attr:`chunks`.
        A second packet of one stream's epoch (not one of ours) is ignored.
        """
        g = self._admit(stream, epoch, seq)
        if g is None:
            return False
        self._hand_out(g, stream, packet_json(stream, seq, epoch, 1, payload), epoch, deliver)
        if len(g.seqs) < self.expected:
            return False
        del self.gathering[epoch]
        self.finish(epoch, g.seqs)
        return True

    def _admit(self, stream: int, epoch: int, seq: int) -> Gathering | None:
        """``epoch``'s gathering with ``stream``'s seq noted; None for a stream's second packet."""
        g = self.gathering.get(epoch)
        if g is None:
            g = self.gathering[epoch] = Gathering()
        elif stream in g.seqs:
            return None
        g.seqs[stream] = seq
        return g

    def gather(self, stream: int, epoch: int, seq: int, payload: Any) -> Gathering | None:
        """Keep ``stream``'s packet of gated ``epoch``; its gathering once every stream's is in.

        A second packet of one stream's epoch (not one of ours) is ignored.
        """
        g = self._admit(stream, epoch, seq)
        if g is None:
            return None
        g.payloads[stream] = payload
        return g if len(g.seqs) >= self.expected else None

    def within_reach(self, epoch: int, lengths_m: list[float]) -> bool:
        """Does every link keep packet 0 of ``epoch`` at lengths ``lengths_m`` (one per link)?"""
        return all(d <= r for d, r in zip(lengths_m, self._reach_at(epoch), strict=True))

    def verdicts(self, epoch: int, lengths_m: list[float]) -> dict[Link, Outcome]:
        """Every link's decision of packet 0 of gated ``epoch`` at ``lengths_m``, each the
        model's ``decide(epoch, distance_m=length)``: within reach, the one before distance."""
        reach, k = self._reach_at(epoch), epoch // self._block
        j, out = epoch - k * self._block, {}
        for link, model, d, r, (codes, table) in zip(
            self.links, self._models, lengths_m, reach, self._base[k], strict=True
        ):
            kept = table[codes[j]] if d <= r else None
            out[link] = kept if kept is not None else model.decide(epoch, distance_m=d)
        return out

    def _reach_at(self, epoch: int) -> list[float]:
        """Each link's reach [m] at ``epoch`` (:meth:`LinkModel.reach`), one per link."""
        k = epoch // self._block
        rows = self._reach.get(k)
        if rows is None:
            self._compute(k)
            rows = self._reach[k]
        return rows[epoch - k * self._block]

    def judged(
        self,
        epoch: int,
        g: Gathering,
        verdicts: dict[Link, Outcome],
        ledger: Ledger,
        deliver: Callable[[int, int, list[bytes], list[int]], None],
    ) -> None:
        """Hand out gated ``epoch``, a link out of reach, as the full path would: each link's
        record and count in gathered order, a receiver's delivery once its senders are in."""
        self.go_slow(epoch)
        records, forwarded = ledger.decisions[("state", epoch)], ledger.forwarded
        boxes: dict[int, tuple[list[bytes], list[int]]] = {}
        for stream, seq in g.seqs.items():
            packet = None
            for link in self.streams[stream].links:
                cls, src, dst = link
                d = verdicts[link]
                records.append((src, dst, cls, epoch, seq, d))
                box = boxes.get(dst)
                if box is None:
                    box = boxes[dst] = ([], [])
                if d.delivered:  # passes (copies 1, no delay) or is dropped by distance
                    packet = packet or packet_json(src, seq, epoch, 1, g.payloads[stream])
                    box[0].append(packet)
                    forwarded[link] += 1
                else:
                    box[1].append(src)
                if len(box[0]) + len(box[1]) >= self.need[dst]:
                    deliver(dst, epoch, *box)

    def open_gate(self, epoch: int, g: Gathering, deliver: Deliver) -> None:
        """Hand out gated ``epoch``, all its links within reach, as a clean epoch (gathered order)."""
        del self.gathering[epoch]
        for stream, seq in g.seqs.items():
            packet = packet_json(stream, seq, epoch, 1, g.payloads[stream])
            self._hand_out(g, stream, packet, epoch, deliver)
        self.finish(epoch, g.seqs)

    def _hand_out(
        self, g: Gathering, stream: int, packet: bytes, epoch: int, deliver: Deliver
    ) -> None:
        """Add ``stream``'s packet to its receivers' deliveries; deliver the complete ones."""
        g.packets[stream] = packet
        waiting, need = g.waiting, self.need
        for r in self.receivers[stream]:
            got = waiting.get(r)
            if got is None:
                got = waiting[r] = []
            got.append(packet)
            if len(got) >= need[r]:
                del waiting[r]
                g.delivered.add(r)
                deliver(r, epoch, got)

    def go_slow(self, epoch: int) -> Gathering | None:
        """``epoch`` takes the full path from now on: what it gathered so far, if anything."""
        self.mark_slow(epoch)
        return self.gathering.pop(epoch, None)

    def finish(self, epoch: int, got: dict[int, int]) -> None:
        """Every stream's packet of clean ``epoch`` went out: encode their records."""
        k = epoch // self._block
        block = self._blocks.get(k)
        templates = block if block is not None else self._compute(k)
        j, width = epoch - k * self._block, self._width
        self.chunks.append(
            b",".join(
                [
                    (t if isinstance(t := templates[s], bytes) else t[j]) % ((epoch, q) * width[s])
                    for s, q in got.items()
                ]
            )
        )
        self.done.add(epoch)
        if epoch > self.last_done:
            self.last_done = epoch

    def invalidate(self) -> None:
        """A link's model changed: compute again."""
        self._blocks.clear()
        self._reach.clear()
        self._base.clear()
        self.flags.clear()
        self.gated = self.gate and any(m.ranged for s in self.streams.values() for m in s.models)

    def forwarded(self) -> dict[Link, int]:
        """Packets forwarded per link in finished epochs (one per stream each)."""
        return {link: len(self.done) for s in self.streams.values() for link in s.links}

    def last_taken(self) -> Iterator[tuple[Link, int]]:
        """Each link and the last epoch a packet of its stream took the clean path, if any."""
        for stream, s in self.streams.items():
            taken = [e for e, g in self.gathering.items() if stream in g.seqs]
            last = max([self.last_done, *taken])
            for link in s.links if last >= 0 else ():
                yield link, last

    def records(self, epoch: int, got: dict[int, int]) -> Iterator[tuple[Record, Link]]:
        """The decision record of every packet forwarded in ``epoch``, with its link."""
        for stream, seq in got.items():
            s = self.streams[stream]
            for link, model in zip(s.links, s.models, strict=True):
                cls, src, dst = link
                d = model.decide(epoch)
                fixed = self.queues(link, epoch, 1) if self.queues is not None else False
                if isinstance(fixed, Fixed):  # clean: its queues passed it in time
                    q = queued(d, fixed.reason[0], fixed.queue, 0, fixed.sojourn_ms[0])
                    yield (src, dst, cls, epoch, seq, q), link
                else:
                    yield (src, dst, cls, epoch, seq, d), link

    # internals ----------------------------------------------------------------------------------

    def _queued_ids(
        self,
        link: Link,
        start: int,
        size: int,
        codes: npt.NDArray[np.int64],
        table: list[Outcome | None],
        ids: npt.NDArray[np.int64],
    ) -> npt.NDArray[np.int64]:
        """``link``'s tail ids (:meth:`RecordTemplates.tail_id`) once its capacity queues judged what its model
        passed: its queues' decision where they pass it in time, -1 elsewhere."""
        assert self.queues is not None
        fixed = self.queues(link, start, size)
        if fixed is False:
            return ids  # no queue on it
        if fixed is None or self.gated:  # no closed form (or lengths to judge): the full path
            return np.full_like(ids, -1)
        in_time = (ids >= 0) & (np.asarray(fixed.reason) == "")
        out = np.full_like(ids, -1)
        if in_time.any():  # few distinct (decision, sojourn): one tail each
            sojourns, which = np.unique(np.asarray(fixed.sojourn_ms)[in_time], return_inverse=True)
            n = len(sojourns)
            keys, where = np.unique(codes[in_time] * n + which.reshape(-1), return_inverse=True)
            tails = []
            for key in keys.tolist():
                d = table[key // n]
                assert d is not None  # a passing decision (its tail id >= 0)
                tails.append(
                    self._records.tail_id(queued(d, "", fixed.queue, 0, float(sojourns[key % n])))
                )
            out[in_time] = np.asarray(tails, dtype=np.int64)[where.reshape(-1)]
        return out

    def _compute(self, k: int) -> dict[int, bytes | list[bytes]]:
        start, size = k * self._block, self._block
        clean = np.ones(size, dtype=np.bool_)
        ids_of: dict[int, npt.NDArray[np.int64]] = {}
        if self.gated:  # a model without distance layers reaches everywhere (inf)
            reach = np.array([m.reach(start, size) for m in self._models])  # (links, block)
            self._reach[k] = reach.T.tolist()
            self._base[k] = []
        for sid, s in self.streams.items():
            ids = np.empty((len(s.models), size), dtype=np.int64)
            for row, (link, model) in enumerate(zip(s.links, s.models, strict=True)):
                codes, table = model.coded(start, size, before_distance=self.gated)
                if self.gated:
                    self._base[k].append((codes.tolist(), table))
                ids[row] = np.array([self._records.tail_id(d) for d in table], dtype=np.int64)[
                    codes
                ]
                if self.queues is not None:
                    ids[row] = self._queued_ids(link, start, size, codes, table, ids[row])
            clean &= (ids >= 0).all(axis=0)
            ids_of[sid] = ids
        templates: dict[int, bytes | list[bytes]] = {}
        some = np.flatnonzero(clean)
        for sid, ids in ids_of.items():
            if not len(some):
                break  # no clean epoch in the block: no templates needed
            ids = np.where(clean, ids, ids[:, some[:1]])  # unclean epochs: never used
            if (ids == ids[:, :1]).all():  # the usual case: one template for the block
                templates[sid] = self._records.template(sid, tuple(ids[:, 0].tolist()))
            else:
                templates[sid] = [
                    self._records.template(sid, t) for t in zip(*ids.tolist(), strict=True)
                ]
        if len(self._blocks) >= 2:
            old = next(iter(self._blocks))
            del self._blocks[old]
            self._reach.pop(old, None)
            self._base.pop(old, None)
            for e in range(old * size, (old + 1) * size):
                self.flags.pop(e, None)
        self.flags.update(zip(range(start, start + size), clean.tolist(), strict=True))
        for e in self.slow:
            if start <= e < start + size:
                self.flags[e] = False
        self._blocks[k] = templates
        return templates


def clean_epochs(links: Links, queues: Judge | None = None) -> dict[Phase, CleanEpochs]:
    """Each phase's streams: an agent's states fan out on its out-links, a report goes to
    the leader, the leader's estimate for ``i`` to ``i``; ``queues``: the closed form of the
    links' capacity queues, if any."""

    def stream(chosen: list[Link]) -> CleanStream:
        models = tuple(links.models[link] for link in chosen)
        return CleanStream(tuple(chosen), tuple(dst for _, _, dst in chosen), models)

    agents, out_links, in_links = links.agents, links.out_links, links.in_links
    return {
        "state": CleanEpochs(
            {
                s: stream([("formation", s, d) for d in out_links[s]])
                for s in agents
                if out_links[s]
            },
            {j: len(in_links[j]) for j in agents},
            gate=True,
            queues=queues,
        ),
        "report": CleanEpochs(
            {s: stream([("report", s, LEADER_ENDPOINT)]) for s in agents},
            {LEADER_ENDPOINT: len(agents)},
            queues=queues,
        ),
        "estimate": CleanEpochs(
            {d: stream([("estimate", LEADER_ENDPOINT, d)]) for d in agents},
            dict.fromkeys(agents, 1),
            queues=queues,
        ),
    }
