"""What the recorder derives while recording: metrics, the agents' frames, the scene, the log.

The true positions of epoch ``k`` are the ``position`` fields of the
``CoordinationState`` messages on ``agent/<i>/state`` (sender side, before loss).
When all ``n`` have arrived the assembler emits ``EpochMetrics`` (docs/model.md §7)
and the agents' ``foxglove.FrameTransforms``.
The scene of epoch ``k`` also needs the leader's estimate of ``k`` (link health,
tree, BLUE) and netem's decisions on the formation links of ``k``; it is emitted once
all are in, in epoch order (:class:`EpochAssembler`). Statuses and netem's link changes
become ``foxglove.Log`` lines (:mod:`recorder.live.logs`). No clock, no I/O:
payloads in, ``(key, payload)`` out; the
messages' ``stamp_ns`` comes from an injected clock.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

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
from recorder.analysis.metrics import formation_error, shape_error
from recorder.live.logs import change_log, status_log
from recorder.live.scene import frame_transforms, scene_update
from recorder.reading.trust import Gate

Derived = tuple[str, bytes]
STALE_EPOCHS = 8  # an incomplete epoch this far behind the newest complete one is given up
WAIT_EPOCHS = 256  # a scene waits this far behind for its epoch's estimate and decisions
# The channel kinds the assembler reads.
TAPS = ("agent_state", "leader_estimate", "decision", "status", "link_change")


def edge_mask(edges: npt.NDArray[np.int64], pairs: list[tuple[int, int]]) -> npt.NDArray[np.bool_]:
    """Which of ``edges`` (m, 2) appear, in either order, in ``pairs``."""
    wanted = {(min(a, b), max(a, b)) for a, b in pairs}
    return np.array([(int(i), int(j)) in wanted for i, j in edges], dtype=bool)


class EpochAssembler:
    """Collects true states, estimates and decisions per epoch; emits metrics and scenes.

    The scene of epoch ``k`` is drawn once everything it shows is in: all ``n`` states of
    ``k``, the leader's estimate of ``k`` and netem's decision on every formation link of
    ``k`` (one per directed link; netem sends the decisions of clean epochs in batches,
    so they may come many epochs late). Scenes go out in epoch order, so the same seed
    gives the same scenes whatever the timing. An epoch still missing a part when the
    newest complete epoch is :data:`WAIT_EPOCHS` ahead (a dead sender, a recording that
    filters decisions out) is drawn with what it has, as is every epoch left at the end.
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
        self.links = len(scenario.directed_links)  # formation decisions per epoch
        self._states: dict[int, dict[int, list[float]]] = {}
        self._waiting: dict[int, npt.NDArray[np.float64]] = {}  # complete, scene not yet out
        self._headings: dict[int, dict[int, float]] = {}  # unicycles' θ_i[k] [rad]
        self._est: dict[int, LeaderEstimate] = {}
        self._decided: Counter[int] = Counter()
        self._lost: dict[int, list[tuple[int, int]]] = {}
        self._next_scene = 0
        self._newest = -1
        self._seq: Counter[str] = Counter()
        self.gate = Gate(scenario, conflicts=False)  # what it skips: gate.skipped
        self.given_up = 0  # epochs whose states never all arrived
        self.drawn_early = 0  # scenes drawn before every part of their epoch was in

    def on_state(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """A ``CoordinationState`` from ``agent/<i>/state``; only one its agent sent about itself
        (:class:`recorder.reading.trust.Gate`), the first of its epoch."""
        state = self.gate.check(key, payload, "agent_state")
        if not isinstance(state, CoordinationState) or state.epoch < self._next_scene:
            return []
        got = self._states.setdefault(state.epoch, {})
        if state.agent in got:
            return []
        got[state.agent] = state.position
        if state.heading is not None:
            self._headings.setdefault(state.epoch, {})[state.agent] = state.heading
        if len(got) < self.n:
            return []
        k = state.epoch
        del self._states[k]
        x = np.array([got[i] for i in range(1, self.n + 1)], dtype=float)
        self._newest = max(self._newest, k)
        self._waiting[k] = x
        out = [
            self._metrics(k, x),
            (keys.frames(self.run_id), frame_transforms(x, stamp_ns).encode()),
        ]
        self._prune()
        return out + self._scenes(stamp_ns)

    def on_estimate(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """A ``LeaderEstimate`` from ``leader/estimate``: health, tree and BLUE of its epoch."""
        est = self.gate.check(key, payload, "leader_estimate")
        if not isinstance(est, LeaderEstimate) or est.epoch < self._next_scene:
            return []
        self._est.setdefault(est.epoch, est)
        return self._scenes(stamp_ns)

    def on_decision(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """A ``DecisionBatch`` from ``netem/decision``: which formation packets were lost."""
        batch = self.gate.check(key, payload, "decision")
        if not isinstance(batch, DecisionBatch):
            return []
        for dec in batch.decisions:
            if dec.link_class != "formation" or dec.epoch < self._next_scene:
                continue
            self._decided[dec.epoch] += 1
            if dec.verdict not in ("pass", "duplicate") or dec.delay_epochs:
                self._lost.setdefault(dec.epoch, []).append((dec.source, dec.target))
        return self._scenes(stamp_ns)

    def on_status(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """A process's ``Status``: a log line when it says something (:func:`status_log`)."""
        status = self.gate.check(key, payload, "status")
        line = status_log(status, stamp_ns) if isinstance(status, Status) else None
        return [] if line is None else [(keys.log(self.run_id), line.encode())]

    def on_link_change(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """netem's ``LinkChange``: a log line."""
        change = self.gate.check(key, payload, "link_change")
        if not isinstance(change, LinkChange):
            return []
        return [(keys.log(self.run_id), change_log(change, stamp_ns).encode())]

    def on(self, kind: str, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """Any tapped message by its channel kind (:data:`TAPS`)."""
        return self._on[kind](key, payload, stamp_ns)

    @property
    def _on(self) -> dict[str, Callable[[str, bytes, int], list[Derived]]]:
        return {
            "agent_state": self.on_state,
            "leader_estimate": self.on_estimate,
            "decision": self.on_decision,
            "status": self.on_status,
            "link_change": self.on_link_change,
        }

    def finish(self, stamp_ns: int) -> list[Derived]:
        """Scenes of every complete epoch still waiting, with what they have."""
        out = []
        for k in sorted(self._waiting):
            self.drawn_early += not self._ready(k)
            out.append(self._scene(k, stamp_ns))
        return out

    def _ready(self, k: int) -> bool:
        if k >= self.scenario.epochs:  # the final states: no estimate, no decisions
            return True
        return k in self._est and self._decided[k] >= self.links

    def _scenes(self, stamp_ns: int) -> list[Derived]:
        """Scenes of the epochs now ready, in epoch order from the next one to draw."""
        out = []
        while True:
            k = self._next_scene
            if k in self._waiting:
                late = self._newest - k > WAIT_EPOCHS
                if not (self._ready(k) or late):
                    break
                self.drawn_early += late and not self._ready(k)
                out.append(self._scene(k, stamp_ns))
            elif k in self._states or k >= self._newest:
                break  # its states are still coming (or nothing newer is complete)
            self._next_scene = k + 1  # drawn, or its states were given up
            self._est.pop(k, None), self._decided.pop(k, None), self._lost.pop(k, None)
        return out

    def _prune(self) -> None:
        for k in [k for k in self._states if k < self._newest - STALE_EPOCHS]:
            del self._states[k]
            self._headings.pop(k, None)
            self.given_up += 1

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

    def _metrics(self, k: int, x: npt.NDArray[np.float64]) -> Derived:
        s = self.scenario
        key = keys.metrics(self.run_id)
        msg = EpochMetrics(
            **self._header(key, k),
            formation_error_m=float(formation_error(x, self.edges, s.weights)),
            shape_error_m=float(shape_error(x, self.edges, s.offsets)),
            positions=x.tolist(),
        )
        return key, encode(msg)

    def _scene(self, k: int, stamp_ns: int) -> Derived:
        x = self._waiting.pop(k)
        est = self._est.pop(k, None)
        self._decided.pop(k, None)
        lost = self._lost.pop(k, [])
        th = self._headings.pop(k, None)
        s = self.scenario
        healthy = tree = None
        if est is not None:
            healthy = edge_mask(self.edges, list(est.healthy))
            tree = edge_mask(self.edges, list(est.tree))
        scene = scene_update(
            k,
            stamp_ns,
            x,
            self.edges,
            s.offsets,
            s.leader,
            healthy,
            tree,
            lost,
            None if est is None else est.positions,
            None if est is None else est.covariances,
            None if th is None else np.array([th.get(i, np.nan) for i in range(1, self.n + 1)]),
        )
        return keys.scene(self.run_id), scene.encode()


__all__ = ["STALE_EPOCHS", "TAPS", "WAIT_EPOCHS", "Derived", "EpochAssembler", "edge_mask"]
