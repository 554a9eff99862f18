"""A recording as the record of a run (:class:`analysis.RunData`): the one decoder of a recording.

Every message of the recording and its rotated parts is validated and its owner checked
first (:class:`~recorder.reading.trust.Gate`; what it refuses is counted in
``RunData.recorded.skipped``). True positions from ``agent/<i>/state`` (sender side), the
leader's output from ``leader/estimate``, every packet's verdict from netem's decisions, the
substitutions each agent publishes with its next state. ``recorder.load_run`` is
``analysis.frames(read_run(path))``.
"""

from __future__ import annotations

import gc
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from mcap.records import Channel, Message
from mcap.summary import Summary

from analysis import Recorded, RunData, consistency, formation_error, shape_error
from formation.errors import RecordingError
from formation.scenario import Scenario
from recorder.reading.chunks import Record
from recorder.reading.collected import Collected, poses, positions, substitutions
from recorder.reading.estimates import estimates
from recorder.reading.reader import (
    iter_chunks,
    iter_messages,
    metadata,
    open_recording,
    open_whole,
    parts,
    scenario_of,
)
from recorder.reading.state_batch import judge_bundles, judge_states
from recorder.reading.trust import Gate
from recorder.recording.schemas import ROS2, classify, derived_channels

Array = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]


_STATE, _BUNDLE = "agent_state", "state_bundle"
_WANTED = frozenset({_STATE, _BUNDLE, "leader_estimate", "decision", "metrics", "status"})


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
    """:func:`read_run`; without ``bulk`` every message goes through its pydantic model and the
    gate one at a time, and every record through the mcap reader's own loop (the same RunData:
    the baseline of the benchmark)."""
    path = Path(path)  # a str from a notebook too
    held: dict[str, Any] = {}

    def gate_of(meta: dict[str, dict[str, str]]) -> Gate:
        scenario = scenario_of(meta, path)
        if scenario is None:
            raise RecordingError(str(path), "no scenario in the metadata (record with --scenario)")
        held.update(meta=meta, scenario=scenario, gate=Gate(scenario, plain_bulk=bulk))
        held["got"] = Collected(bulk, scenario.dimension)
        return held["gate"]  # type: ignore[no-any-return]

    if bulk:
        with _collector_paused():
            _read_by_chunk(path, gate_of, held)
    else:
        for kind, channel, record, msg, _ in iter_trusted(path, gate_of, by_chunk=False):
            _take(held["got"], kind, channel, record, msg)
    scenario: Scenario = held["scenario"]
    got: Collected = held["got"]
    recorded = (held["meta"], held["gate"].skipped, tuple(got.ended), parts(path))
    return _assemble(scenario, path, label, got, recorded)


@contextmanager
def _collector_paused() -> Iterator[None]:
    """Python's cycle collector off while a million acyclic objects are made: each of its
    passes walks every object alive, the recording's read so far included."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _take(got: Collected, kind: str, channel: Channel, record: Message, msg: Any) -> None:
    if kind in _WANTED:
        got.add(kind, msg)
    elif kind.startswith(ROS2):
        got.bodies.add(channel.topic, record, kind.removeprefix(ROS2))


def _read_by_chunk(
    path: Path, gate_of: Callable[[dict[str, dict[str, str]]], Gate], held: dict[str, Any]
) -> None:
    """Every trusted message of the recording into ``held["got"]``, a chunk at a time: its
    agent states judged together (:func:`~recorder.reading.state_batch.judge_states`), the
    rest, or every message of a chunk whose states are not plainly good, one by one (the
    pools' state bundles likewise, judged together apart from the states)."""
    gate: Gate | None = None
    for part in parts(path):
        with open_whole(part) as (f, summary, meta):
            if gate is None:
                gate = gate_of(meta)
            gate.derived_channels = derived_channels(summary.channels)
            kinds = _kinds(summary)
            for records in iter_chunks(part, f, summary):
                _read_chunk(gate, held["got"], summary, kinds, records)
    if gate is not None:  # a million keys and epochs, which the collector would walk next
        gate.seen.clear()


def _kinds(summary: Summary) -> dict[int, str]:
    return {
        cid: channel.metadata.get("kind") or classify(channel.topic)
        for cid, channel in summary.channels.items()
    }


def _read_chunk(
    gate: Gate, got: Collected, summary: Summary, kinds: dict[int, str], records: list[Record]
) -> None:
    channels = summary.channels
    for judged, judge in ((_STATE, judge_states), (_BUNDLE, judge_bundles)):
        of_kind = [kinds[r[0]] for r in records]
        states = [r for r, kind in zip(records, of_kind, strict=True) if kind == judged]
        block = (
            judge(gate, [channels[r[0]].topic for r in states], [r[4] for r in states])
            if states
            else None
        )
        if block is not None:
            got.blocks.append(block)
            records = [r for r, kind in zip(records, of_kind, strict=True) if kind != judged]
    for channel_id, sequence, log_time, publish_time, data in records:
        kind = kinds[channel_id]
        channel = channels[channel_id]
        msg = gate.check(channel.topic, data, kind, channel_id)
        if msg is not None:
            record = Message(
                channel_id=channel_id,
                log_time=log_time,
                data=data,
                publish_time=publish_time,
                sequence=sequence,
            )
            _take(got, kind, channel, record, msg)


def _assemble(
    scenario: Scenario,
    path: Path,
    label: str | None,
    got: Collected,
    recorded: tuple[Any, Any, tuple[str, ...], list[Path]],
) -> RunData:
    n, d = scenario.n, scenario.dimension
    states = got.states()
    x = positions(states, n, d)
    x, computed = _measured(x, got.bodies.measured(scenario, len(x)))
    decisions = got.decisions_of_run()
    epochs = [*got.ests, int(decisions.epoch.max(initial=-1))]
    count = max(epochs) + 1 if max(epochs) >= 0 else max(len(x) - 1, 0)
    est = estimates(scenario, got.ests, count, got.est_arrays)
    delivered, decided = decisions.delivery(scenario.directed_links, count)
    followers = np.arange(n) != scenario.reference_agent - 1
    nees_values, est_errors = consistency(
        x, est["estimates"], est["estimate_cov"], est["observable"] & followers
    )
    subs = substitutions(states, d)
    headings, saturated = (
        poses(states, n, len(x)) if scenario.control.dynamics == "unicycle" else (None, None)
    )
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


__all__ = ["decode_run", "iter_trusted", "read_run"]
