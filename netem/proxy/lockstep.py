"""netem's lockstep as pure logic: packets and deaths in, deliveries and records out.

docs/architecture.md "Time". A sender's packet of an epoch is decided on every link it takes
at once: its stream's row of the link models' decisions, taken ahead for a block of epochs
(:mod:`netem.proxy.decision_rows`), then the distance layers at the epoch's lengths, then the
capacity queues. A packet on a queue it shares with other links waits for the rest of its
phase, which the queues judge together (:mod:`netem.proxy.queued_phases`): the one place where
a phase's packets are decided together. Once every live sender's epoch-``k`` packet into a
receiver is decided, that receiver gets one delivery of the phase with the payloads passed,
unparsed: the delivery is also the epoch's close (:meth:`LockstepCore._close`, the one place).
Epochs into a receiver close in order. Delays are whole epochs: a delayed packet is held and
goes out with a later epoch's delivery. Once every live receiver of a phase's epoch is closed,
its records (a stream's template, epoch and seq: :class:`RecordTemplates`) join the next batch
(:meth:`LockstepCore.flush`). No network, clock or thread: the node calls the core under its
lock and publishes what it hands to the :class:`Outbox`, in order.
"""

from __future__ import annotations

import logging
from collections import Counter, defaultdict
from typing import Any

from formation.keys import LEADER_ENDPOINT
from netem.links.layer_stack import Outcome
from netem.links.models import LinkModel
from netem.proxy.decision_rows import Row, decision_rows
from netem.proxy.open_epochs import Delayed, OpenEpoch, Outbox, RecordBatches
from netem.proxy.positions import Positions
from netem.proxy.progress import Progress
from netem.proxy.queued_phases import PHASES, queued_phases
from netem.proxy.records import Ledger, Queued, RecordTemplates, packet_json
from netem.proxy.routes import Link, Links, Phase, Route
from netem.proxy.team_plan import Attendance

log = logging.getLogger("netem")
_NOBODY: set[int] = set()  # no sender dead


class LockstepCore(Attendance):
    """The lockstep state machine of one run: every phase, receiver and epoch."""

    def __init__(
        self, links: Links, epochs: int, progress: Progress, ledger: Ledger, outbox: Outbox
    ) -> None:
        super().__init__(links.team, epochs, links.agents)
        self.links = links
        self.progress, self.ledger, self.outbox = progress, ledger, outbox
        self.open: dict[tuple[Phase, int, int], OpenEpoch] = {}  # (phase, receiver, epoch)
        self.delayed: dict[tuple[Phase, int, int], list[Delayed]] = defaultdict(list)
        self.next_close: dict[tuple[Phase, int], int] = defaultdict(int)
        self.closed_count: dict[tuple[Phase, int], int] = defaultdict(int)
        self.rows = decision_rows(links)
        self._senders_count = {
            phase: {r: len(links.senders(phase, r)) for r in [LEADER_ENDPOINT, *links.agents]}
            for phase in PHASES
        }
        self.templates = {
            phase: RecordTemplates({sid: s.links for sid, s in rows.streams.items()})
            for phase, rows in self.rows.items()
        }
        self.records = RecordBatches(outbox, epochs, self.templates)
        self.passed: Counter[tuple[Phase, int]] = Counter()  # packets every link passed as is
        self.passed_together: Counter[tuple[Phase, tuple[int, ...]]] = Counter()  # by bundle
        self.positions = Positions(links)  # for distance models: read from the states
        self.last_report: dict[int, int] = {}  # agent → epoch of its last report handled
        # Packets the models passed onto a capacity queue or the air, until their phase's are in.
        self.queued = queued_phases(links, self.positions)
        self.queues: dict[Phase, set[int]] = {}  # the streams a queue may serve, by phase
        self._find_queues()

    # -- events in ----------------------------------------------------------------------------
    def packet(self, route: Route, epoch: int, seq: int, payload: Any) -> None:
        """A sender's packet of ``epoch`` on ``route``, its seq and payload (bytes or ZBytes)."""
        if not self.positions.needed:
            self._packet(route, epoch, seq, payload)
        elif self.positions.admit(route, epoch, seq, payload, self.dead_at(epoch)):
            self._packet(route, epoch, seq, payload)  # else held until the positions come
        if self.positions.ready:
            self._release_held()

    def _release_held(self, gone: int | None = None) -> None:
        for held in self.positions.release(gone):
            self._packet(*held)

    def _packet(self, route: Route, epoch: int, seq: int, payload: Any) -> None:
        kind, source, dst = route
        if kind == "state":
            self._state(source, epoch, seq, payload)
        elif kind == "report":
            self._report(source, epoch, seq, payload)
        else:
            self._route("estimate", dst, epoch, seq, payload)
            self.progress.estimate_handled(epoch)

    def _state(self, source: int, epoch: int, seq: int, payload: Any) -> None:
        progress = self.progress
        if epoch > progress.epoch_seen:
            progress.epoch_seen = epoch
        self.last_state[source] = (epoch, payload)
        if epoch >= self.epochs:
            progress.final_state(source)
        elif self.out and source in self.out.get(epoch, ()):
            self.leave(source, epoch)  # its last state: kept (for a restart), not forwarded
            progress.final_state(source)  # what netem/final answers a leaving agent
        elif source in self.rows["state"].streams:
            self._route("state", source, epoch, seq, payload)

    def _report(self, source: int, epoch: int, seq: int, payload: Any) -> None:
        if self.out and source in self.out.get(epoch, ()):
            return  # not one of ours: that agent is out of the team at this epoch
        self.last_report[source] = epoch
        self._route("report", source, epoch, seq, payload)
        if LEADER_ENDPOINT in self.dead:
            self._close_estimates_without_leader(source)

    def sender_died(self, agent: int) -> None:
        """``agent`` is gone (0: the leader): its packets count as lost, nobody waits for them."""
        if agent in self.progress.final_states or agent in self.away:
            return  # its part is over, or it is out by the scenario's events
        if agent in self.dead and self.revive.pop(agent, None) is None:
            return  # already down; else it died again after coming back
        log.warning("%s is gone: its packets count as lost from now on", _name(agent))
        self.dead.add(agent)
        self._release_held(agent)  # nobody waits for its positions
        if agent == LEADER_ENDPOINT:
            for j in self.links.agents:
                self._close_estimates_without_leader(j)
            return
        for j in self.links.out_links[agent]:
            self._try_close("state", j)
        self._try_close("report", LEADER_ENDPOINT)

    def rejoin(self, sender: int) -> int:
        """``sender`` (0: the leader) is back: the epoch from which it takes part again.

        No packet of that epoch has been handled yet (the newest state or report seen,
        plus one), so every receiver of it still waits for the sender's packets.
        """
        planned = self.planned_start(sender)
        if planned is not None:
            return self._rejoin_planned(sender, planned)
        if sender not in self.dead:
            self.sender_died(sender)  # back before netem saw it go: down until it rejoins
        if sender in self.revive:
            return self.revive[sender]
        newest = max([self.progress.epoch_seen, *self.last_report.values()])
        epoch = min(newest + 1, self.epochs)
        self.revive[sender] = epoch
        if sender != LEADER_ENDPOINT:  # the leader just ignores the report deliveries before
            self._skip_to(sender, epoch)
        log.warning("%s is back: it takes part again from epoch %d", _name(sender), epoch)
        return epoch

    def _rejoin_planned(self, agent: int, epoch: int) -> int:
        """A scheduled (re)start: its receivers' epochs before ``epoch`` are not its own."""
        if self.rejoined.get(agent) == epoch:
            return epoch  # asked again
        self.start(agent, epoch)
        self.progress.final_states.discard(agent)  # its next last state is still to come
        self._skip_to(agent, epoch)
        for phase in ("state", "estimate"):  # what is complete already goes out now
            self._try_close(phase, agent)
        log.warning("agent %d takes part from epoch %d (a scenario event)", agent, epoch)
        return epoch

    def _skip_to(self, agent: int, epoch: int) -> None:
        for phase in ("state", "estimate"):
            key: tuple[Phase, int] = (phase, agent)
            self.next_close[key] = max(self.next_close[key], epoch)
            for stale in [e for (p, r, e) in self.open if p == phase and r == agent]:
                if stale < epoch:
                    del self.open[(phase, agent, stale)]

    def _close_estimates_without_leader(self, agent: int) -> None:
        """The leader is down: ``agent``'s estimate epochs close empty up to its last report."""
        last = self.last_report.get(agent, -1)
        key: tuple[Phase, int, int]
        for epoch in range(self.next_close[("estimate", agent)], min(last + 1, self.epochs)):
            if not self.is_dead(LEADER_ENDPOINT, epoch) or self.is_dead(agent, epoch):
                break
            key = ("estimate", agent, epoch)
            if key not in self.open:
                self.open[key] = OpenEpoch()
                self.progress.estimate_skipped(epoch)
        self._try_close("estimate", agent)

    def models_changed(self) -> None:
        """A link's model or queue changed: its decisions are taken again."""
        for rows in self.rows.values():
            rows.invalidate()
        self.positions.refresh()
        self._find_queues()

    def _find_queues(self) -> None:
        served = set() if self.links.capacity is None else self.links.capacity.first_epoch
        aired = frozenset() if self.links.air is None else self.links.air.phases
        self.queues = {
            phase: {
                sid
                for sid, s in rows.streams.items()
                if phase in aired or any((a, b) in served for _, a, b in s.links)
            }
            for phase, rows in self.rows.items()
        }

    def flush(self) -> None:
        """Hand out the records of every epoch closed since the last flush."""
        self.records.flush()

    # -- state out ----------------------------------------------------------------------------
    def finished(self) -> bool:
        return self.progress.finished(self.gone())

    def forwarded(self) -> dict[Link, int]:
        """Delivered packets per link (for the final status)."""
        total = self.ledger.forwarded.copy()
        passed = self.passed.copy()
        for (phase, streams), n in self.passed_together.items():
            passed.update(dict.fromkeys([(phase, stream) for stream in streams], n))
        for (phase, stream), n in passed.items():
            total.update(dict.fromkeys(self.rows[phase].streams[stream].links, n))
        return dict(total)

    # -- deciding -----------------------------------------------------------------------------
    def _route(self, phase: Phase, stream: int, epoch: int, seq: int, payload: Any) -> None:
        """Decide ``stream``'s packet of ``epoch`` on each of its links, put it in its receivers'
        open epochs, record it, and close the receivers it completes."""
        rows = self.rows[phase]
        s = rows.streams[stream]
        row, reach = rows.row(stream, epoch)
        decisions = row.decisions
        if reach is not None:  # a distance model: a link out of reach is the model's to judge
            decisions = self._at_lengths(s.links, s.models, epoch, decisions, reach)
        # With someone down or out a receiver may need nothing of it: out, or closed without it
        # (a dead sender's packet held for positions comes after its receivers went on).
        skip = bool(self.dead or self.out)
        next_close, q, ledger, open_ = self.next_close, self.queued, self.ledger, self.open
        if (
            row.plain
            and decisions is row.decisions
            and not skip
            and stream not in self.queues[phase]
        ):
            self._pass(phase, stream, epoch, seq, payload, row)  # every link passes it as it is
            return
        final: list[Outcome | Queued | None] = []  # each link's decision, None: not recorded
        boxes: list[tuple[int, OpenEpoch]] = []
        packet = b""
        for link, dst, d in zip(s.links, s.receivers, decisions, strict=True):
            if skip and (
                next_close[(phase, dst)] > epoch or (phase != "report" and self.is_dead(dst, epoch))
            ):
                final.append(None)
                continue
            if d is None:
                d = self._decide(link, epoch)
            v: Outcome | Queued = d
            box = open_.get((phase, dst, epoch))
            if box is None:
                box = open_[(phase, dst, epoch)] = OpenEpoch()
            src = link[1]
            box.handled.add(src)
            boxes.append((dst, box))
            if d.delivered and q is not None:
                judged = q.at_once(phase, epoch, link, d)
                if judged is None:  # judged with the rest of its phase (_judge_when_complete)
                    q.hold(phase, epoch, (link, seq, payload, d))
                    final.append(None)
                    continue
                v = judged
            final.append(v)
            if v.delivered and v.delay_epochs == 0 and v.copies == 1:
                if not packet:
                    packet = packet_json(src, seq, epoch, 1, payload)
                box.packets.append(packet)
                ledger.forwarded[link] += 1
            else:
                self._apply(box, phase, link, epoch, seq, payload, v)
        self._record(phase, stream, epoch, seq, final)
        self._close_complete(phase, epoch, boxes)

    def _pass(
        self, phase: Phase, stream: int, epoch: int, seq: int, payload: Any, row: Row
    ) -> None:
        """:meth:`_route` for a packet every link passes as it is, nobody out: its records are the
        row's template, its count the stream's (:meth:`forwarded`)."""
        s = self.rows[phase].streams[stream]
        src = s.links[0][1]
        packet = packet_json(src, seq, epoch, 1, payload)
        open_, counts = self.open, self._senders_count[phase]
        # In the usual case only a receiver this packet completes can close: the others are
        # not looked at again.
        usual = not (self.away or self.queued)
        boxes = []
        for dst in s.receivers:
            key = (phase, dst, epoch)
            box = open_.get(key)
            if box is None:
                box = open_[key] = OpenEpoch()
            handled = box.handled
            handled.add(src)
            box.packets.append(packet)
            if not usual or len(handled) >= counts[dst]:
                boxes.append((dst, box))
        self.passed[(phase, stream)] += 1
        self.records.add(
            phase, epoch, self.templates[phase].row_template(stream, row.decisions), seq
        )
        if boxes:
            self._close_complete(phase, epoch, boxes)

    def _record(
        self,
        phase: Phase,
        stream: int,
        epoch: int,
        seq: int,
        final: list[Outcome | Queued | None],
    ) -> None:
        """The records of ``stream``'s packet as ``final`` decided it, by a template."""
        templates = self.templates[phase]
        ids = tuple(-1 if v is None else templates.judgement_id(v) for v in final)
        template = templates.template(stream, ids)
        if template.source:
            self.records.add(phase, epoch, template, seq)

    def _close_complete(self, phase: Phase, epoch: int, boxes: list[tuple[int, OpenEpoch]]) -> None:
        """Close the receivers whose open ``epoch`` got its last packet: at once in the usual
        case (everyone up, in turn, nothing waiting for the queues), else in order."""
        usual = not (self.dead or self.out or self.away or self.queued)
        counts, next_close, open_ = self._senders_count[phase], self.next_close, self.open
        for dst, box in boxes:
            if usual:
                if len(box.handled) < counts[dst]:
                    continue
                if next_close[(phase, dst)] == epoch:
                    self._close(phase, dst, epoch, box, _NOBODY)
                    if (phase, dst, epoch + 1) not in open_:
                        continue  # nothing later can be complete
                self._try_close(phase, dst)
            elif self._all_handled(box, self.links.senders(phase, dst), epoch):
                self._try_close(phase, dst)

    def _at_lengths(
        self,
        links: tuple[Link, ...],
        models: tuple[LinkModel, ...],
        epoch: int,
        decisions: tuple[Outcome | None, ...],
        reach: list[float],
    ) -> tuple[Outcome | None, ...]:
        """The row's decisions at the epoch's lengths: within reach the row's (before the
        distance layers), else the model's at that length."""
        out: list[Outcome | None] | None = None
        length = self.positions.length
        for i, (link, model, r) in enumerate(zip(links, models, reach, strict=True)):
            d = length(link, epoch)
            if d is not None and not d <= r:
                if out is None:
                    out = list(decisions)
                out[i] = model.decide(epoch, distance_m=d)
        return decisions if out is None else tuple(out)

    def _decide(self, link: Link, epoch: int) -> Outcome:
        """The model's own decision of ``link``'s packet of ``epoch`` (its row could not say)."""
        return self.links.models[link].decide(epoch, distance_m=self.positions.length(link, epoch))

    def _apply(
        self,
        box: OpenEpoch,
        phase: Phase,
        link: Link,
        epoch: int,
        seq: int,
        payload: Any,
        d: Outcome | Queued,
    ) -> None:
        """Put a packet in ``box`` as ``d`` says (or hold it for a later epoch)."""
        _, src, dst = link
        if not d.delivered:
            box.lost.append(src)
        elif d.delay_epochs == 0:
            box.packets.append(packet_json(src, seq, epoch, d.copies, payload))
            self.ledger.forwarded[link] += d.copies
        else:
            box.lost.append(src)  # lost for this epoch; arrives with a later one
            due = epoch + d.delay_epochs
            if not (self.out and dst in self.out.get(due, ())):  # else its receiver is out then
                self.delayed[(phase, dst, due)].append(
                    Delayed(link, d.copies, packet_json(src, seq, epoch, d.copies, payload))
                )

    def _judge_when_complete(self, phase: Phase, epoch: int) -> bool:
        """Once every live receiver of ``epoch`` of ``phase`` has all its packets, and every
        phase before it in virtual time has closed (the queues serve phases in order), let the
        queues judge the held packets and close what can close (True); else False."""
        q = self.queued
        assert q is not None  # only held with queues
        if not all(self._settled(phase, r, epoch, True) for r in q.receivers(phase)):
            return False
        if not all(
            self._settled(p, r, e) for p, e in q.earlier(phase, epoch) for r in q.receivers(p)
        ):
            return False
        for link, seq, payload, d in q.judge(phase, epoch):
            _, src, dst = link
            self.records.add(phase, epoch, self.templates[phase].single(src, dst, d), seq)
            self._apply(self.open[(phase, dst, epoch)], phase, link, epoch, seq, payload, d)
        for r in q.receivers(phase):  # those that waited for the queues, the caller's too
            self._try_close(phase, r)
        for later_phase, later in q.waiting():  # a later phase waiting for this one: its turn
            if (later_phase, later) in q:
                for r in q.receivers(later_phase):
                    self._try_close(later_phase, r)
        return True

    def _settled(self, phase: Phase, r: int, epoch: int, complete: bool = False) -> bool:
        """Receiver ``r`` closed ``epoch`` of ``phase``, or needs nothing of it (out, dead), or
        (``complete``) has all its packets."""
        if self.next_close[(phase, r)] > epoch or r in self.away or self.is_dead(r, epoch):
            return True
        box = self.open.get((phase, r, epoch)) if complete else None
        return box is not None and self._all_handled(box, self.links.senders(phase, r), epoch)

    def _all_handled(self, box: OpenEpoch, senders: list[int], epoch: int) -> bool:
        if not self.dead and epoch not in self.out:  # counting is enough: only its senders send
            return len(box.handled) >= len(senders)
        dead = self.dead_at(epoch)
        return all(s in box.handled for s in senders if s not in dead)

    # -- closing ------------------------------------------------------------------------------
    def _try_close(self, phase: Phase, receiver: int) -> None:
        """Close ``receiver``'s epochs of ``phase`` in order, as far as they are complete."""
        if receiver in self.away:
            return  # out by the scenario's events, its next process not up: it would miss it
        senders = self.links.senders(phase, receiver)
        while True:
            epoch = self.next_close[(phase, receiver)]
            if self.out and epoch < self.epochs and receiver in self.out.get(epoch, ()):
                self.next_close[(phase, receiver)] = self.back(receiver, epoch)  # out: skip
                continue
            dead = self.dead_at(epoch)
            box = self._complete(phase, receiver, epoch, senders, dead)
            if box is None:
                return
            if self.queued is not None and (phase, epoch) in self.queued.held:
                if not self._judge_when_complete(phase, epoch):
                    return  # the rest of the phase's queued packets are still to come
                continue  # judged: every receiver of the phase was tried again, this one too
            self._close(phase, receiver, epoch, box, dead)

    def _complete(
        self, phase: Phase, receiver: int, epoch: int, senders: list[int], dead: set[int]
    ) -> OpenEpoch | None:
        """``receiver``'s open ``epoch`` of ``phase`` if every live sender's packet is handled,
        an empty one if every sender is dead, else None."""
        box = self.open.get((phase, receiver, epoch))
        if box is not None:
            return box if self._all_handled(box, senders, epoch) else None
        # Not the estimates: with the leader down, each closes when its report comes.
        if epoch >= self.epochs or phase == "estimate" or any(s not in dead for s in senders):
            return None
        return OpenEpoch()

    def _close(
        self, phase: Phase, receiver: int, epoch: int, box: OpenEpoch, dead: set[int]
    ) -> None:
        """Deliver ``box`` with what was delayed to ``epoch``; once every live receiver of the
        epoch is closed, its records join the phase's batch."""
        self.open.pop((phase, receiver, epoch), None)
        if self.delayed:
            for h in self.delayed.pop((phase, receiver, epoch), ()):
                self.ledger.forwarded[h.link] += h.copies
                box.packets.append(h.packet)
        gone = [s for s in self.links.senders(phase, receiver) if s in dead] if dead else []
        self.outbox.deliver(phase, receiver, epoch, box.packets, box.lost, gone)
        self.next_close[(phase, receiver)] = epoch + 1
        key = (phase, epoch)
        closed = self.closed_count[key] = self.closed_count.get(key, 0) + 1
        receivers = 1 if phase == "report" else len(self.links.agents)
        if dead and phase != "report":
            receivers -= len(dead) - (LEADER_ENDPOINT in dead)
        if closed >= receivers:
            del self.closed_count[key]
            self.records.close(phase, epoch)


def _name(sender: int) -> str:
    return "the leader" if sender == LEADER_ENDPOINT else f"agent {sender}"
