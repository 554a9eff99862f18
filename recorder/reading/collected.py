"""What :func:`recorder.read_run` takes from a recording's trusted messages, gathered as arrays.

States come as blocks (:class:`~recorder.reading.state_batch.StateBlock`): a chunk's at once
from the batch path, or one by one from the gate's own path; netem's decisions as columns.
Both become the arrays of :class:`analysis.RunData` here.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import fields
from typing import Any

import numpy as np
import numpy.typing as npt

from analysis import Decisions, Substitutions
from formation.messages import LINK_CLASS_OF, DecisionBatch, Judgement
from formation.plugin_api import PLUGIN_FAILED
from recorder.reading.bodies import RecordedPoses
from recorder.reading.bulk import decision_columns, judgement_columns
from recorder.reading.estimates import EstimateArrays, estimate_arrays
from recorder.reading.state_batch import StateBlock

Array = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]
ROBOT_COUNTS = "body_"  # the prefix of an agent's body counts in its status (agent.body)
DECISION_COLUMNS = tuple(f.name for f in fields(Decisions) if f.compare)
JUDGED = tuple(Judgement.model_fields)  # the last of DECISION_COLUMNS, in their order


class Collected:
    """What :func:`~recorder.reading.run.read_run` takes from the trusted messages of one or
    more files; ``bulk``: decisions as arrays a batch at a time, else as rows."""

    def __init__(self, bulk: bool, d: int) -> None:
        self.d = d
        # with bulk: each batch's record columns, phase and judgements' columns
        self.batches: list[tuple[dict[str, Ints], str, dict[str, Any]]] | None = (
            [] if bulk else None
        )
        self.blocks: list[StateBlock] = []
        self.rows: list[Any] = []  # states one by one, a block at the end
        self.ests: dict[int, Any] = {}  # the leader's estimates by epoch
        self.est_arrays: dict[int, EstimateArrays | None] = {}  # and as arrays
        self.decisions: list[tuple[Any, ...]] = []
        self.recorded: dict[int, float | None] = {}  # None: no edge in the team
        self.ended: list[str] = []  # why a process ended the run (a plug-in failed)
        self.bodies = RecordedPoses()  # the robots' poses (agent.body)
        self.robots: dict[str, dict[str, int]] = {}  # sender → its newest body counts

    def add(self, kind: str, msg: Any) -> None:
        if kind == "agent_state":
            self.rows.append(msg)
        elif kind == "state_bundle":
            self.rows.extend(msg.states)  # the trusted parts
        elif kind == "leader_estimate":
            self.ests[msg.epoch] = msg
            self.est_arrays[msg.epoch] = estimate_arrays(msg, self.d)  # the gate's, kept
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
        records = batch.records
        if self.batches is None:
            head = (batch.phase, LINK_CLASS_OF[batch.phase])
            judged = [tuple(getattr(j, name) for name in JUDGED) for j in batch.judgements]
            self.decisions.extend(
                (e, *head, s, t, q, *judged[j])  # in DECISION_COLUMNS' order
                for s, t, e, q, j in zip(
                    records.source,
                    records.target,
                    records.epoch,
                    records.seq,
                    records.judgement,
                    strict=True,
                )
            )
            return
        if records.source:
            columns = decision_columns(batch)  # the gate's, kept
            self.batches.append((columns, batch.phase, judgement_columns(batch.judgements)))

    def decisions_of_run(self) -> Decisions:
        if self.batches is None:
            return Decisions.of_rows(self.decisions)
        if not self.batches:
            return Decisions.of_columns({name: [] for name in DECISION_COLUMNS})
        return _joined(self.batches)

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

    def states(self) -> StateBlock:
        """Every trusted state, in one block."""
        blocks = [*self.blocks, StateBlock.of_rows(self.rows, self.d)]
        offsets = np.cumsum([0, *(len(b.epoch) for b in blocks[:-1])])
        joined = {
            name: np.concatenate([getattr(b, name) for b in blocks])
            for name in StateBlock.__dataclass_fields__
        }
        joined["sub_state"] = np.concatenate(
            [b.sub_state + at for b, at in zip(blocks, offsets, strict=True)]
        )
        return StateBlock(**joined)


def positions(states: StateBlock, n: int, d: int) -> Array:
    """(P, n, d) each agent's state at each epoch [m], NaN where none was trusted."""
    count = int(states.epoch.max()) + 1 if len(states.epoch) else 0
    x = np.full((count, n, d), np.nan)
    ok = (states.agent >= 1) & (states.agent <= n)
    x[states.epoch[ok], states.agent[ok] - 1] = states.position[ok]
    return x


def poses(states: StateBlock, n: int, count: int) -> tuple[Array, Ints]:
    """Recorded headings (count, n) [rad] and saturation counts (count − 1, n) of a unicycle
    team; NaN and −1 where not recorded."""
    headings = np.full((count, n), np.nan)
    saturated = np.full((max(count - 1, 0), n), -1, dtype=np.int64)
    k, i = states.epoch, states.agent
    ok = (k >= 0) & (k < count) & (i >= 1) & (i <= n)
    headings[k[ok], i[ok] - 1] = states.heading[ok]
    step = ok & (k >= 1)  # a state of k counts the step from k − 1
    saturated[k[step] - 1, i[step] - 1] = states.saturated[step]
    return headings, saturated


def substitutions(states: StateBlock, d: int) -> Substitutions:
    """The values each agent used, the epoch before its state: a repeated state counts once."""
    if not len(states.sub_state):
        return Substitutions.none(d)
    base = int(states.agent.max()) + 1
    _, first = np.unique(states.epoch * base + states.agent, return_index=True)
    keep = np.isin(states.sub_state, first)
    row = states.sub_state[keep]
    epoch, agent = states.epoch[row] - 1, states.agent[row]
    neighbour, fallback = states.sub_neighbour[keep], states.sub_fallback[keep]
    values = states.sub_value[keep]
    order = np.lexsort((*values.T[::-1], fallback, neighbour, agent, epoch))
    return Substitutions(
        epoch=epoch[order],
        agent=agent[order],
        neighbour=neighbour[order],
        fallback=fallback[order],
        values=values[order].reshape(-1, d),
    )


def _joined(batches: list[tuple[dict[str, Ints], str, dict[str, Any]]]) -> Decisions:
    """Every batch's records as one table: their judgements' values taken once per record
    from the batches' judgements joined (a batch holds few), not batch by batch."""
    counts = [len(columns["epoch"]) for columns, _, _ in batches]
    out: dict[str, Any] = {
        name: np.concatenate([columns[name] for columns, _, _ in batches])
        for name in ("epoch", "source", "target", "seq")
    }
    offsets = np.cumsum([0, *(len(judged["verdict"]) for _, _, judged in batches[:-1])])
    index = np.concatenate(
        [c["judgement"] + offset for (c, _, _), offset in zip(batches, offsets, strict=True)]
    )
    coded: dict[str, tuple[Ints, Any]] = {}
    for name in JUDGED:
        values = np.concatenate([judged[name] for _, _, judged in batches])
        if values.dtype == object:  # text: codes into the batches' few values
            of_judgement, distinct = _factorized(values)
            coded[name] = (of_judgement[index], distinct)
            out[name] = distinct[coded[name][0]]
        else:
            out[name] = values[index]
    phases = sorted({phase for _, phase, _ in batches})
    codes = np.repeat([phases.index(phase) for _, phase, _ in batches], counts)
    coded["phase"] = (codes, np.array(phases, dtype=object))
    coded["link_class"] = (codes, np.array([LINK_CLASS_OF[p] for p in phases], dtype=object))
    out["phase"], out["link_class"] = coded["phase"][1][codes], coded["link_class"][1][codes]
    return Decisions(**out, coded=coded)


def _factorized(values: npt.NDArray[Any]) -> tuple[Ints, npt.NDArray[Any]]:
    """Codes into the distinct values (None among them) of a short object array."""
    index: dict[Any, int] = {}
    codes = np.fromiter((index.setdefault(v, len(index)) for v in values), np.int64, len(values))
    distinct = np.empty(len(index), dtype=object)
    distinct[:] = list(index)
    return codes, distinct


__all__ = ["Collected", "poses", "positions", "substitutions"]
