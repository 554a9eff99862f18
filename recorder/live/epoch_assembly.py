"""What the recorder derives while recording: metrics, the agents' frames, the scene, the log.

The true positions of epoch ``k`` are the ``position`` fields of the
``CoordinationState`` messages on ``agent/<i>/state`` (sender side, before loss). An epoch
closes, in epoch order, once every agent that takes part at it has sent its state
(:class:`recorder.live.roster.Roster`: the scenario's events, netem's team statuses),
or once it is known to be over (a state two epochs later, or the leader's estimate of it).
Then the assembler emits ``EpochMetrics`` (docs/model.md §7, over the team) and the agents'
``foxglove.FrameTransforms``; an agent without a state is out, drawn where its body was.
The scene of epoch ``k`` also needs the leader's estimate of ``k`` (link health, tree,
BLUE) and netem's decisions on the formation links of ``k``; it is emitted once all are
in, in epoch order (:class:`EpochAssembler`). Statuses and netem's link changes become
``foxglove.Log`` lines (:mod:`recorder.live.logs`). No clock, no I/O: payloads in,
``(key, payload)`` out, a function of the order they came in (so a replay of the recording
derives the same); the messages' ``stamp_ns`` comes from an injected clock.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from analysis import edge_mask, errors_of_team
from formation import keys
from formation.codec import encode, now_ns
from formation.messages import (
    CoordinationState,
    DecisionBatch,
    EpochMetrics,
    LeaderEstimate,
    LinkChange,
    Status,
)
from formation.scenario import Scenario
from recorder.live.logs import change_log, status_log
from recorder.live.robots import POSE_KINDS, LiveRobots
from recorder.live.roster import Roster, team_detail
from recorder.live.scene import frame_transforms, scene_update
from recorder.reading.bundle_checks import StateParts
from recorder.reading.trust import Gate

Derived = tuple[str, bytes]
CLOSE_AFTER = 2  # a state this many epochs later closes an epoch still missing some
WAIT_EPOCHS = 256  # a scene waits this far behind for its epoch's estimate and decisions
# The channel kinds the assembler reads.
TAPS = (
    "agent_state",
    "state_bundle",
    "leader_estimate",
    "decision",
    "status",
    "link_change",
    *POSE_KINDS,
)


@dataclass(frozen=True)
class Closed:
    """An epoch's states once closed: positions (n, d) [m], bodies for the agents out;
    ``team`` (n,) its state came; headings (n,) [rad] (NaN: none) of a unicycle team."""

    positions: npt.NDArray[np.float64]
    team: npt.NDArray[np.bool_]
    headings: npt.NDArray[np.float64] | None


class EpochAssembler:
    """Collects true states, estimates and decisions per epoch; emits metrics and scenes.

    Epochs close in order (:meth:`_closable`), each with the agents whose state came
    before it closed; a state that comes later is counted (:attr:`late`), not drawn.
    The scene of epoch ``k`` is drawn once everything it shows is in: its closed states,
    the leader's estimate of ``k`` (unless netem says the leader is down) and netem's
    decision on every formation link of ``k`` between agents taking part (netem sends the
    decisions of closed epochs in batches, so they may come many epochs late). Scenes go
    out in epoch order, so the same seed gives the same scenes whatever the timing. A
    scene still missing a part when the newest closed epoch is :data:`WAIT_EPOCHS` ahead
    (a recording that filters decisions out) is drawn with what it has, as is every
    epoch left at the end.
    """

    def __init__(
        self,
        scenario: Scenario,
        run_id: str,
        sender: str = "recorder",
        clock: Callable[[], int] = now_ns,
    ) -> None:
        self.scenario, self.run_id, self.sender, self._clock = scenario, run_id, sender, clock
        self.n, self.d = scenario.n, scenario.dimension
        self.edges = scenario.edge_array
        self.roster = Roster(scenario)
        self.robots = LiveRobots(scenario, run_id)  # realtime robot bodies' measured poses
        self._bodies = scenario.initial_positions()  # where each agent was last seen [m]
        self._states: dict[int, dict[int, list[float]]] = {}
        self._headings: dict[int, dict[int, float]] = {}  # unicycles' θ_i[k] [rad]
        self._closed: dict[int, Closed] = {}  # closed, scene not yet out
        self._est: dict[int, LeaderEstimate] = {}
        self._decided: Counter[int] = Counter()
        self._lost: dict[int, list[tuple[int, int]]] = {}
        self._next_close = self._next_scene = 0
        self._newest_state = self._newest_estimate = -1
        self._seq: Counter[str] = Counter()
        self.gate = Gate(scenario, conflicts=False)  # what it skips: gate.skipped
        self.incomplete = 0  # epochs closed without an agent the plan has (lost, or late)
        self.late = 0  # states that came after their epoch had closed
        self.drawn_early = 0  # scenes drawn before every part of their epoch was in

    def on_state(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """A ``CoordinationState`` from ``agent/<i>/state``; only one its agent sent about itself
        (:class:`recorder.reading.trust.Gate`), the first of its epoch."""
        state = self.gate.check(key, payload, "agent_state")
        if not isinstance(state, CoordinationState) or not self._take_state(state):
            return []
        return self._advance(stamp_ns)

    def on_states(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """A pool's states in one ``Bundle`` on ``agent/pool/<p>/state``: each part taken as
        if it came alone (the trust gate passes only the parts it would pass so)."""
        parts = self.gate.check(key, payload, "state_bundle")
        if not isinstance(parts, StateParts):
            return []
        taken = [self._take_state(state) for state in parts.states]
        return self._advance(stamp_ns) if any(taken) else []

    def _take_state(self, state: CoordinationState) -> bool:
        """Keep ``state`` if it is the first of its agent and epoch, of an epoch still open."""
        if state.epoch > self.scenario.epochs:
            return False
        if state.epoch < self._next_close:
            self.late += 1
            return False
        got = self._states.setdefault(state.epoch, {})
        if state.agent in got:
            return False
        got[state.agent] = state.position
        self.robots.on_state(state.agent, state.epoch, state.position)
        if state.heading is not None:
            self._headings.setdefault(state.epoch, {})[state.agent] = state.heading
        self._newest_state = max(self._newest_state, state.epoch)
        return True

    def on_estimate(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """A ``LeaderEstimate`` from ``leader/estimate``: health, tree and BLUE of its epoch."""
        est = self.gate.check(key, payload, "leader_estimate")
        if not isinstance(est, LeaderEstimate) or est.epoch < self._next_scene:
            return []
        self._est.setdefault(est.epoch, est)
        self._newest_estimate = max(self._newest_estimate, est.epoch)
        return self._advance(stamp_ns)

    def on_decision(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """A ``DecisionBatch`` from ``netem/decision``: which formation packets were lost."""
        batch = self.gate.check(key, payload, "decision")
        if not isinstance(batch, DecisionBatch):
            return []
        if batch.phase != "state":
            return self._scenes(stamp_ns)
        lost = [j.verdict not in ("pass", "duplicate") or j.delay_epochs for j in batch.judgements]
        records = batch.records
        for s, t, k, j in zip(
            records.source, records.target, records.epoch, records.judgement, strict=True
        ):
            if k < self._next_scene:
                continue
            self._decided[k] += 1
            if lost[j]:
                self._lost.setdefault(k, []).append((s, t))
        return self._scenes(stamp_ns)

    def on_status(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """A process's ``Status``: a log line when it says something (:func:`status_log`);
        netem's team status also says who is down (:meth:`Roster.on_team`)."""
        status = self.gate.check(key, payload, "status")
        if not isinstance(status, Status):
            return []
        line = status_log(status, stamp_ns)
        out = [] if line is None else [(keys.log(self.run_id), line.encode())]
        team = team_detail(status.detail) if status.role == "netem" else None
        if team is None:
            return out
        self.roster.on_team(team)
        return out + self._advance(stamp_ns)

    def on_link_change(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """netem's ``LinkChange``: a log line."""
        change = self.gate.check(key, payload, "link_change")
        if not isinstance(change, LinkChange):
            return []
        return [(keys.log(self.run_id), change_log(change, stamp_ns).encode())]

    def on_pose(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """A robot's pose on ``body/<i>/pose/<type>``, once the trust gate has passed it."""
        if self.gate.check(key, payload) is None:
            return []
        return self.robots.on_pose(key, payload, stamp_ns)

    def on(self, kind: str, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """Any tapped message by its channel kind (:data:`TAPS`)."""
        return self._on[kind](key, payload, stamp_ns)

    @property
    def _on(self) -> dict[str, Callable[[str, bytes, int], list[Derived]]]:
        return {
            "agent_state": self.on_state,
            "state_bundle": self.on_states,
            "leader_estimate": self.on_estimate,
            "decision": self.on_decision,
            "status": self.on_status,
            "link_change": self.on_link_change,
            **dict.fromkeys(POSE_KINDS, self.on_pose),
        }

    def finish(self, stamp_ns: int) -> list[Derived]:
        """Close every epoch up to the newest state, then draw every scene still waiting."""
        out: list[Derived] = []
        while self._next_close <= self._newest_state:
            out += self._close(stamp_ns)
        for k in sorted(self._closed):
            self.drawn_early += not self._ready(k)
            out.append(self._scene(k, stamp_ns))
        return out

    def _closable(self, k: int) -> bool:
        """Whether epoch ``k``'s states are all in, or will not all come."""
        if k > self.scenario.epochs:
            return False
        got = self._states.get(k, {})
        if (got or k <= self._newest_state) and self.roster.complete(k, got.keys()):
            return True
        return self._newest_state >= k + CLOSE_AFTER or self._newest_estimate >= k

    def _advance(self, stamp_ns: int) -> list[Derived]:
        out: list[Derived] = []
        while self._closable(self._next_close):
            out += self._close(stamp_ns)
        return out + self._scenes(stamp_ns)

    def _close(self, stamp_ns: int) -> list[Derived]:
        """Epoch ``_next_close`` with the states it has: its metrics and frames."""
        k = self._next_close
        self._next_close += 1
        got = self._states.pop(k, {})
        th = self._headings.pop(k, None)
        self.incomplete += not self.roster.planned(k) <= got.keys()
        team = np.zeros(self.n, dtype=bool)
        for i, p in got.items():
            self._bodies[i - 1], team[i - 1] = p, True
        x = self._bodies.copy()
        headings = (
            None if th is None else np.array([th.get(i, np.nan) for i in range(1, self.n + 1)])
        )
        self._closed[k] = Closed(x, team, headings)
        return [
            self._metrics(k, x, team),
            (keys.frames(self.run_id), frame_transforms(x, stamp_ns).encode()),
        ]

    def _ready(self, k: int) -> bool:
        if k >= self.scenario.epochs:  # the final states: no estimate, no decisions
            return True
        estimated = k in self._est or not self.roster.estimated(k)
        return estimated and self._decided[k] >= self.roster.decisions(k, self._closed[k].team)

    def _scenes(self, stamp_ns: int) -> list[Derived]:
        """Scenes of the closed epochs now ready, in epoch order from the next one to draw."""
        out = []
        while (k := self._next_scene) in self._closed:
            late = self._next_close - 1 - k > WAIT_EPOCHS
            ready = self._ready(k)
            if not (ready or late):
                break
            self.drawn_early += not ready
            out.append(self._scene(k, stamp_ns))
        return out

    def _header(self, key: str, epoch: int) -> dict[str, Any]:
        seq = self._seq[key]
        self._seq[key] += 1
        return {
            "run_id": self.run_id,
            "sender": self.sender,
            "seq": seq,
            "epoch": epoch,
            "stamp_ns": self._clock(),
        }

    def _metrics(self, k: int, x: npt.NDArray[np.float64], team: npt.NDArray[np.bool_]) -> Derived:
        s = self.scenario
        key = keys.metrics(self.run_id)
        fe, se = errors_of_team(x, team, self.edges, s.weights, s.offsets)
        msg = EpochMetrics(
            **self._header(key, k),
            formation_error_m=_finite_or_none(fe),
            shape_error_m=_finite_or_none(se),
            positions=x.tolist(),
            out=[int(i) + 1 for i in np.flatnonzero(~team)],
        )
        return key, encode(msg)

    def _scene(self, k: int, stamp_ns: int) -> Derived:
        closed = self._closed.pop(k)
        self._next_scene = max(self._next_scene, k + 1)
        est = self._est.pop(k, None)
        self._decided.pop(k, None)
        lost = self._lost.pop(k, [])
        s = self.scenario
        healthy = tree = None
        if est is not None:
            healthy = edge_mask(self.edges, list(est.healthy))
            tree = edge_mask(self.edges, list(est.tree))
        scene = scene_update(
            k,
            stamp_ns,
            closed.positions,
            self.edges,
            s.offsets,
            s.reference_agent,
            healthy,
            tree,
            lost,
            None if est is None else est.positions,
            None if est is None else est.covariances,
            closed.headings,
            ~closed.team,
        )
        return keys.scene(self.run_id), scene.encode()


def _finite_or_none(value: npt.NDArray[np.float64]) -> float | None:
    """An error [m] for the wire; None where no edge was between agents taking part (NaN)."""
    v = float(value)
    return None if np.isnan(v) else v


__all__ = ["CLOSE_AFTER", "TAPS", "WAIT_EPOCHS", "Closed", "Derived", "EpochAssembler"]
