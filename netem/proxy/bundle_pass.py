"""A bundle's parts passed at once: netem's lockstep core in its usual case, a bundle at a time.

A pool's states or reports and the leader's estimates come as one bundle of one phase and
epoch. When every link of every part passes it as it is and nobody is down, out, away or
queued (:meth:`BundlePass.take`), the bundle is handled in one loop: each part's packet goes
into its receivers' open epochs, its records are its stream's template, and the receivers it
completes close after the last part, in the order the parts completed them. That is what
handling the parts one by one (:meth:`LockstepCore.packet`) does: a close touches only its
receiver, so closing later changes no delivery, record or count. Anything else (a part netem
must decide, a duplicate, a final state) leaves the whole bundle to the one-by-one path.
"""

from __future__ import annotations

from collections import defaultdict
from itertools import repeat
from operator import itemgetter
from typing import Any

from formation.keys import LEADER_ENDPOINT
from netem.proxy.lockstep import LockstepCore
from netem.proxy.open_epochs import OpenEpoch
from netem.proxy.records import ONE_COPY, Escaped, Template, message_json
from netem.proxy.routes import Phase, Route

# A receiver whose epoch a part completed: its open epoch (None: the part is all it gets), the
# part's sender and packet.
_Complete = tuple[int, OpenEpoch | None, int, bytes]
_STREAM = itemgetter(0)  # of a part chosen
# The leader's estimates are passed this many parts at a time: a pool's batch goes out once
# its receivers are in, and the pool steps on the other core while netem passes the rest.
ESTIMATES_AT_ONCE = 32


class BundlePass:
    """The core's bundles in its usual case (:meth:`take`)."""

    def __init__(self, core: LockstepCore, estimates_at_once: int = ESTIMATES_AT_ONCE) -> None:
        self.core = core
        self.estimates_at_once = estimates_at_once
        # phase → the streams of the ends below, and each stream's source and receivers
        self._streams: dict[Phase, tuple[object, dict[int, tuple[int, tuple[int, ...]]]]] = {}
        # phase → each stream's last row and its records' template
        self._templates: dict[Phase, dict[int, tuple[Any, Template]]] = defaultdict(dict)

    def _ends(self, phase: Phase) -> dict[int, tuple[int, tuple[int, ...]]]:
        """Each of ``phase``'s streams' source and receivers."""
        streams = self.core.rows[phase].streams
        got = self._streams.get(phase)
        if got is None or got[0] is not streams:
            ends = {sid: (s.links[0][1], s.receivers) for sid, s in streams.items()}
            got = self._streams[phase] = (streams, ends)
        return got[1]

    def bundle(
        self, phase: Phase, epoch: int, agents: list[int], seqs: list[int], payloads: list[Any]
    ) -> None:
        """A bundle's parts of ``phase`` and ``epoch``: ``agents[i]``'s packet ``payloads[i]``
        with seq ``seqs[i]``, each as if it came alone (:meth:`LockstepCore.packet`), at once
        where it can (:meth:`take`)."""
        if self.take(phase, epoch, agents, seqs, payloads):
            return
        packet = self.core.packet
        for agent, seq, payload in zip(agents, seqs, payloads, strict=True):
            route: Route = (
                (phase, LEADER_ENDPOINT, agent) if phase == "estimate" else (phase, agent, 0)
            )
            packet(route, epoch, seq, payload)

    def usual(self) -> bool:
        """Nobody down, out or away, no queue, no distance to wait for: every part passes alone."""
        core = self.core
        return not (core.dead or core.out or core.away or core.queued or core.positions.needed)

    def take(
        self, phase: Phase, epoch: int, agents: list[int], seqs: list[int], payloads: list[Any]
    ) -> bool:
        """Handle a bundle's parts (``agents[i]``'s packet ``payloads[i]`` with seq ``seqs[i]``)
        at once; False, having changed nothing, where the parts must go one by one."""
        core = self.core
        if not self.usual() or len(set(agents)) != len(agents):
            return False
        rows = core.rows[phase]
        if phase == "state":
            if epoch >= core.epochs:
                return False  # final states: their senders' last
            last = core.last_state
            for a in agents:
                prev = last.get(a)
                if prev is not None and prev[0] >= epoch:
                    return False  # a state netem has handled already
        elif phase == "report":
            last_report = core.last_report
            if any(last_report.get(a, -1) >= epoch for a in agents):
                return False
        else:
            next_close, open_ = core.next_close, core.open
            for a in agents:
                if next_close[(phase, a)] > epoch or (phase, a, epoch) in open_:
                    return False  # this estimate came before
        queues = core.queues[phase]
        block, j = rows.at(epoch)
        chosen = []  # (stream, its row, seq, payload)
        for a, seq, payload in zip(agents, seqs, payloads, strict=True):
            got = block.get(a)
            if got is None:
                continue  # an agent without out-links: nothing to route
            row = got[0][j]
            if not row.plain or got[1] is not None or a in queues:
                return False
            chosen.append((a, row, seq, payload))
        if phase == "state":
            progress = core.progress
            if epoch > progress.epoch_seen:
                progress.epoch_seen = epoch
            last.update(zip(agents, zip(repeat(epoch), payloads), strict=True))
        elif phase == "report":
            last_report.update(zip(agents, repeat(epoch)))
        if phase == "estimate":
            step = self.estimates_at_once
            for i in range(0, len(chosen), step):
                self._pass(phase, epoch, chosen[i : i + step])
            core.progress.estimate_handled(epoch, len(agents))
        else:
            self._pass(phase, epoch, chosen)
        return True

    def _pass(self, phase: Phase, epoch: int, chosen: list[tuple[int, Any, int, Any]]) -> None:
        """:meth:`LockstepCore._pass` of each part, the closes after the last. A receiver with
        one sender gets no open epoch: its part is its delivery."""
        core = self.core
        ends = self._ends(phase)
        open_, counts = core.open, core._senders_count[phase]
        templates, known = core.templates[phase], self._templates[phase]
        complete: list[_Complete] = []
        recorded = []
        for stream, row, seq, payload in chosen:
            src, receivers = ends[stream]
            message = payload.json if type(payload) is Escaped else message_json(payload)
            packet = ONE_COPY % (src, seq, epoch, message)  # packet_json_of(.., 1, ..)
            for dst in receivers:
                key = (phase, dst, epoch)
                box = open_.get(key)
                if box is None:
                    if counts[dst] == 1:
                        complete.append((dst, None, src, packet))
                        continue
                    box = open_[key] = OpenEpoch()
                handled = box.handled
                handled.add(src)
                box.packets.append(packet)
                if len(handled) >= counts[dst]:
                    complete.append((dst, box, src, packet))
            decisions = row.decisions  # rows are shared: its template is the last one's
            template = known.get(stream)
            if template is None or template[0] is not decisions:
                template = known[stream] = (decisions, templates.row_template(stream, decisions))
            recorded.append((template[1], seq))
        core.passed_together[(phase, tuple(map(_STREAM, chosen)))] += 1
        core.records.add_many(phase, epoch, recorded)
        if complete:
            self._close(phase, epoch, complete)

    def _close(self, phase: Phase, epoch: int, complete: list[_Complete]) -> None:
        """:meth:`LockstepCore._close_complete` of the receivers ``complete``: one whose epoch
        is the next to close and the last open one goes out with the others in one call to
        the outbox, in turn; any other as the core closes it."""
        core = self.core
        next_close, open_ = core.next_close, core.open
        ready: list[tuple[int, list[bytes], list[int]]] = []
        for dst, box, src, packet in complete:
            at = (phase, dst)
            if (
                not core.delayed
                and next_close[at] == epoch
                and (phase, dst, epoch + 1) not in open_
            ):
                next_close[at] = epoch + 1
                if box is None:
                    ready.append((dst, [packet], []))
                else:
                    del open_[(phase, dst, epoch)]
                    ready.append((dst, box.packets, box.lost))
                continue
            self._deliver(phase, epoch, ready)
            ready = []
            if box is None:  # as the core would have kept it
                box = open_[(phase, dst, epoch)] = OpenEpoch()
                box.handled.add(src)
                box.packets.append(packet)
            core._close_complete(phase, epoch, [(dst, box)])
        self._deliver(phase, epoch, ready)

    def _deliver(
        self, phase: Phase, epoch: int, ready: list[tuple[int, list[bytes], list[int]]]
    ) -> None:
        """:meth:`LockstepCore._close` of receivers whose ``epoch`` is next and complete."""
        if not ready:
            return
        core = self.core
        core.outbox.deliver_many(phase, epoch, ready)
        key = (phase, epoch)
        closed = core.closed_count[key] = core.closed_count.get(key, 0) + len(ready)
        if closed >= (1 if phase == "report" else len(core.links.agents)):
            del core.closed_count[key]
            core.records.close(phase, epoch)


__all__ = ["BundlePass"]
