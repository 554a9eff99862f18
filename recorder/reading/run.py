"""A recording as the record of a run (:class:`analysis.RunData`): the one decoder of a recording.

Every message of the recording and its rotated parts is validated and its owner checked
first (:class:`~recorder.reading.trust.Gate`; what it refuses is counted in
``RunData.recorded.skipped``). True positions from ``agent/<i>/state`` (sender side), the
leader's output from ``leader/estimate``, every packet's verdict from netem's decisions, the
substitutions each agent publishes with its next state. ``recorder.load_run`` is
``analysis.frames(read_run(path))``.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import fields
from operator import attrgetter
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from mcap.records import Channel, Message

from analysis import (
    Decisions,
    Recorded,
    RunData,
    Substitutions,
    consistency,
    edge_mask,
    formation_error,
    shape_error,
)
from formation.errors import RecordingError
from formation.messages import CoordinationState, DecisionBatch, LeaderEstimate
from formation.plugin_api import PLUGIN_FAILED
from formation.scenario import Scenario
from recorder.reading.bodies import RecordedPoses
from recorder.reading.reader import iter_messages, metadata, open_recording, parts, scenario_of
from recorder.reading.trust import Gate, derived_channels
from recorder.recording.schemas import ROS2, classify

Array = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]
Pose = tuple[float | None, int | None]
DECISION_COLUMNS = tuple(f.name for f in fields(Decisions))
ROBOT_COUNTS = "body_"  # the prefix of an agent's body counts in its status (agent.body)


class _Collected:
    """What :func:`read_run` takes from the trusted messages of one or more files."""

    def __init__(self, bulk: bool) -> None:
        # decisions as a list per column (bulk) or as rows
        self.columns: dict[str, list[Any]] | None = (
            {name: [] for name in DECISION_COLUMNS} if bulk else None
        )
        self.states: dict[tuple[int, int], list[float]] = {}  # (epoch, agent)
        self.poses: dict[tuple[int, int], Pose] = {}  # unicycles
        self.subs: dict[tuple[int, int], list[tuple[int, bool, list[float]]]] = {}
        self.ests: dict[int, LeaderEstimate] = {}
        self.decisions: list[tuple[Any, ...]] = []
        self.recorded: dict[int, float | None] = {}  # None: no edge in the team
        self.ended: list[str] = []  # why a process ended the run (a plug-in failed)
        self.bodies = RecordedPoses()  # the robots' poses (agent.body)
        self.robots: dict[str, dict[str, int]] = {}  # sender → its newest body counts

    def add(self, kind: str, msg: Any) -> None:
        if kind == "agent_state":
            state: CoordinationState = msg
            self.states[state.epoch, state.agent] = state.position
            if state.heading is not None or state.saturated is not None:
                self.poses[state.epoch, state.agent] = (state.heading, state.saturated)
            if state.substituted:  # used at the previous epoch; a repeat replaces, never adds
                self.subs[state.epoch - 1, state.agent] = [
                    (s.neighbour, s.fallback, s.value) for s in state.substituted
                ]
        elif kind == "leader_estimate":
            self.ests[msg.epoch] = msg
        elif kind == "metrics":
            self.recorded[msg.epoch] = msg.formation_error_m
        elif kind == "status":
            if msg.state == "error" and msg.detail.startswith(PLUGIN_FAILED):
                self.ended.append(f"{msg.sender}: {msg.detail.removeprefix(PLUGIN_FAILED)}")
            elif msg.detail.startswith("{") and ROBOT_COUNTS in msg.detail:
                self._robot_counts(msg.sender, msg.detail)
        elif kind == "decision":
            self._decisions(msg)

    def _decisions(self, batch: DecisionBatch) -> None:
        if self.columns is not None:
            for name, values in self.columns.items():
                if name == "phase":
                    values.extend([batch.phase] * len(batch.decisions))
                else:
                    values.extend(map(attrgetter(name), batch.decisions))
        else:
            self.decisions.extend(
                (
                    c.epoch,
                    batch.phase,
                    c.link_class,
                    c.source,
                    c.target,
                    c.seq,
                    c.verdict,
                    c.delay_epochs,
                    c.delay_ms,
                    c.model,
                    c.state,
                    c.queue,
                    c.queue_depth,
                    c.sojourn_ms,
                )
                for c in batch.decisions
            )

    def _robot_counts(self, sender: str, detail: str) -> None:
        """An agent's realtime status: its ``body_`` counts, the newest kept."""
        try:
            counts = json.loads(detail)
            self.robots[sender] = {
                k.removeprefix(ROBOT_COUNTS): int(v)
                for k, v in counts.items()
                if k.startswith(ROBOT_COUNTS)
            }
        except (ValueError, TypeError, AttributeError):
            return  # not counts: nothing to add

    def robot_counts(self) -> dict[str, int]:
        total: Counter[str] = Counter()
        for counts in self.robots.values():
            total.update(counts)
        return dict(total)

    def substitutions(self, d: int) -> Substitutions:
        rows = sorted((k, i, j, fb, v) for (k, i), got in self.subs.items() for j, fb, v in got)
        if not rows:
            return Substitutions.none(d)
        return Substitutions(
            epoch=np.array([r[0] for r in rows], dtype=np.int64),
            agent=np.array([r[1] for r in rows], dtype=np.int64),
            neighbour=np.array([r[2] for r in rows], dtype=np.int64),
            fallback=np.array([r[3] for r in rows], dtype=bool),
            values=np.array([r[4] for r in rows], dtype=float).reshape(-1, d),
        )


_WANTED = frozenset({"agent_state", "leader_estimate", "decision", "metrics", "status"})


def iter_trusted(
    path: Path,
    gate_of: Callable[[dict[str, dict[str, str]]], Gate] | None = None,
    by_chunk: bool = True,
) -> Iterator[tuple[str, Channel, Message, Any, Gate]]:
    """Every message of a recording (and its rotated parts) that its :class:`Gate` passes:
    ``(kind, channel, record, validated message, gate)``; the skips are in ``gate.skipped``.

    ``gate_of(meta)`` builds the gate once the first file's metadata is read (default: one
    for the stored scenario); ``by_chunk``: see :func:`~recorder.reading.reader.iter_messages`.
    """
    gate: Gate | None = None
    for part in parts(path):
        with open_recording(part) as (reader, summary):
            if gate is None:
                meta = metadata(reader)
                gate = gate_of(meta) if gate_of else Gate(scenario_of(meta, path))
            gate.derived_channels = derived_channels(summary.channels)
            for _, channel, msg in iter_messages(part, reader, by_chunk, log_time_order=False):
                kind = channel.metadata.get("kind") or classify(channel.topic)
                checked = gate.check(channel.topic, msg.data, kind, channel.id)
                if checked is not None:
                    yield kind, channel, msg, checked, gate


def read_run(path: Path | str, label: str | None = None) -> RunData:
    """A recording as :class:`~analysis.RunData`, with its rotated parts (``run-001.mcap``, ...).

    Needs the scenario stored as metadata. Every message is validated and its owner
    checked first (:mod:`recorder.reading.trust`); ``recorded.skipped`` counts what was not trusted.
    """
    return decode_run(path, label, bulk=True)


def decode_run(path: Path | str, label: str | None = None, *, bulk: bool) -> RunData:
    """:func:`read_run`; without ``bulk`` every state goes through its pydantic model and every
    record through the mcap reader's own loop (the same RunData: the baseline of the benchmark)."""
    path = Path(path)  # a str from a notebook too
    got = _Collected(bulk)
    held: dict[str, Any] = {}

    def gate_of(meta: dict[str, dict[str, str]]) -> Gate:
        scenario = scenario_of(meta, path)
        if scenario is None:
            raise RecordingError(str(path), "no scenario in the metadata (record with --scenario)")
        held.update(meta=meta, scenario=scenario, gate=Gate(scenario, plain_bulk=bulk))
        return held["gate"]  # type: ignore[no-any-return]

    for kind, channel, record, msg, _ in iter_trusted(path, gate_of, by_chunk=bulk):
        if kind in _WANTED:
            got.add(kind, msg)
        elif kind.startswith(ROS2):
            got.bodies.add(channel.topic, record, kind.removeprefix(ROS2))
    scenario: Scenario = held["scenario"]
    recorded = (held["meta"], held["gate"].skipped, tuple(got.ended), parts(path))
    return _assemble(scenario, path, label, got, recorded)


def _assemble(
    scenario: Scenario,
    path: Path,
    label: str | None,
    got: _Collected,
    recorded: tuple[Any, Any, tuple[str, ...], list[Path]],
) -> RunData:
    n, d = scenario.n, scenario.dimension
    states = _positions(got.states, n, d)
    x, computed = _measured(states, got.bodies.measured(scenario, len(states)))
    decisions = (
        Decisions.of_rows(got.decisions)
        if got.columns is None
        else Decisions.of_columns(got.columns)
    )
    epochs = [*got.ests, *decisions.epoch.tolist()]
    count = max(epochs) + 1 if epochs else max(len(x) - 1, 0)
    est = _estimates(scenario, got.ests, count)
    delivered, decided = decisions.delivery(scenario.directed_links, count)
    followers = np.arange(n) != scenario.reference_agent - 1
    nees_values, est_errors = consistency(
        x, est["estimates"], est["estimate_cov"], est["observable"] & followers
    )
    subs = got.substitutions(d)
    headings, saturated = _poses(scenario, got.poses, len(x))
    recorded_fe = np.full(len(x), np.nan)
    for k, v in got.recorded.items():
        if k < len(x):
            recorded_fe[k] = np.nan if v is None else v
    meta, skipped, ended, files = recorded
    return RunData(
        label=label or f"{scenario.name} {scenario.strategy.name}",
        scenario=scenario,
        strategy=scenario.strategy.name,
        seed=scenario.seed,
        positions=x,
        formation_error=formation_error(x, scenario.edge_array, scenario.weights),
        shape_error=shape_error(x, scenario.edge_array, scenario.offsets),
        substitution_errors=subs.known_errors(x),
        nees_values=nees_values,
        estimation_errors=est_errors,
        delivered=delivered,
        decided=decided,
        source=str(path),
        headings=headings,
        saturated=saturated,
        substitutions=subs,
        decisions=decisions,
        recorded=Recorded(
            meta,
            skipped,
            recorded_fe,
            ended,
            tuple(str(f) for f in files),
            got.robot_counts(),
        ),
        computed=computed,
        **est,
    )


def _measured(states: Array, measured: Array | None) -> tuple[Array, Array | None]:
    """The positions of a run: a robot's measured pose where one was recorded while its agent
    took part, else the agent's state; and the states those poses replace (NaN elsewhere)."""
    if measured is None:
        return states, None
    use = np.asarray(np.isfinite(measured).all(axis=2) & np.isfinite(states).all(axis=2))
    return np.where(use[:, :, None], measured, states), np.where(use[:, :, None], states, np.nan)


def _positions(states: dict[tuple[int, int], list[float]], n: int, d: int) -> Array:
    count = max(k for k, _ in states) + 1 if states else 0
    x = np.full((count, n, d), np.nan)
    for (k, i), pos in states.items():
        if 1 <= i <= n and len(pos) == d:
            x[k, i - 1] = pos
    return x


def _estimates(scenario: Scenario, ests: dict[int, LeaderEstimate], count: int) -> dict[str, Any]:
    n, d, m = scenario.n, scenario.dimension, len(scenario.edges)
    out: dict[str, Any] = {
        "estimates": np.full((count, n, d), np.nan),
        "estimate_cov": np.full((count, n, d, d), np.nan),
        "observable": np.zeros((count, n), dtype=bool),
        "estimated": np.zeros(count, dtype=bool),
        "healthy": np.zeros((count, m), dtype=bool),
        "tree": np.zeros((count, m), dtype=bool),
        "components": np.full(count, -1, dtype=np.int64),
        "rigidity_rank": np.full(count, -1, dtype=np.int64),
        "rigid": np.full(count, -1, dtype=np.int64),
    }
    for k, e in ests.items():
        if not 0 <= k < count:
            continue
        out["estimated"][k] = True
        for i, (p, c) in enumerate(zip(e.positions, e.covariances, strict=False)):
            if p is not None and i < n:
                out["estimates"][k, i] = p
            if c is not None and i < n:
                out["estimate_cov"][k, i] = c
        out["observable"][k, : len(e.observable[:n])] = e.observable[:n]
        out["healthy"][k] = edge_mask(scenario.edge_array, list(e.healthy))
        out["tree"][k] = edge_mask(scenario.edge_array, list(e.tree))
        out["components"][k], out["rigidity_rank"][k] = e.components, e.rigidity_rank
        out["rigid"][k] = e.rigid
    return out


def _poses(
    scenario: Scenario, poses: dict[tuple[int, int], Pose], count: int
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


__all__ = ["decode_run", "iter_trusted", "read_run"]
