"""netem's lockstep as pure logic: packets and deaths in, deliveries and records out.

docs/architecture.md "Time": for each packet netem asks the link's model (keyed by seed,
link and epoch, so any process gets the same verdict). Once every live sender's
epoch-``k`` packet into a receiver is handled, that receiver gets one delivery of the
phase with the payloads passed, unparsed: the delivery is also the epoch's close.
Epochs into a receiver close in order. Delays are whole epochs: a delayed packet is
held and goes out with a later epoch's delivery. Once every live receiver of a phase's
epoch is closed, that epoch's decision records go out in one batch.

An epoch in which every link of the phase passes takes the clean path
(:mod:`netem.proxy.clean_epochs`): no per-packet decision, records spliced from templates and
published together (:meth:`LockstepCore.flush_clean`). No network, clock or thread: the node
calls the core under its lock and publishes what it hands to the :class:`Outbox`, in order.
"""

from __future__ import annotations

import logging
from collections import defaultdict
from typing import Any

from formation.keys import LEADER_ENDPOINT
from netem.links.layer_stack import Outcome
from netem.proxy.clean_epochs import CleanEpochs, Deliver, clean_epochs
from netem.proxy.open_epochs import Delayed, OpenEpoch, Outbox
from netem.proxy.positions import Positions
from netem.proxy.progress import Progress
from netem.proxy.queued_phases import queued_phases
from netem.proxy.records import Ledger, Queued, packet_json
from netem.proxy.routes import Link, LinkClass, Links, Phase, Route
from netem.proxy.team_plan import Attendance

log = logging.getLogger("netem")
FLUSH_CHUNKS = 64  # clean epochs' records per batch (at least one batch per 0.2 s wake-up)


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
        self.clean: dict[Phase, CleanEpochs] = {}  # none until setup_clean
        self._clean_deliver: dict[Phase, Deliver] = {}
        self.positions = Positions(links)  # for distance models: read from the states
        self.last_report: dict[int, int] = {}  # agent → epoch of its last report handled
        # Packets the models passed onto a capacity queue or the air, until their phase's are in.
        self.queued = queued_phases(links, self.positions)

    def setup_clean(self) -> None:
        """Take clean epochs on the clean path from now on: with capacity queues, those in which
        every queue a packet meets has a closed form and passes it in time (a queue judging a
        phase's packets together has none: they take the full path)."""
        judge = self.queued.closed_form if self.queued is not None else None
        self.clean = clean_epochs(self.links, judge)
        self._clean_deliver = {phase: self._clean_delivery(phase) for phase in self.clean}

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
            self._estimate(dst, epoch, seq, payload)

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
        elif not self._forward_clean("state", source, epoch, seq, payload):
            self._route_state(source, epoch, seq, payload)

    def _report(self, source: int, epoch: int, seq: int, payload: Any) -> None:
        if self.out and source in self.out.get(epoch, ()):
            return  # not one of ours: that agent is out of the team at this epoch
        self.last_report[source] = epoch
        if self._forward_clean("report", source, epoch, seq, payload):
            return
        box = self._route_packet("report", "report", source, LEADER_ENDPOINT, payload, epoch, seq)
        if self._all_handled(box, self.links.agents, epoch):
            self._try_close("report", LEADER_ENDPOINT)
        if LEADER_ENDPOINT in self.dead:
            self._close_estimates_without_leader(source)

    def _estimate(self, dst: int, epoch: int, seq: int, payload: Any) -> None:
        if not self._forward_clean("estimate", dst, epoch, seq, payload) and not (
            (dst in self.dead or self.out) and self.is_dead(dst, epoch)
        ):
            self._route_packet("estimate", "estimate", LEADER_ENDPOINT, dst, payload, epoch, seq)
            self._try_close("estimate", dst)
        self.progress.estimate_handled(epoch)

    def _route_state(
        self,
        source: int,
        epoch: int,
        seq: int,
        payload: Any,
        verdicts: dict[Link, Outcome] | None = None,
    ) -> None:
        links, dead = self.links, self.dead
        for dst in links.out_links[source]:
            if (dst in dead or self.out) and self.is_dead(dst, epoch):
                continue
            d = verdicts[("formation", source, dst)] if verdicts is not None else None
            box = self._route_packet("state", "formation", source, dst, payload, epoch, seq, d)
            if self._all_handled(box, links.in_links[dst], epoch):  # else none can close yet
                self._try_close("state", dst)

    def sender_died(self, agent: int) -> None:
        """``agent`` is gone (0: the leader): its packets count as lost, nobody waits for them."""
        if agent in self.progress.final_states or agent in self.away:
            return  # its part is over, or it is out by the scenario's events
        if agent in self.dead and self.revive.pop(agent, None) is None:
            return  # already down; else it died again after coming back
        log.warning("%s is gone: its packets count as lost from now on", _name(agent))
        self._leave_clean_path(gated=True)  # what was gathered was routed while it was alive
        self.dead.add(agent)
        self._release_held(agent)  # nobody waits for its positions
        self._leave_clean_path()
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

    def queues_changing(self) -> None:
        """A capacity queue is about to change: its state counts the packets the clean path put
        through it, up to the last one (:meth:`QueuedPhases.crossed`)."""
        if (q := self.queued) is not None:
            for link, last in (x for ce in self.clean.values() for x in ce.last_taken()):
                q.crossed(link, last)

    def models_changed(self) -> None:
        """A link's model changed: which epochs are clean is computed again."""
        self._leave_clean_path(gated=True)  # decided by the models in force as they came
        for ce in self.clean.values():
            ce.invalidate()
        self.positions.refresh()

    def flush_clean(self) -> None:
        """Hand out the records of every clean epoch finished since the last flush."""
        for phase in self.clean:
            self._flush_clean(phase)

    # -- state out ----------------------------------------------------------------------------
    def finished(self) -> bool:
        return self.progress.finished(self.gone())

    def forwarded(self) -> dict[Link, int]:
        """Delivered packets per link, clean epochs' included (for the final status)."""
        total = self.ledger.forwarded.copy()
        for ce in self.clean.values():
            total.update(ce.forwarded())
        return dict(total)

    # -- the full path ------------------------------------------------------------------------
    def _route_packet(
        self,
        phase: Phase,
        cls: LinkClass,
        src: int,
        dst: int,
        payload: Any,
        epoch: int,
        seq: int,
        decided: Outcome | None = None,
    ) -> OpenEpoch:
        """Decide (unless ``decided``) and record one packet, and put it in its receiver's open
        epoch (returned)."""
        key = (phase, dst, epoch)
        box = self.open.get(key)
        if box is None:
            box = self.open[key] = OpenEpoch()
        box.handled.add(src)
        link: Link = (cls, src, dst)
        d = decided or self.links.models[link].decide(
            epoch, distance_m=self.positions.length(link, epoch)
        )
        q = self.queued
        if d.delivered and q is not None:
            judged = q.at_once(phase, epoch, link, d)
            if judged is None:
                q.hold(phase, epoch, (link, seq, payload, d))
                return box  # judged with the rest of its phase (_judge_when_complete)
            self._apply(box, phase, link, epoch, seq, payload, judged)
            return box
        self._apply(box, phase, link, epoch, seq, payload, d)
        return box

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
        """Record a packet's decision and put it in ``box`` (or hold it for a later epoch)."""
        cls, src, dst = link
        self.ledger.decisions[(phase, epoch)].append((src, dst, cls, epoch, seq, d))
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
            self._apply(self.open[(phase, link[2], epoch)], phase, link, epoch, seq, payload, d)
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
        epoch is closed, its records go out."""
        self.open.pop((phase, receiver, epoch), None)
        for h in self.delayed.pop((phase, receiver, epoch), []):
            self.ledger.forwarded[h.link] += h.copies
            box.packets.append(h.packet)
        gone = [s for s in self.links.senders(phase, receiver) if s in dead] if dead else []
        self.outbox.deliver(phase, receiver, epoch, box.packets, box.lost, gone)
        self.next_close[(phase, receiver)] = epoch + 1
        self.closed_count[(phase, epoch)] += 1
        down = len(dead) - (LEADER_ENDPOINT in dead)
        receivers = len(self.links.agents) - down if phase != "report" else 1
        if self.closed_count[(phase, epoch)] >= receivers:
            del self.closed_count[(phase, epoch)]
            self._publish_decisions(phase, epoch)

    def _publish_decisions(self, phase: Phase, epoch: int) -> None:
        batch = self.ledger.decisions.pop((phase, epoch), [])
        self._flush_clean(phase)  # records stay in epoch order
        self.outbox.records(phase, epoch, batch)

    # -- the clean path -----------------------------------------------------------------------
    def _clean_delivery(self, phase: Phase) -> Deliver:
        outbox, next_close = self.outbox, self.next_close

        def deliver(receiver: int, epoch: int, packets: list[bytes]) -> None:
            outbox.deliver(phase, receiver, epoch, packets, [], [])
            # Epochs into a receiver finish in order: its senders need its previous one.
            next_close[(phase, receiver)] = epoch + 1

        return deliver

    def _forward_clean(self, phase: Phase, stream: int, epoch: int, seq: int, payload: Any) -> bool:
        """Take a packet of a clean epoch with no per-packet decision; False when the epoch
        needs the full path. A receiver's delivery goes out once all its senders' are here."""
        ce = self.clean.get(phase)
        if ce is None:
            return False
        clean = ce.flags.get(epoch)
        if clean is None:
            clean = ce.clean(epoch)
        if not clean:  # by the models, or already handled packet by packet
            return False
        if stream not in ce.receivers or self.dead or self.delayed or epoch in self.out:
            self._go_slow(phase, epoch)
            return False
        if ce.gated:
            self._gate(ce, stream, epoch, seq, payload)
            return True
        if ce.take(stream, epoch, seq, payload, self._clean_deliver[phase]) and (
            len(ce.chunks) >= FLUSH_CHUNKS or epoch >= self.epochs - 1
        ):
            self._flush_clean(phase)  # the last epoch's go out while the run still goes
        return True

    def _gate(self, ce: CleanEpochs, stream: int, epoch: int, seq: int, payload: Any) -> None:
        """Gather a state of a gated epoch; once all are in, judge their lengths at once."""
        g = ce.gather(stream, epoch, seq, payload)
        if g is None:
            return
        lengths = self.positions.lengths(ce.links, epoch)
        if any(self.next_close[("state", r)] != epoch for r in ce.need):  # out of turn
            self._go_slow("state", epoch, ce.verdicts(epoch, lengths))
            return
        if not ce.within_reach(epoch, lengths):  # decided as the full path would, from these
            ce.judged(epoch, g, ce.verdicts(epoch, lengths), self.ledger, self._close_judged)
            return
        ce.open_gate(epoch, g, self._clean_deliver["state"])
        if len(ce.chunks) >= FLUSH_CHUNKS or epoch >= self.epochs - 1:
            self._flush_clean("state")

    def _close_judged(self, dst: int, epoch: int, packets: list[bytes], lost: list[int]) -> None:
        """A judged gated epoch's delivery into ``dst``; its later epochs complete go too."""
        self._close("state", dst, epoch, OpenEpoch(packets=packets, lost=lost), set())
        self._try_close("state", dst)

    def _leave_clean_path(self, gated: bool = False) -> None:
        """Epochs being gathered (only gated ones: ``gated``) take the full path from now on."""
        for phase, ce in self.clean.items():
            if ce.gated or not gated:
                for epoch in list(ce.gathering):
                    self._go_slow(phase, epoch)

    def _flush_clean(self, phase: Phase) -> None:
        ce = self.clean.get(phase)
        if ce is None or not ce.chunks:
            return
        self.outbox.clean_records(phase, ce.last_done, ce.chunks)
        ce.chunks = []

    def _go_slow(
        self, phase: Phase, epoch: int, verdicts: dict[Link, Outcome] | None = None
    ) -> None:
        """From now on ``epoch`` of ``phase`` takes the full path; what went fast is recorded as such."""
        ce = self.clean[phase]
        g = ce.go_slow(epoch)
        if g is None:
            return
        if ce.gated:  # nothing went out yet: route each as the full path would have
            for src, seq in g.seqs.items():
                self._route_state(src, epoch, seq, g.payloads[src], verdicts)
            return
        touched: set[int] = set()
        for (src, dst, cls, _, seq, d), link in ce.records(epoch, g.seqs):
            self.ledger.decisions[(phase, epoch)].append((src, dst, cls, epoch, seq, d))
            self.ledger.forwarded[link] += 1
            if dst in g.delivered:
                continue
            box = self.open.get((phase, dst, epoch))
            if box is None:
                box = self.open[(phase, dst, epoch)] = OpenEpoch()
            box.handled.add(src)
            box.packets.append(g.packets[src])
            touched.add(dst)
        self.closed_count[(phase, epoch)] += len(g.delivered)
        for dst in touched:
            self._try_close(phase, dst)


def _name(sender: int) -> str:
    return "the leader" if sender == LEADER_ENDPOINT else f"agent {sender}"
