"""One phase on a shared 802.11 channel: the DCF of every agent, event by event.

Each agent sends its frames in order of readiness through the DCF of IEEE Std 802.11-2016
(10.3.4.2, 10.3.4.3): a frame that finds the medium idle goes once the medium has stayed idle
for DIFS after the frame was queued (and after the medium's last busy time, EIFS after a
frame received in error); one that finds it busy, and every frame after a
transmission (the post-backoff), waits a backoff of ``U{0 .. CW}`` slots, counted down only
while the medium is idle for DIFS and then slot by slot, frozen while it is busy (10.3.4.3).
As in ns-3, a frame queued on an idle medium that turns busy within its DIFS draws no backoff.
A unicast frame is acknowledged after SIFS at the control rate; without the ACK by
ACKTimeout (or with an ACK received in error) its sender doubles CW (up to CWmax) and
retries, up to ``retry_limit`` attempts; a broadcast is sent once, with CW at CWmin. Agents
that decode a unicast frame keep off the medium until its ACK ends (NAV). Carrier sense sees
a transmission ``aCCATime`` after it starts, so agents whose backoffs end within that time of
each other collide, as in the standard's slot.

The phase starts on a medium idle for long, every post-backoff over; when each frame is
ready is the caller's (the senders' start offsets). The phase runs until the last frame is
done; a frame received after ``phase_end_ns`` is ``LATE``. Times are integer nanoseconds and
every backoff is a keyed draw of ``(seed, AIR_STREAM, 0, epoch, phase, agent, draw)``, so a
phase is the same to the bit in any process (docs/model.md §11).
"""

from __future__ import annotations

import heapq
from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from formation.keyed_random import keyed_uniform
from netem.links.wifi.config import AirConfig
from netem.links.wifi.frames import BROADCAST, Cause, Frames, PhaseOutcome
from netem.links.wifi.medium import ACK, Medium
from netem.links.wifi.radio import AIR_STREAM, received_dbm, to_mw
from netem.links.wifi.reception import Reception, Transmission

Floats = npt.NDArray[np.float64]
NEVER = 1 << 62  # [ns] a time that does not come
LONG_AGO = -(1 << 40)  # [ns] the medium was idle since before the phase
BACKOFF = 0  # sub-stream of AIR_STREAM

# what happens at one instant, in this order: frames leave the air before others start
END, TIMEOUT, NAV_END, READY, ACK_START, SEND, SENSED = range(7)


@dataclass(frozen=True)
class Key:
    """Where a phase's random numbers come from."""

    seed: int
    epoch: int
    phase: int


def decide_phase(
    config: AirConfig,
    positions_m: Floats,
    frames: Frames,
    key: Key,
    phase_end_ns: int | None = None,
) -> PhaseOutcome:
    """Every frame's fate on the channel, through the compiled event loop.

    Parameters
    ----------
    positions_m : (n, d) array [m]
        The agents' true positions during the phase.
    frames
        The phase's frames (``Frames.of``); ``AirError`` if one does not fit the team.
    key
        The seed, epoch and phase the draws are keyed by.
    phase_end_ns
        Frames received later are ``LATE``; ``None``: none is.
    """
    # numba takes about a second to load: only once a phase is decided
    from netem.links.wifi.compiled_phase import decide

    return decide(config, positions_m, frames, key.seed, key.epoch, key.phase, phase_end_ns)


def load_compiled_loop() -> None:
    """Load the compiled loop now (compile it, on a fresh install) rather than at the first
    phase: realtime would hold that phase's packets meanwhile."""
    two = np.array([[0.0, 0.0], [1.0, 0.0]])
    decide_phase(AirConfig(), two, Frames.of(0, 1, 0, 0), Key(0, 0, 0))


def reference_phase(
    config: AirConfig,
    positions_m: Floats,
    frames: Frames,
    key: Key,
    phase_end_ns: int | None = None,
) -> PhaseOutcome:
    """``decide_phase`` through this module's loop in Python: the reference the compiled
    loop is held to."""
    positions = np.asarray(positions_m, dtype=np.float64)
    frames.check(positions.shape[0])
    return _Phase(config, positions, frames, key).run(phase_end_ns)


def _power_mw(config: AirConfig, positions: Floats, key: Key) -> Floats:
    """(n, n) [i, j]: what j receives from i [mW]; 0 on the diagonal."""
    power = to_mw(received_dbm(config, positions, key.seed, key.epoch))
    np.fill_diagonal(power, 0.0)
    return power


def _outcome(
    arrival: npt.NDArray[np.int64],
    cause: npt.NDArray[np.int8],
    attempts: npt.NDArray[np.int64],
    first_start: npt.NDArray[np.int64],
    end_ns: int,
    phase_end_ns: int | None,
) -> PhaseOutcome:
    delivered = cause == Cause.DELIVERED
    if phase_end_ns is not None:
        late = delivered & (arrival > phase_end_ns)
        cause[late] = Cause.LATE
        delivered &= ~late
    return PhaseOutcome(
        delivered=delivered,
        arrival_ns=arrival,
        cause=cause,
        attempts=attempts,
        first_start_ns=first_start,
        end_ns=end_ns,
    )


class _Phase:
    def __init__(self, config: AirConfig, positions: Floats, frames: Frames, key: Key) -> None:
        n, m = positions.shape[0], len(frames)
        self.config, self.frames, self.key, self.n = config, frames, key, n
        phy = config.physical
        self.phy = phy
        self.rate = config.rate_kbps
        self.slot_ns, self.sifs_ns, self.difs_ns = phy.slot_ns, phy.sifs_ns, phy.difs_ns
        self.eifs_ns, self.ack_ns = phy.eifs_ns(), phy.ack_ns(self.rate)
        self.cw_min, self.cw_max = config.window
        power = _power_mw(config, positions, key)
        noise = float(to_mw(config.noise_dbm))
        detect_snr = float(to_mw(config.preamble_detection_snr_db))
        detect = max(
            float(to_mw(config.preamble_detection_dbm)), float(to_mw(config.rx_sensitivity_dbm))
        )
        self.sinr = float(to_mw(config.sinr_db))
        self.ack_rate = phy.control_rate_kbps(self.rate)
        self.ack_sinr = float(to_mw(phy.sinr_threshold_db(self.ack_rate)))
        reception = Reception(
            power, noise, phy, config.error_model == "chunks", (key.seed, key.epoch, key.phase)
        )
        self.medium = Medium(
            power, noise, detect, detect_snr, float(to_mw(config.carrier_sense_dbm)), reception
        )
        # a frame the receiver cannot take even on a silent channel
        alone = (power >= detect) & (power >= max(detect_snr, self.sinr) * noise)
        self.alone = alone
        # the stations
        order = np.lexsort((np.arange(m), frames.ready_ns))
        self.queue: list[deque[int]] = [deque() for _ in range(n)]
        for f in order:
            self.queue[int(frames.sender[f])].append(int(f))
        self.head_ready = np.full(n, NEVER, dtype=np.int64)  # [ns] the head frame's
        for q in range(n):
            self.set_head(q)
        self.busy = np.zeros(n, dtype=bool)
        self.sending = np.full(n, -1, dtype=np.int64)  # log index of its transmission
        self.nav_ns = np.zeros(n, dtype=np.int64)
        self.planned = np.full(n, NEVER, dtype=np.int64)
        self.idle_from = np.full(n, LONG_AGO, dtype=np.int64)
        self.eifs = np.zeros(n, dtype=bool)
        self.counter = np.zeros(n, dtype=np.int64)
        self.cw = [self.cw_min] * n
        self.draws = [0] * n
        self.uniforms = np.zeros((n, 0))
        self.awaiting = np.zeros(n, dtype=bool)  # sent a unicast frame, waiting for its ACK
        self.ack_on_air = [False] * n
        self.tries = [0] * n  # attempts of the head frame
        self.events: list[tuple[int, int, int, int]] = []  # (time, kind, order, value)
        self.order = 0
        # the outcome
        self.arrival = np.full((m, n), -1, dtype=np.int64)
        self.cause = np.full((m, n), Cause.NOT_ADDRESSED, dtype=np.int8)
        self.attempts = np.zeros(m, dtype=np.int64)
        self.first_start = np.full(m, -1, dtype=np.int64)
        self.now = 0

    # -- the loop --------------------------------------------------------------------------
    def push(self, time_ns: int, kind: int, value: int) -> None:
        self.order += 1
        heapq.heappush(self.events, (time_ns, kind, self.order, value))

    def run(self, phase_end_ns: int | None) -> PhaseOutcome:
        for f in range(len(self.frames)):
            self.push(int(self.frames.ready_ns[f]), READY, f)
        while True:
            send_at = int(self.planned.min())
            if self.events and (self.events[0][0], self.events[0][1]) < (send_at, SEND):
                time_ns, kind, _, value = heapq.heappop(self.events)
                self.now = time_ns
                self.handle(kind, value)
            elif send_at < NEVER:
                self.now = send_at
                self.send([int(s) for s in np.flatnonzero(self.planned == send_at)])
            else:
                break
        return self.outcome(phase_end_ns)

    def handle(self, kind: int, value: int) -> None:
        if kind == END:
            self.end(value)
        elif kind == TIMEOUT:
            if self.awaiting[value] and not self.ack_on_air[value]:
                self.idle_from[value] = max(self.idle_from[value], self.now)
                self.eifs[value] = False
                self.resolve(value, acked=False)
        elif kind == NAV_END:
            self.sense()
        elif kind == READY:
            s = int(self.frames.sender[value])
            head = self.queue[s][0] if self.queue[s] else -1
            if head == value and self.contending(s) and self.busy[s] and self.counter[s] == 0:
                self.counter[s] = self.draw(s)
            self.plan(s)
        elif kind == ACK_START:
            receiver, sender = divmod(value, self.n)
            if self.sending[receiver] < 0:
                self.ack_on_air[sender] = True
                self.transmit([(receiver, ACK, sender, self.ack_ns, self.ack_rate, self.ack_sinr)])
        elif kind == SENSED:
            self.medium.sense(value)
            self.sense()

    # -- a station's DCF -------------------------------------------------------------------
    def set_head(self, s: int) -> None:
        queue = self.queue[s]
        self.head_ready[s] = self.frames.ready_ns[queue[0]] if queue else NEVER

    def contending(self, s: int) -> bool:
        return bool(self.queue[s]) and self.sending[s] < 0 and not self.awaiting[s]

    def draw(self, s: int) -> int:
        """Agent ``s``'s next backoff [slots]: its ``draws[s]``-th keyed uniform, over CW."""
        k, d = self.key, self.draws[s]
        if d >= self.uniforms.shape[1]:  # a block of draws for every agent at once
            cols = np.arange(self.uniforms.shape[1], 2 * self.uniforms.shape[1] + 8)
            agents = np.arange(self.n)[:, None]
            more = keyed_uniform(k.seed, AIR_STREAM, BACKOFF, k.epoch, k.phase, agents, cols)
            self.uniforms = np.concatenate([self.uniforms, more], axis=1)
        self.draws[s] += 1
        return int(self.uniforms[s, d] * (self.cw[s] + 1))

    def count_start(self) -> npt.NDArray[np.int64]:
        """[ns] when each agent's backoff counts from: DIFS (EIFS) after the medium went idle."""
        ifs = np.where(self.eifs, self.eifs_ns, self.difs_ns)
        return np.asarray(self.idle_from + ifs)

    def plan(self, s: int) -> None:
        """When agent ``s`` sends next if the medium stays idle (``plan_all`` for one)."""
        if self.busy[s] or self.sending[s] >= 0 or self.awaiting[s] or self.head_ready[s] >= NEVER:
            self.planned[s] = NEVER
            return
        ifs = self.eifs_ns if self.eifs[s] else self.difs_ns
        backoff_end = int(self.idle_from[s]) + ifs + int(self.counter[s]) * self.slot_ns
        self.planned[s] = max(int(self.head_ready[s]) + self.difs_ns, backoff_end)

    def plan_all(self, which: npt.NDArray[np.bool_]) -> None:
        """When the agents in ``which`` send next if the medium stays idle."""
        backoff_end = self.count_start() + self.counter * self.slot_ns
        # a frame goes once the medium has stayed idle for DIFS after it was queued
        queued = np.where(self.head_ready < NEVER, self.head_ready + self.difs_ns, NEVER)
        free = ~self.busy & (self.sending < 0) & ~self.awaiting & (queued < NEVER)
        planned = np.where(free, np.maximum(queued, backoff_end), NEVER)
        self.planned[which] = planned[which]

    def freeze(self, turned: npt.NDArray[np.int64]) -> None:
        """The medium turned busy at these agents: keep the slots they have not counted yet."""
        if turned.shape[0] == 0:
            return
        ifs = np.where(self.eifs[turned], self.eifs_ns, self.difs_ns)
        start = self.idle_from[turned] + ifs
        done = np.where(self.now > start, (self.now - start) // self.slot_ns, 0)
        # a frame queued on an idle medium that turns busy within DIFS draws no backoff: it
        # goes DIFS after the medium is idle again (ns-3's ChannelAccessManager)
        self.counter[turned] = np.maximum(self.counter[turned] - done, 0)

    def sense(self) -> None:
        """Carrier sense at every agent; freeze or resume the backoffs that changed."""
        busy = (self.sending >= 0) | self.medium.carrier_busy() | (self.nav_ns > self.now)
        if (busy == self.busy).all():
            return
        turned_busy, turned_idle = busy & ~self.busy, ~busy & self.busy
        self.freeze(np.flatnonzero(turned_busy))
        self.planned[turned_busy] = NEVER
        self.idle_from[turned_idle] = self.now
        self.busy = busy
        if turned_idle.any():
            self.plan_all(turned_idle)

    def send(self, senders: list[int]) -> None:
        txs = []
        for s in senders:
            f = self.queue[s][0]
            self.attempts[f] += 1
            self.tries[s] += 1
            if self.first_start[f] < 0:
                self.first_start[f] = self.now
            size = int(self.frames.payload_bytes[f]) + self.config.mac_overhead_bytes
            airtime = self.phy.airtime_ns(size, self.rate)
            txs.append((s, f, int(self.frames.receiver[f]), airtime, self.rate, self.sinr))
        self.transmit(txs)

    def transmit(self, txs: list[tuple[int, int, int, int, int, float]]) -> None:
        new = [
            Transmission(s, f, dest, self.now, self.now + airtime, rate, sinr)
            for s, f, dest, airtime, rate, sinr in txs
        ]
        for k, tx in enumerate(new):
            self.sending[tx.sender] = len(self.medium.log) + k
            self.planned[tx.sender] = NEVER
            self.eifs[tx.sender] = False  # a transmission ends the EIFS (ns-3: NotifyTxStartNow)
        indices = self.medium.start(new, self.sending >= 0)
        for index, tx in zip(indices, new, strict=True):
            self.push(tx.start_ns + self.phy.cca_ns, SENSED, index)
            self.push(tx.end_ns, END, index)
        self.sense()

    def end(self, index: int) -> None:
        tx = self.medium.log[index]
        s = tx.sender
        self.sending[s] = -1
        locked, received = self.medium.end(index)
        for r in np.flatnonzero(locked):
            self.eifs[r] = not received[r]
        if tx.frame == ACK:
            self.ack_on_air[tx.dest] = False
            if self.awaiting[tx.dest]:
                self.resolve(tx.dest, acked=bool(received[tx.dest]))
        else:
            self.data_end(tx, received)
        self.sense()

    def data_end(self, tx: Transmission, received: npt.NDArray[np.bool_]) -> None:
        s, f = tx.sender, tx.frame
        if tx.dest == BROADCAST:
            self.arrival[f, received] = self.now
            others = np.arange(self.n) != s
            why = np.where(self.alone[s], Cause.COLLISION, Cause.BELOW_SENSITIVITY)
            self.cause[f, others] = np.where(received, Cause.DELIVERED, why)[others]
            self.next_frame(s)
            return
        d = tx.dest
        if received[d]:
            if self.arrival[f, d] < 0:
                self.arrival[f, d] = self.now
            self.cause[f, d] = Cause.DELIVERED
            self.push(self.now + self.sifs_ns, ACK_START, d * self.n + s)
            ack_end = self.now + self.sifs_ns + self.ack_ns
            overhearing = received.copy()
            overhearing[d] = False
            if overhearing.any():
                self.nav_ns[overhearing] = np.maximum(self.nav_ns[overhearing], ack_end)
                self.push(ack_end, NAV_END, 0)
        self.awaiting[s] = True
        self.push(self.now + self.phy.ack_timeout_ns(), TIMEOUT, s)

    def resolve(self, s: int, acked: bool) -> None:
        """The end of a unicast attempt at its sender."""
        self.awaiting[s] = False
        f = self.queue[s][0]
        d = int(self.frames.receiver[f])
        if acked or self.tries[s] >= self.config.retry_limit:
            if self.arrival[f, d] < 0:
                lost = Cause.RETRY_LIMIT if self.alone[s, d] else Cause.BELOW_SENSITIVITY
                self.cause[f, d] = lost
            self.next_frame(s)
        else:
            self.cw[s] = min(2 * self.cw[s] + 1, self.cw_max)
            self.counter[s] = self.draw(s)
        self.plan(s)

    def next_frame(self, s: int) -> None:
        """The head frame is done: the next one waits a post-backoff at CWmin."""
        self.queue[s].popleft()
        self.set_head(s)
        self.tries[s] = 0
        self.cw[s] = self.cw_min
        self.counter[s] = self.draw(s)

    # -- the result ------------------------------------------------------------------------
    def outcome(self, phase_end_ns: int | None) -> PhaseOutcome:
        first = self.first_start
        return _outcome(self.arrival, self.cause, self.attempts, first, self.now, phase_end_ns)


__all__ = ["Key", "decide_phase", "load_compiled_loop", "reference_phase"]
