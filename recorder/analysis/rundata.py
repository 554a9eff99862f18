"""One run as arrays, from a recording or from the in-process simulator: the record of a run.

:class:`RunData` is what every summary reads (:func:`recorder.analysis.summary.summarise`): the
recorder's (:func:`read_run`), the simulator's (``SimResult``, a subclass) and the launcher's
(``RunOutcome.record()``, what it saw over Zenoh). From a recording
(:func:`read_run`): true positions from ``agent/<i>/state`` (sender side), the
leader's output from ``leader/estimate``, link delivery from netem's decisions.
Substitution errors from the ``substituted`` values each agent publishes with its
next state, against the recorded truth.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from mcap.records import Channel, Message

from formation.errors import RecordingError
from formation.messages import CoordinationState, LeaderEstimate
from formation.plugin_api import PLUGIN_FAILED
from formation.rigidity import expected_rigidity_rank
from formation.scenario import Scenario
from recorder.analysis import membership
from recorder.analysis.epoch_assembly import edge_mask
from recorder.analysis.metrics import formation_error, nees, shape_error
from recorder.analysis.queues import Judged, loss_split, queue_table
from recorder.reading.reader import iter_messages, metadata, open_recording, parts, scenario_of
from recorder.reading.trust import Gate, Skipped, derived_channels
from recorder.recording.schemas import classify

Array = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]


@dataclass
class RunData:
    """A run as arrays; row ``i − 1`` is agent ``i``; ``P`` epochs of states, ``E`` of estimates.

    positions : (P, n, d) true positions [m], NaN where not recorded
    present : (P, n) in the team: its state of the epoch recorded (default: finite
    ``positions``; the simulator's bodies stay where they were, so it marks them itself)
    formation_error, shape_error : (P,) [m] over every edge
    estimates : (E, n, d) [m]; estimate_cov : (E, n, d, d) [m²]; observable : (E, n)
    delivered : (E, L) formation link ``links[l]`` delivered in time at epoch ``k``
    decided : (E, L) whether that delivery is known (always True from the simulator)
    healthy, tree : (E, m) per formation edge; components, rigidity_rank : (E,), −1 if unknown
    rigid : (E,) 1 rigid, 0 not, −1 unknown (default: from ``rigidity_rank``)
    substitution_errors : (N, d); nees_values : (M,); estimation_errors : (M, d) [m]
    headings : (P, n) [rad], NaN where not recorded; saturated : (P − 1, n) sub-steps of the step
    from epoch ``k`` with a clipped speed, −1 where not recorded (unicycle only, else None)
    """

    label: str
    scenario: Scenario
    strategy: str
    seed: int
    positions: Array
    formation_error: Array
    shape_error: Array
    estimates: Array
    estimate_cov: Array
    observable: Bools
    delivered: Bools
    healthy: Bools
    tree: Bools
    components: Ints
    rigidity_rank: Ints
    substitution_errors: Array
    nees_values: Array
    estimation_errors: Array
    decided: Bools = field(default_factory=lambda: np.zeros(0, dtype=bool))
    source: str = "simulation"
    extra: dict[str, Any] = field(default_factory=dict)
    headings: Array | None = None
    saturated: Ints | None = None
    present: Bools = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))
    rigid: Ints = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self) -> None:
        if self.decided.shape != self.delivered.shape:  # the simulator knows every delivery
            self.decided = np.ones_like(self.delivered, dtype=bool)
        if self.present.shape != self.positions.shape[:2]:
            self.present = membership.present(self.positions)
        if self.rigid.shape != self.rigidity_rank.shape:  # ranks say it where they are known
            s = self.scenario
            full = self.rigidity_rank == expected_rigidity_rank(s.n, s.dimension)
            self.rigid = np.where(self.rigidity_rank < 0, -1, full).astype(np.int64)

    @property
    def links(self) -> Ints:
        """Directed formation links (L, 2), the columns of :attr:`delivered`."""
        return self.scenario.directed_links


def _positions(states: dict[int, dict[int, list[float]]], n: int, d: int) -> Array:
    count = max(states) + 1 if states else 0
    x = np.full((count, n, d), np.nan)
    for k, by_agent in states.items():
        for i, pos in by_agent.items():
            if 1 <= i <= n and len(pos) == d:
                x[k, i - 1] = pos
    return x


def _estimates(scenario: Scenario, ests: dict[int, dict[str, Any]], count: int) -> dict[str, Any]:
    n, d, m = scenario.n, scenario.dimension, len(scenario.edges)
    out: dict[str, Any] = {
        "estimates": np.full((count, n, d), np.nan),
        "estimate_cov": np.full((count, n, d, d), np.nan),
        "observable": np.zeros((count, n), dtype=bool),
        "healthy": np.zeros((count, m), dtype=bool),
        "tree": np.zeros((count, m), dtype=bool),
        "components": np.full(count, -1, dtype=np.int64),
        "rigidity_rank": np.full(count, -1, dtype=np.int64),
        "rigid": np.full(count, -1, dtype=np.int64),
    }
    for k, e in ests.items():
        for i, (p, c) in enumerate(zip(e["positions"], e["covariances"], strict=False)):
            if p is not None and c is not None and i < n:
                out["estimates"][k, i], out["estimate_cov"][k, i] = p, c
        out["observable"][k, : len(e["observable"][:n])] = e["observable"][:n]
        out["healthy"][k] = edge_mask(scenario.edge_array, [tuple(p) for p in e["healthy"]])
        out["tree"][k] = edge_mask(scenario.edge_array, [tuple(p) for p in e["tree"]])
        out["components"][k], out["rigidity_rank"][k] = e["components"], e["rigidity_rank"]
        out["rigid"][k] = e["rigid"]
    return out


def _consistency(scenario: Scenario, x: Array, est: dict[str, Any]) -> tuple[Array, Array]:
    """NEES values and estimation errors ``x̂ − x`` of observable followers, epoch by epoch."""
    d = scenario.dimension
    followers = np.arange(scenario.n) != scenario.reference_agent - 1
    values, errors = [], []
    for k in range(min(len(x), len(est["estimates"]))):
        truth = x[k]
        mask = est["observable"][k] & followers & np.isfinite(truth).all(axis=1)
        mask &= np.isfinite(est["estimates"][k]).all(axis=1)
        mask &= np.abs(np.linalg.det(np.nan_to_num(est["estimate_cov"][k]))) > 0  # ideal sensors
        if mask.any():
            values.append(nees(est["estimates"][k], est["estimate_cov"][k], truth, mask))
            errors.append(est["estimates"][k][mask] - truth[mask])
    nees_values = np.concatenate(values) if values else np.zeros(0)
    return nees_values, np.concatenate(errors) if errors else np.zeros((0, d))


def _substitution_errors(x: Array, subs: list[tuple[int, int, int, list[float]]], d: int) -> Array:
    """``x̃_j[k] − x_j[k]`` for every recorded substitute whose truth was recorded."""
    rows = [np.asarray(v, dtype=float) - x[k, j - 1] for k, _, j, v in subs if 0 <= k < len(x)]
    rows = [r for r in rows if np.isfinite(r).all()]
    return np.array(rows).reshape(-1, d)


class _Collected:
    """What :func:`read_run` takes from the messages of one or more files, each one first
    validated and its owner checked by a :class:`~recorder.reading.trust.Gate` (skips are counted there)."""

    def __init__(self) -> None:
        self.states: dict[int, dict[int, list[float]]] = {}
        self.subs: dict[tuple[int, int], list[tuple[int, list[float]]]] = {}  # (epoch, agent)
        self.ests: dict[int, dict[str, Any]] = {}
        self.verdicts: list[tuple[int, int, int, bool]] = []
        self.judged: list[Judged] = []  # drops and queued packets of every link class
        self.recorded: dict[int, float | None] = {}  # None: no edge in the team
        self.poses: dict[tuple[int, int], tuple[float | None, int | None]] = {}  # unicycles
        self.ended: list[str] = []  # why a process ended the run (a plug-in failed)

    def add(self, kind: str, msg: Any) -> None:
        if kind == "agent_state":
            state: CoordinationState = msg
            self.states.setdefault(state.epoch, {})[state.agent] = state.position
            if state.heading is not None or state.saturated is not None:
                self.poses[state.epoch, state.agent] = (state.heading, state.saturated)
            if state.substituted:  # used at the previous epoch; a repeat replaces, never adds
                self.subs[state.epoch - 1, state.agent] = [
                    (s.neighbour, s.value) for s in state.substituted
                ]
        elif kind == "leader_estimate":
            est: LeaderEstimate = msg
            self.ests[est.epoch] = {
                "positions": est.positions,
                "covariances": est.covariances,
                "observable": est.observable,
                "healthy": est.healthy,
                "tree": est.tree,
                "components": est.components,
                "rigidity_rank": est.rigidity_rank,
                "rigid": est.rigid,
            }
        elif kind == "metrics":
            self.recorded[msg.epoch] = msg.formation_error_m
        elif kind == "status":
            if msg.state == "error" and msg.detail.startswith(PLUGIN_FAILED):
                self.ended.append(f"{msg.sender}: {msg.detail.removeprefix(PLUGIN_FAILED)}")
        elif kind == "decision":
            for dec in msg.decisions:
                if dec.verdict == "drop" or dec.queue is not None:
                    self.judged.append(
                        Judged(
                            dec.epoch,
                            dec.verdict,
                            dec.model,
                            dec.queue,
                            dec.queue_depth,
                            dec.sojourn_ms,
                        )
                    )
                if dec.link_class == "formation":
                    on_time = dec.verdict in ("pass", "duplicate") and dec.delay_epochs == 0
                    self.verdicts.append((dec.epoch, dec.source, dec.target, on_time))

    @property
    def substitutes(self) -> list[tuple[int, int, int, list[float]]]:
        """``(epoch used, agent, neighbour, x̃)``, sorted."""
        return sorted((k, i, j, v) for (k, i), rows in self.subs.items() for j, v in rows)


_WANTED = frozenset({"agent_state", "leader_estimate", "decision", "metrics", "status"})


def iter_trusted(
    path: Path, gate_of: Any = None
) -> Iterator[tuple[str, Channel, Message, Any, Gate]]:
    """Every message of a recording (and its rotated parts) that its :class:`Gate` passes:
    ``(kind, channel, record, validated message, gate)``; the skips are in ``gate.skipped``.

    ``gate_of(meta)`` builds the gate once the first file's metadata is read (default: one
    for the stored scenario).
    """
    gate: Gate | None = None
    for part in parts(path):
        with open_recording(part) as (reader, summary):
            if gate is None:
                meta = metadata(reader)
                gate = gate_of(meta) if gate_of else Gate(scenario_of(meta, path))
            gate.derived_channels = derived_channels(summary.channels)
            for _, channel, msg in iter_messages(part, reader, log_time_order=False):
                kind = channel.metadata.get("kind") or classify(channel.topic)
                checked = gate.check(channel.topic, msg.data, kind, channel.id)
                if checked is not None:
                    yield kind, channel, msg, checked, gate


def read_run(path: Path | str, label: str | None = None) -> RunData:
    """A recording as :class:`RunData`, with its rotated parts (``run-001.mcap``, ...) if any.

    Needs the scenario stored as metadata. Every message is validated and its owner
    checked first (:mod:`recorder.reading.trust`); ``extra["skipped"]`` counts what was not trusted.
    """
    path = Path(path)  # a str from a notebook too
    got = _Collected()
    holder: dict[str, Any] = {}

    def gate_of(meta: dict[str, dict[str, str]]) -> Gate:
        scenario = scenario_of(meta, path)
        if scenario is None:
            raise RecordingError(str(path), "no scenario in the metadata (record with --scenario)")
        holder["meta"], holder["scenario"] = meta, scenario
        holder["gate"] = Gate(scenario)
        return holder["gate"]  # type: ignore[no-any-return]

    for kind, _, _, msg, _ in iter_trusted(path, gate_of):
        if kind in _WANTED:
            got.add(kind, msg)
    gate: Gate = holder["gate"]
    return _assemble(holder["scenario"], path, label, got, holder["meta"], gate.skipped)


def _capacity(scenario: Scenario, judged: list[Judged], epochs: int) -> dict[str, Any]:
    """``queues`` and ``losses`` (channel, queue, deadline) of a run with capacity queues."""
    if not scenario.network.capacity:
        return {}
    return {"queues": queue_table(judged, epochs), "loss_split": loss_split(judged)}


def _assemble(
    scenario: Scenario,
    path: Path,
    label: str | None,
    got: _Collected,
    meta: dict[str, dict[str, str]],
    skipped: Skipped,
) -> RunData:
    n, d = scenario.n, scenario.dimension
    x = _positions(got.states, n, d)
    ests, verdicts, recorded = got.ests, got.verdicts, got.recorded
    epochs = [*ests, *(v[0] for v in verdicts)]
    count = max(epochs) + 1 if epochs else max(len(x) - 1, 0)
    est = _estimates(scenario, ests, count)
    column = {(int(a), int(b)): c for c, (a, b) in enumerate(scenario.directed_links)}
    delivered = np.zeros((count, len(column)), dtype=bool)
    decided = np.zeros_like(delivered)
    for k, a, b, ok in verdicts:
        c = column.get((a, b))
        if c is not None and 0 <= k < count:
            delivered[k, c], decided[k, c] = ok, True
    nees_values, est_errors = _consistency(scenario, x, est)
    headings, saturated = _poses(scenario, got.poses, len(x))
    recorded_fe = np.full(len(x), np.nan)
    for k, v in recorded.items():
        if k < len(x):
            recorded_fe[k] = np.nan if v is None else v
    return RunData(
        label=label or f"{scenario.name} {scenario.strategy.name}",
        scenario=scenario,
        strategy=scenario.strategy.name,
        seed=scenario.seed,
        positions=x,
        formation_error=formation_error(x, scenario.edge_array, scenario.weights),
        shape_error=shape_error(x, scenario.edge_array, scenario.offsets),
        substitution_errors=_substitution_errors(x, got.substitutes, d),
        nees_values=nees_values,
        estimation_errors=est_errors,
        delivered=delivered,
        decided=decided,
        source=str(path),
        extra={
            **_capacity(scenario, got.judged, count),
            "recorded_formation_error": recorded_fe,
            "metadata": meta,
            "skipped": skipped,
            **({"ended": got.ended} if got.ended else {}),
        },
        headings=headings,
        saturated=saturated,
        **est,
    )


def _poses(
    scenario: Scenario, poses: dict[tuple[int, int], tuple[float | None, int | None]], count: int
) -> tuple[Array | None, Ints | None]:
    """Recorded headings (P, n) and saturation counts (P − 1, n) of a unicycle team, else None."""
    if scenario.control.dynamics != "unicycle":
        return None, None
    headings = np.full((count, scenario.n), np.nan)
    saturated = np.full((max(count - 1, 0), scenario.n), -1, dtype=np.int64)
    for (k, i), (h, sat) in poses.items():
        if 0 <= k < count and 1 <= i <= scenario.n:
            if h is not None:
                headings[k, i - 1] = h
            if sat is not None and k >= 1:
                saturated[k - 1, i - 1] = sat  # a state of k counts the step from k − 1
    return headings, saturated


__all__ = ["RunData", "iter_trusted", "read_run"]
