"""The launcher's own Zenoh view of a run: progress, drops, states, statuses, final states."""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from typing import Any, NamedTuple

import numpy as np
import orjson
import zenoh

from formation import keys
from formation.codec import Malformed, read_attachment
from formation.messages import LINK_CLASS_OF, Status
from formation.scenario import Scenario

_COLUMNS = ("source", "target", "epoch", "seq", "judgement")  # as Verdict takes them


class Verdict(NamedTuple):
    """One netem decision as the launcher keeps it (the recording has the whole record)."""

    source: int
    target: int
    link_class: str
    epoch: int
    seq: int
    verdict: str
    model: str = ""  # what dropped it: a link model, or a queue's reason (queue_full, ...)


# a state as the observer keeps it: epoch, agent, seq, position, substitutions, fallbacks
_State = tuple[int, int, int, list[float], list[tuple[int, list[float]]], int]


class Observer:
    """The launcher's own Zenoh view of the run: progress, drops, states, statuses.

    It shares the machine with the run, so it reads only the fields it needs (orjson,
    not the models: at 1,000 agents full validation cost it a tenth of the run's CPU).
    What it cannot read is counted as malformed.
    """

    def __init__(self, session: zenoh.Session, run_id: str, scenario: Scenario) -> None:
        self.lock = threading.Lock()
        self.scenario = scenario
        e, n, d = scenario.epochs, scenario.n, scenario.dimension
        self.positions = np.full((e + 1, n, d), np.nan)
        self.estimated: set[int] = set()
        # netem's decision batches as columns: (link class, [(verdict, model)], columns)
        self._batches: list[tuple[str, list[tuple[str, str]], tuple[list[int], ...]]] = []
        self.substitutions: list[
            tuple[int, int, int, list[float]]
        ] = []  # (epoch, agent, neighbour, x̃)
        self.statuses: dict[str, Status] = {}  # each process's last
        self.parts: list[Status] = []  # the last statuses of the parts before a restart
        self.alive: set[str] = set()
        self.malformed = Malformed()
        self.drops = 0
        self.fallbacks = 0  # substituted values that fell back (no estimate to use)
        self.fallback_epochs: Counter[int] = Counter()  # epoch → those used at it
        # agent → (epoch, t) of its newest process's first state (seq 0) or its first after a gap
        self.returns: dict[int, tuple[int, float]] = {}
        self.team_events: list[tuple[float, str]] = []  # netem's running statuses (t, detail)
        self.run_id = run_id
        self._subs = [
            session.declare_subscriber(keys.agent_state(run_id, "*"), self._on_state),
            session.declare_subscriber(keys.pool_states(run_id, "*"), self._on_states),
            # Agent 1's part (realtime) or the parts' bundle (lockstep) says the leader
            # finished the epoch as well as the whole estimate does, by its attachment alone.
            session.declare_subscriber(keys.leader_estimate_for(run_id, 1), self._on_estimate),
            session.declare_subscriber(keys.leader_estimates(run_id), self._on_estimate),
            session.declare_subscriber(keys.netem_decision(run_id), self._on_decisions),
            session.declare_subscriber(keys.status_all(run_id), self._on_status),
            session.liveliness().declare_subscriber(
                keys.alive_all(run_id), self._on_alive, history=True
            ),
        ]

    def _decode(self, sample: zenoh.Sample, model: Any) -> Any:
        return self.malformed.decode(str(sample.key_expr), sample.payload.to_bytes(), model)

    def _on_state(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        args = keys.parse(key).args  # its own key only
        state = self._read_state(key, sample.payload.to_bytes(), args[0] if len(args) == 1 else "")
        if state is not None:
            with self.lock:
                self._keep(*state)

    def _on_states(self, sample: zenoh.Sample) -> None:
        """A pool's states in one bundle: each part as if it came alone, its pool's agents'."""
        key = str(sample.key_expr)
        try:
            parts = orjson.loads(sample.payload.to_bytes())["parts"]
            first = int(keys.parse(key).args[0])
            messages = [(int(p["agent"]), str(p["message"])) for p in parts]
        except (orjson.JSONDecodeError, KeyError, TypeError, ValueError):
            self.malformed.counts[key] += 1
            return
        read = self._read_state
        states = [read(key, message, str(i) if i >= first else "") for i, message in messages]
        with self.lock:
            for state in states:
                if state is not None:
                    self._keep(*state)

    def _read_state(self, key: str, payload: bytes | str, owner: str) -> _State | None:
        """A state on ``key``; None, counted there as malformed, unless its agent is ``owner``
        (the id its key, or its part of a pool's bundle, stands for)."""
        try:
            msg = orjson.loads(payload)
            k, i, seq = int(msg["epoch"]), int(msg["agent"]), int(msg["seq"])
            position = [float(v) for v in msg["position"]]
            subs = [
                (int(s["neighbour"]), [float(v) for v in s["value"]]) for s in msg["substituted"]
            ]
            fell = sum(bool(s.get("fallback")) for s in msg["substituted"])
            ok = 0 <= k <= self.scenario.epochs and 1 <= i <= self.scenario.n
            ok = ok and len(position) == self.scenario.dimension and str(i) == owner
        except (orjson.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError):
            ok = False
        if not ok:
            self.malformed.counts[key] += 1
            return None
        return k, i, seq, position, subs, fell

    def _keep(
        self,
        k: int,
        i: int,
        seq: int,
        position: list[float],
        subs: list[tuple[int, list[float]]],
        fell: int,
    ) -> None:
        """Agent ``i``'s state of epoch ``k`` (under :attr:`lock`)."""
        if seq == 0 or (k > 0 and np.isnan(self.positions[k - 1, i - 1, 0])):
            self.returns[i] = (k, time.monotonic())
        self.positions[k, i - 1] = position
        for j, value in subs:  # used at the previous epoch
            self.substitutions.append((k - 1, i, j, value))
        if fell:
            self.fallbacks += fell
            self.fallback_epochs[k - 1] += fell

    def _on_estimate(self, sample: zenoh.Sample) -> None:
        att = sample.attachment
        meta = read_attachment(None if att is None else att.to_bytes())
        if meta is None:
            self.malformed.counts[str(sample.key_expr)] += 1
            return
        with self.lock:
            self.estimated.add(meta[0])

    def _on_decisions(self, sample: zenoh.Sample) -> None:
        try:
            batch = orjson.loads(sample.payload.to_bytes())
            judged = [(str(j["verdict"]), str(j.get("model", ""))) for j in batch["judgements"]]
            records = batch["records"]
            columns = tuple(records[name] for name in _COLUMNS)
            link_class = LINK_CLASS_OF[batch["phase"]]
            index = np.array(records["judgement"], dtype=np.int64)
            ok = all(len(c) == len(index) for c in columns)
            ok = ok and (not len(index) or 0 <= index.min() <= index.max() < len(judged))
        except (orjson.JSONDecodeError, KeyError, TypeError, ValueError, OverflowError):
            ok = False
        if not ok:
            self.malformed.counts[str(sample.key_expr)] += 1
            return
        dropped = np.array([v == "drop" for v, _ in judged], dtype=bool)
        with self.lock:  # rows only when the run is over (decisions): thousands an epoch
            self._batches.append((link_class, judged, columns))
            self.drops += int(dropped[index].sum()) if len(judged) else 0

    @property
    def decisions(self) -> list[Verdict]:
        """Every decision received, in order (read under :attr:`lock`, as every field)."""
        batches = list(self._batches)  # one copy: a batch may be appended meanwhile
        return [
            Verdict(s, t, link_class, e, q, *judged[j])
            for link_class, judged, columns in batches
            for s, t, e, q, j in zip(*columns, strict=True)
        ]

    def _on_status(self, sample: zenoh.Sample) -> None:
        msg = self._decode(sample, Status)
        role, ident = keys.parse(str(sample.key_expr)).args
        if msg is not None and msg.sender != (
            f"{role}/{ident}" if role in ("agent", "pool") else role
        ):
            self.malformed.counts[str(sample.key_expr)] += 1  # another process's status
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


__all__ = ["Observer", "Verdict", "all_final", "flush_recorder", "missing_final"]
