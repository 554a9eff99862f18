"""The launcher's own Zenoh view of a run: progress, drops, states, statuses, final states."""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
import zenoh

from formation import keys
from formation.codec import Malformed, read_attachment
from formation.messages import Status
from formation.scenario import Scenario
from testbed.runtime.observed_decisions import Judged, read_batch
from testbed.runtime.observed_states import (
    Bounds,
    ObservedState,
    StateRows,
    read_bundle,
    read_parts,
    read_state,
)

# The states kept unread, at most this many bytes (about 200 epochs of 1,000 agents): past it
# they are read at once, so a long run's memory stays bounded.
PENDING_BYTES = 64 << 20


class Verdict(NamedTuple):
    """One netem decision as the launcher keeps it (the recording has the whole record)."""

    source: int
    target: int
    link_class: str
    epoch: int
    seq: int
    verdict: str
    model: str = ""  # what dropped it: a link model, or a queue's reason (queue_full, ...)


class _Raw(NamedTuple):
    """A state, or a pool's bundle of them, as it came: read when the states are asked for."""

    key: str
    payload: bytes
    owner: str  # a state: the agent its key stands for; a bundle: its pool's first agent
    bundle: bool
    arrived: float  # time.monotonic() [s]


class Observer:
    """The launcher's own Zenoh view of the run: progress, drops, states, statuses.

    It shares the machine with the run, so it reads only what it needs when it needs it:
    a progress line needs the estimates' epochs and the drops, so the states are kept as they
    came and read (in bulk, :mod:`testbed.runtime.observed_states`) once someone reads
    :attr:`positions`, :attr:`returns`, :attr:`substitutions`, :attr:`fallbacks`,
    :attr:`fallback_epochs` or :attr:`malformed`, or they pass ``PENDING_BYTES``.
    What it cannot read is counted as malformed.
    """

    def __init__(self, session: zenoh.Session, run_id: str, scenario: Scenario) -> None:
        self.lock = threading.RLock()  # reading the states settles them, under it
        self.scenario = scenario
        e, n, d = scenario.epochs, scenario.n, scenario.dimension
        self.bounds = Bounds(e, n, d)
        self._positions = np.full((e + 1, n, d), np.nan)
        self.estimated: set[int] = set()
        self._batches: list[Judged] = []  # netem's decision batches, records unread
        # (epoch, agent, neighbour, x̃)
        self._substitutions: list[tuple[int, int, int, list[float]]] = []
        self.statuses: dict[str, Status] = {}  # each process's last
        self.parts: list[Status] = []  # the last statuses of the parts before a restart
        self.alive: set[str] = set()
        self._malformed = Malformed()
        self.drops = 0
        self._fallbacks = 0  # substituted values that fell back (no estimate to use)
        self._fallback_epochs: Counter[int] = Counter()  # epoch → those used at it
        # agent → (epoch, t) of its newest process's first state (seq 0) or its first after a gap
        self._returns: dict[int, tuple[int, float]] = {}
        self._pending: list[_Raw] = []
        self._pending_bytes = 0
        self.team_events: list[tuple[float, str]] = []  # netem's running statuses (t, detail)
        self.run_id = run_id
        # The leader finished an epoch: said by the attachment of agent 1's part (realtime) or
        # of the whole estimate (lockstep: the parts' bundle is four times its size).
        done = (
            keys.leader_estimate_for(run_id, 1)
            if scenario.runtime.mode == "realtime"
            else keys.leader_estimate_out(run_id)
        )
        self._subs = [
            session.declare_subscriber(keys.agent_state(run_id, "*"), self._on_state),
            session.declare_subscriber(keys.pool_states(run_id, "*"), self._on_states),
            session.declare_subscriber(done, self._on_estimate),
            session.declare_subscriber(keys.netem_decision(run_id), self._on_decisions),
            session.declare_subscriber(keys.status_all(run_id), self._on_status),
            session.liveliness().declare_subscriber(
                keys.alive_all(run_id), self._on_alive, history=True
            ),
        ]

    def _decode(self, sample: zenoh.Sample, model: Any) -> Any:
        return self._malformed.decode(str(sample.key_expr), sample.payload.to_bytes(), model)

    def _on_state(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        args = keys.parse(key).args  # its own key only
        self._hold(
            _Raw(
                key,
                sample.payload.to_bytes(),
                args[0] if len(args) == 1 else "",
                False,
                time.monotonic(),
            )
        )

    def _on_states(self, sample: zenoh.Sample) -> None:
        """A pool's states in one bundle: each part as if it came alone, its pool's agents'."""
        key = str(sample.key_expr)
        try:
            first = keys.parse(key).args[0]
        except (KeyError, ValueError, IndexError):
            first = ""  # counted when read
        self._hold(_Raw(key, sample.payload.to_bytes(), first, True, time.monotonic()))

    def _hold(self, raw: _Raw) -> None:
        with self.lock:
            self._pending.append(raw)
            self._pending_bytes += len(raw.payload)
            if self._pending_bytes > PENDING_BYTES:
                self.settle()

    def settle(self) -> None:
        """Read every state kept as it came, in the order they came."""
        with self.lock:
            pending, self._pending, self._pending_bytes = self._pending, [], 0
            for raw in pending:
                if raw.bundle:
                    self._read_bundle(raw)
                    continue
                state = read_state(raw.payload, raw.owner, self.bounds)
                if state is None:
                    self._malformed.counts[raw.key] += 1
                else:
                    self._keep(state, raw.arrived)

    def _read_bundle(self, raw: _Raw) -> None:
        try:
            first = int(raw.owner)
        except ValueError:
            self._malformed.counts[raw.key] += 1
            return
        rows = read_bundle(raw.payload, first, self.bounds)
        if rows is not None:
            self._keep_rows(rows, raw.arrived)
            return
        parts = read_parts(raw.payload, first)
        if parts is None:
            self._malformed.counts[raw.key] += 1
            return
        for i, message in parts:
            state = read_state(message, str(i) if i >= first else "", self.bounds)
            if state is None:
                self._malformed.counts[raw.key] += 1
            else:
                self._keep(state, raw.arrived)

    def _keep(self, state: ObservedState, arrived: float) -> None:
        """One agent's state (under :attr:`lock`)."""
        k, i = state.epoch, state.agent
        if state.seq == 0 or (k > 0 and np.isnan(self._positions[k - 1, i - 1, 0])):
            self._returns[i] = (k, arrived)
        self._positions[k, i - 1] = state.position
        for j, value in state.substituted:  # used at the previous epoch
            self._substitutions.append((k - 1, i, j, value))
        if state.fell_back:
            self._fallbacks += state.fell_back
            self._fallback_epochs[k - 1] += state.fell_back

    def _keep_rows(self, rows: StateRows, arrived: float) -> None:
        """A bundle's states, each agent once, as :meth:`_keep` keeps them one by one."""
        k, i = rows.epoch, rows.agent
        gap = (k > 0) & np.isnan(self._positions[np.maximum(k - 1, 0), i - 1, 0])
        for epoch, agent in zip(
            k[(rows.seq == 0) | gap].tolist(), i[(rows.seq == 0) | gap].tolist(), strict=True
        ):
            self._returns[agent] = (epoch, arrived)
        self._positions[k, i - 1] = rows.position
        for r in np.flatnonzero([bool(s) for s in rows.substituted]).tolist():
            e, a = int(k[r]) - 1, int(i[r])
            self._substitutions.extend((e, a, j, value) for j, value in rows.substituted[r])
        for r in np.flatnonzero(rows.fell_back).tolist():
            self._fallbacks += int(rows.fell_back[r])
            self._fallback_epochs[int(k[r]) - 1] += int(rows.fell_back[r])

    @property
    def positions(self) -> npt.NDArray[np.float64]:
        """(E + 1, n, d) each agent's state at each epoch [m], NaN where none came."""
        self.settle()
        return self._positions

    @property
    def returns(self) -> dict[int, tuple[int, float]]:
        """Agent → (epoch, monotonic time it came) of its newest process's first state (seq 0)
        or its first after a gap."""
        self.settle()
        return self._returns

    @property
    def substitutions(self) -> list[tuple[int, int, int, list[float]]]:
        """(epoch, agent, neighbour, x̃) of each value an agent used for a lost neighbour."""
        self.settle()
        return self._substitutions

    @property
    def fallbacks(self) -> int:
        """Substituted values that fell back (no estimate to use)."""
        self.settle()
        return self._fallbacks

    @property
    def fallback_epochs(self) -> Counter[int]:
        """Epoch → the substituted values that fell back at it."""
        self.settle()
        return self._fallback_epochs

    @property
    def malformed(self) -> Malformed:
        """What could not be read, per key (the states read first)."""
        self.settle()
        return self._malformed

    def _on_estimate(self, sample: zenoh.Sample) -> None:
        att = sample.attachment
        meta = read_attachment(None if att is None else att.to_bytes())
        if meta is None:
            with self.lock:
                self._malformed.counts[str(sample.key_expr)] += 1
            return
        with self.lock:
            self.estimated.add(meta[0])

    def _on_decisions(self, sample: zenoh.Sample) -> None:
        batch = read_batch(sample.payload.to_bytes())
        with self.lock:  # rows only when the run is over (decisions): thousands an epoch
            if batch is None:
                self._malformed.counts[str(sample.key_expr)] += 1
                return
            self._batches.append(batch)
            self.drops += batch.drops

    @property
    def decisions(self) -> list[Verdict]:
        """Every decision received, in order (read under :attr:`lock`, as every field)."""
        batches = list(self._batches)  # one copy: a batch may be appended meanwhile
        return [
            Verdict(s, t, batch.link_class, e, q, *batch.judged[j])
            for batch in batches
            for s, t, e, q, j in batch.records()
        ]

    def _on_status(self, sample: zenoh.Sample) -> None:
        msg = self._decode(sample, Status)
        role, ident = keys.parse(str(sample.key_expr)).args
        if msg is not None and msg.sender != (
            f"{role}/{ident}" if role in ("agent", "pool") else role
        ):
            with self.lock:
                self._malformed.counts[str(sample.key_expr)] += 1  # another process's status
        elif msg is not None:
            with self.lock:
                last = self.statuses.get(msg.sender)
                if (
                    last is not None
                    and last.state == "done"
                    and (msg.state != "done" or msg.epochs_done > last.epochs_done)
                ):
                    self.parts.append(last)  # a part a crash event ended; this is the next
                self.statuses[msg.sender] = msg
                if msg.role == "netem" and msg.state == "running":
                    self.team_events.append((time.monotonic(), msg.detail))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with self.lock:
            (self.alive.add if sample.kind == zenoh.SampleKind.PUT else self.alive.discard)(key)

    def netem_done(self, timeout_s: float = 10.0) -> bool:
        """Wait until netem's last status (done or error) has come, at most ``timeout_s``.

        netem publishes it after its last decisions, over the same session, so once it is
        here every decision is too (a summary taken earlier could miss the last batch).
        """
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                st = self.statuses.get("netem")
                if st is not None and st.state in ("done", "error"):
                    return True
            time.sleep(0.01)
        return False

    def is_alive(self, role: str, ident: int | str) -> bool:
        with self.lock:
            return keys.alive(self.run_id, role, ident) in self.alive

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()


def all_final(observer: Observer, ids: list[int]) -> bool:
    with observer.lock:
        return bool(np.isfinite(observer.positions[-1, np.array(ids, dtype=int) - 1]).all())


def missing_final(observer: Observer, ids: list[int]) -> str:
    with observer.lock:
        have = np.isfinite(observer.positions[-1]).all(axis=1)
        missing = np.array([i for i in ids if not have[i - 1]], dtype=int)
    shown = ", ".join(str(i) for i in missing[:10]) + (", ..." if len(missing) > 10 else "")
    return f" of {len(missing)} agents ({shown})"


def flush_recorder(session: zenoh.Session, run_id: str, observer: Observer) -> None:
    """Wait until the recorder has every status message the services sent (they are sent last)."""
    with observer.lock:
        expected = len(observer.statuses)
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        for reply in session.get(keys.flush(run_id), timeout=1.0):
            if reply.ok is None:
                continue
            counts = json.loads(reply.ok.payload.to_bytes())
            got = sum(v for k, v in counts.items() if "/status/" in k)
            if got >= expected:
                return
        time.sleep(0.02)


__all__ = ["PENDING_BYTES", "Observer", "Verdict", "all_final", "flush_recorder", "missing_final"]
