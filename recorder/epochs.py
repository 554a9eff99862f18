"""What the recorder derives per epoch while recording: metrics and the Foxglove scene.

The true positions of epoch ``k`` are the ``position`` fields of the
``CoordinationState`` messages on ``agent/<i>/state`` (sender side, before loss).
When all ``n`` have arrived the assembler emits ``EpochMetrics`` (docs/model.md §7).
The scene of epoch ``k`` also needs the leader's estimate of ``k`` (link health,
tree); it is emitted when that estimate arrives, or when a later epoch completes,
or at the end, whichever comes first (edges then drawn grey). No clock, no I/O:
payloads in, ``(key, payload)`` out; the
messages' ``stamp_ns`` comes from an injected clock.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from formation import keys
from formation.codec import encode, now_ns
from formation.messages import CoordinationState, EpochMetrics, LeaderEstimate
from formation.scenario import Scenario
from recorder.metrics import formation_error, shape_error
from recorder.scene import scene_update
from recorder.trust import Gate

Derived = tuple[str, bytes]
STALE_EPOCHS = 8  # an incomplete epoch this far behind the newest complete one is given up


def edge_mask(edges: npt.NDArray[np.int64], pairs: list[tuple[int, int]]) -> npt.NDArray[np.bool_]:
    """Which of ``edges`` (m, 2) appear, in either order, in ``pairs``."""
    wanted = {(min(a, b), max(a, b)) for a, b in pairs}
    return np.array([(int(i), int(j)) in wanted for i, j in edges], dtype=bool)


class EpochAssembler:
    """Collects true states per epoch; emits metrics and scenes for the recording."""

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
        self._states: dict[int, dict[int, list[float]]] = {}
        self._waiting: dict[int, npt.NDArray[np.float64]] = {}  # complete, scene not yet out
        self._health: dict[int, tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]] = {}
        self._newest = -1
        self._seq: Counter[str] = Counter()
        self.gate = Gate(scenario, conflicts=False)  # what it skips: gate.skipped
        self.given_up = 0  # epochs whose states never all arrived

    def on_state(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """A ``CoordinationState`` from ``agent/<i>/state``; only one its agent sent about itself
        (:class:`recorder.trust.Gate`), the first of its epoch."""
        state = self.gate.check(key, payload, "agent_state")
        if not isinstance(state, CoordinationState):
            return []
        got = self._states.setdefault(state.epoch, {})
        if state.agent in got:
            return []
        got[state.agent] = state.position
        if len(got) < self.n:
            return []
        k = state.epoch
        del self._states[k]
        x = np.array([got[i] for i in range(1, self.n + 1)], dtype=float)
        out = [self._metrics(k, x)]
        self._newest = max(self._newest, k)
        self._waiting[k] = x
        for j in sorted(self._waiting):
            if j in self._health or j < k:
                out.append(self._scene(j, stamp_ns))
        self._prune()
        return out

    def on_estimate(self, key: str, payload: bytes, stamp_ns: int) -> list[Derived]:
        """A ``LeaderEstimate`` from ``leader/estimate``: health and tree of its epoch."""
        est = self.gate.check(key, payload, "leader_estimate")
        if not isinstance(est, LeaderEstimate):
            return []
        self._health[est.epoch] = (
            edge_mask(self.edges, list(est.healthy)),
            edge_mask(self.edges, list(est.tree)),
        )
        if est.epoch in self._waiting:
            return [self._scene(est.epoch, stamp_ns)]
        return []

    def finish(self, stamp_ns: int) -> list[Derived]:
        """Scenes of every complete epoch still waiting for an estimate."""
        return [self._scene(k, stamp_ns) for k in sorted(self._waiting)]

    def _prune(self) -> None:
        for k in [k for k in self._states if k < self._newest - STALE_EPOCHS]:
            del self._states[k]
            self.given_up += 1
        for k in [k for k in self._health if k < self._newest - STALE_EPOCHS]:
            del self._health[k]

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
        healthy, tree = self._health.pop(k, (None, None))
        s = self.scenario
        scene = scene_update(k, stamp_ns, x, self.edges, s.offsets, s.leader, healthy, tree)
        return keys.scene(self.run_id), json.dumps(scene, separators=(",", ":")).encode()


__all__ = ["STALE_EPOCHS", "Derived", "EpochAssembler", "edge_mask"]
