"""netem in realtime: each packet forwarded on its link's key as it comes, after its delay.

No epoch closes: a link's model decides each packet from its epoch and the time since
the clock's start (a realtime outage), and a delayed packet waits in a heap until due.
The decision records go out once per period, one batch per phase and epoch.

Packets are queued by Zenoh's threads and handled here, on the main thread, a whole queue
at a time, so Zenoh's threads never wait on netem. Handled where it arrived, a packet kept
its receiving thread in a blocking put; under overload (100 and 200 agents at 20 Hz) two
runs then stalled for 30 s, the router, netem and the agents waiting on each other.
"""

from __future__ import annotations

import heapq
import threading
import time
from collections import Counter
from collections.abc import Callable

import zenoh

from formation.codec import read_attachment
from formation.deadlines import PHASES
from formation.realtime import Clock
from formation.scenario import LEADER_ENDPOINT
from formation.service import Incoming, Service
from netem.links import PHASE_OF, Link, LinkClass, Links, Phase, Routes, link_key
from netem.models import LinkModel
from netem.progress import Progress
from netem.records import Ledger, Record

# (due ns, tie, link, payload, attachment, its phase's deadline ns)
Due = tuple[int, int, zenoh.Publisher, bytes, "bytes | None", int]
KIND_OF: dict[LinkClass, str] = {"formation": "state", "report": "report", "estimate": "estimate"}
PublishRecords = Callable[[Phase, int, list[Record]], None]


class Realtime:
    """Forwards packets on their links' keys, after their models' delays."""

    def __init__(self, service: Service, links: Links, routes: Routes, progress: Progress,
                 ledger: Ledger, publish_records: PublishRecords) -> None:  # fmt: skip
        self.service, self.links, self.routes = service, links, routes
        self.progress, self.ledger, self.publish_records = progress, ledger, publish_records
        self.clock: Clock | None = None  # set by run()
        self._links: dict[Link, tuple[zenoh.Publisher, LinkModel]] = {}
        # modelled_late: packets a model delayed past their deadline (modelled losses);
        # late_forwards: packets in time here (and by their model) put out after it
        self.deadline: Counter[str] = Counter()

    def link(self, cls: LinkClass, src: int, dst: int) -> tuple[zenoh.Publisher, LinkModel]:
        """The publisher of a link's forwarded packets and its model, looked up once."""
        got = self._links.get((cls, src, dst))
        if got is None:
            got = self._links[(cls, src, dst)] = (
                self.service.publisher(link_key(self.service.run_id, (cls, src, dst))),
                self.links.models[(cls, src, dst)],
            )
        return got

    def forward(self, cls: LinkClass, src: int, dst: int, msg: Incoming, epoch: int, seq: int,
                due: list[Due]) -> None:  # fmt: skip
        """Decide one packet on one link: put it now, push it on ``due``, or drop it."""
        assert self.clock is not None
        now = time.time_ns()
        pub, model = self.link(cls, src, dst)
        d = model.decide(epoch, time_s=(now - self.clock.t0_ns) / 1e9)
        self.ledger.decisions[(PHASE_OF[cls], epoch)].append((src, dst, cls, epoch, seq, d))
        if not d.delivered:
            return
        self.ledger.forwarded[(cls, src, dst)] += d.copies
        due_ns = now + int(d.delay_ms * 1e6)
        deadline_ns = self.clock.at(epoch, PHASES[KIND_OF[cls]][1])
        if d.delay_ms > 0 and due_ns > deadline_ns:
            self.deadline["modelled_late"] += d.copies
        elif d.delay_ms <= 0 and msg.arrived_ns <= deadline_ns < now:
            self.deadline["late_forwards"] += d.copies
        for _ in range(d.copies):
            if d.delay_ms <= 0:
                pub.put(msg.payload, attachment=msg.attachment)
            else:
                item = (due_ns, len(due), pub, msg.payload, msg.attachment, deadline_ns)
                heapq.heappush(due, item)

    def handle(self, msg: Incoming, due: list[Due]) -> None:
        """One inbound packet: forwarded on each of its links (a final state only noted)."""
        meta = read_attachment(msg.attachment)
        route = self.routes.of(msg.key)
        if meta is None or route is None or meta[2] != route[1]:
            self.service.malformed.counts[msg.key] += 1
            return
        epoch, seq, source = meta
        kind = route[0]
        progress = self.progress
        if kind == "state":
            progress.epoch_seen = max(progress.epoch_seen, epoch)
            if epoch >= progress.epochs:
                progress.final_state(source)
                return
            for dst in self.links.out_links[source]:
                self.forward("formation", source, dst, msg, epoch, seq, due)
        elif kind == "report":
            self.forward("report", source, LEADER_ENDPOINT, msg, epoch, seq, due)
        else:
            self.forward("estimate", LEADER_ENDPOINT, route[2], msg, epoch, seq, due)
            progress.estimate_handled(epoch)

    def publish_decisions(self) -> None:
        """Every record not yet published, one batch per phase and epoch, in order."""
        decisions = self.ledger.decisions
        for phase, epoch in sorted(decisions):
            self.publish_records(phase, epoch, decisions.pop((phase, epoch), []))

    def run(self, period_s: float, lock: threading.Lock, ready: Callable[[], bool],
            check_dead: Callable[[], None], finished: Callable[[], bool]) -> int:  # fmt: skip
        """Forward until ``finished`` and nothing is due (0), or until stopped (130).

        The clock starts once ``ready``; ``check_dead`` is called on every wake-up and
        packets are handled under ``lock``, every queued one at each wake-up.
        """
        service = self.service
        while not ready():
            if service.stopping.wait(0.02):
                return 130
        self.clock = Clock(time.time_ns() + int(0.3e9), int(period_s * 1e9))
        service.declare_start()
        due: list[Due] = []  # delayed packets, by due time
        next_flush = self.clock.at(1)
        while not (finished() and not due) and not service.stopping.is_set():
            now = time.time_ns()
            with lock:
                while due and due[0][0] <= now:
                    due_ns, _, pub, payload, att, deadline_ns = heapq.heappop(due)
                    self.deadline["late_forwards"] += due_ns <= deadline_ns < time.time_ns()
                    pub.put(payload, attachment=att)
                if now >= next_flush:
                    self.publish_decisions()
                    next_flush += self.clock.period_ns
            until = min(next_flush, due[0][0]) if due else next_flush
            msg = service.next_incoming(max(0.0, min(0.05, (until - now) / 1e9)))
            check_dead()
            if msg is not None:
                with lock:
                    self.handle(msg, due)
                    while (more := service.next_incoming(0)) is not None:
                        self.handle(more, due)
        with lock:
            self.publish_decisions()
        return 0 if finished() else 130
