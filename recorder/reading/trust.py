"""Reading a recording without trusting the wire: every message validated and its owner checked.

Any process on the machine can publish into a local run, and in a closed deployment an
agent can still put anything on its own keys. Everything that reads a recording for
analysis (``formation report``, ``info``, ``replay``, the run's summary, the experiments,
:func:`recorder.load_run`) goes through one :class:`Gate`, which passes a message only when

- it validates against the pydantic model of its channel's kind (:data:`recorder.recording.schemas.MESSAGE_MODELS`;
  netem's decision batches of an older recording, as rows, are read into columns:
  :mod:`recorder.reading.row_batches`),
  with finite numbers of the scenario's dimension; the recorder's Foxglove channels (scene,
  frames, log) decode as the SDK's protobuf message (:mod:`recorder.reading.decoder`; read in
  bulk, a scene on a channel the recorder marked as its own only down to its entities' ids);
- its sender owns the key: ``agent/<i>/…`` and link ``i → j`` carry ``agent/<i>`` (or a pool
  ``pool/<a>`` with ``a ≤ i``) and ``agent = i``; the leader's keys ``leader``; netem's
  ``netem``; ``status/<role>/<id>`` its process; the recorder's own channels (metrics, scene,
  frames, log) only what the recorder wrote itself (channel metadata ``origin = recorder``);
- its epoch, agent ids, links and edges exist in the scenario;
- it does not contradict an earlier message of the same key and epoch (the first one
  stays; an identical repeat, e.g. a republished final state, is not a fault).

Every other message is skipped and counted per channel (topic) and reason
(:data:`REASONS`). Nothing here raises on a payload.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np
import numpy.typing as npt
from google.protobuf.message import Message
from msgspec import Struct
from pydantic import BaseModel, ValidationError

from formation import keys
from formation.messages import (
    LINK_CLASS_OF,
    AgentEstimate,
    CoordinationState,
    DecisionBatch,
    Delivery,
    DeliveryBatch,
    EpochMetrics,
    LeaderEstimate,
    LinkChange,
    Status,
    TokenReport,
)
from formation.scenario import Scenario
from recorder.reading.bulk import DECODERS, decision_columns, plain
from recorder.reading.bundle_checks import BUNDLE_CHECKS
from recorder.reading.decision_shape import check_shape, records_in_range
from recorder.reading.decoder import DecodeError, decode_cdr, decode_kind, scene_outline
from recorder.reading.estimates import estimate_arrays
from recorder.reading.row_batches import row_batch
from recorder.reading.skips import (
    CONFLICT,
    FORGED,
    INVALID,
    OUT_OF_RANGE,
    REASONS,
    UNKNOWN_KEY,
    Skip,
    Skipped,
)
from recorder.reading.value_checks import all_finite, finite, within
from recorder.recording.schemas import (
    FOXGLOVE,
    MESSAGE_MODELS,
    ORIGIN,
    RECORDER,
    ROS2,
    UNKNOWN,
    CdrMessage,
    LivelinessEvent,
    classify,
)

DERIVED = frozenset({"metrics", *FOXGLOVE})  # kinds only the recorder writes
# many per epoch (a pool's batches: one per input netem handled)
_REPEATED = frozenset({"status", "decision", "alive", "link_change", "delivery_batch"})

Args = tuple[str, ...]  # the open chunks of a key, in order: keys.parse(topic).args


class Gate:
    """Validates recorded messages and checks their owners against ``scenario``.

    Without a scenario (a recording that stores none) only the models and the key owners
    are checked. ``derived_channels``: ids of the channels the recorder marked as its own
    (channel metadata ``origin = recorder``,
    :func:`recorder.recording.schemas.derived_channels`); when given, metrics
    and scenes on other channels are counted as forged.
    """

    def __init__(
        self,
        scenario: Scenario | None,
        derived_channels: set[int] | None = None,
        conflicts: bool = True,
        plain_bulk: bool = False,
    ) -> None:
        self.scenario = scenario
        self.derived_channels = derived_channels
        self.conflicts = conflicts  # remember each (key, epoch) to refuse a different second one
        # the bulk kinds as msgspec structs (recorder.reading.bulk), the recorder's scenes outlined
        self.plain_bulk = plain_bulk
        self.skipped = Skipped()
        self.passed: Counter[str] = Counter()
        self._codes: npt.NDArray[np.int64] | None = None  # formation links, as codes
        self._edge_codes: npt.NDArray[np.int64] | None = None  # formation edges, as codes
        self.seen: dict[tuple[str, int], int] = {}  # (topic, epoch) -> hash of the first payload
        # Realtime netem sends a receiver a delivery per wake-up: several of one epoch are normal.
        realtime = scenario is not None and scenario.runtime.mode == "realtime"
        self.repeated = _REPEATED | {"delivery"} if realtime else _REPEATED
        if scenario is not None:
            self.n, self.d, self.epochs = scenario.n, scenario.dimension, scenario.epochs
            self.links = {(int(a), int(b)) for a, b in scenario.directed_links}
            self.edges = {
                (min(int(a), int(b)), max(int(a), int(b))) for a, b in scenario.edge_array
            }

    # -- the one entry ----------------------------------------------------------------------
    def check(
        self, topic: str, data: bytes, kind: str | None = None, channel_id: int | None = None
    ) -> BaseModel | Message | Struct | None:
        """The validated message (a model; a decoded protobuf message for the Foxglove
        channels; with ``plain_bulk`` a state, decisions, an estimate or metrics as a struct of
        :mod:`recorder.reading.bulk` and a scene the recorder marked as its own as its outline,
        :func:`~recorder.reading.decoder.scene_outline`), or None after counting the skip."""
        kind = kind or classify(topic)
        try:
            msg = self._check(kind, topic, data, channel_id)
        except Skip as skip:
            self.skipped.add(topic, skip.reason, str(skip))
            return None
        self.passed[kind] += 1
        return msg

    def _check(
        self, kind: str, topic: str, data: bytes, channel_id: int | None
    ) -> BaseModel | Message | Struct:
        derived = self.derived_channels
        if kind in DERIVED and derived is not None and channel_id not in derived:
            raise Skip(FORGED, f"{kind} not written by the recorder")
        if kind in FOXGLOVE:
            return self._foxglove(kind, data, self.plain_bulk and derived is not None)
        if kind.startswith(ROS2):
            return self._cdr(kind.removeprefix(ROS2), topic, data)
        model = MESSAGE_MODELS.get(kind)
        if model is None or kind == UNKNOWN:
            raise Skip(UNKNOWN_KEY, f"no process publishes on {topic}")
        msg: BaseModel | Struct | None = (
            plain(kind, data) if self.plain_bulk and kind in DECODERS else None
        )
        if msg is None:
            try:
                msg = model.model_validate_json(data)
            except (ValidationError, ValueError, UnicodeDecodeError) as exc:
                msg = row_batch(data) if kind == "decision" else None  # an older recording's
                if msg is None:
                    raise Skip(INVALID, f"{model.__name__}: {str(exc).splitlines()[0]}") from None
        bundle = BUNDLE_CHECKS.get(kind)
        if bundle is not None:
            parts = bundle(self, msg, topic)  # type: ignore[arg-type]
            if parts is not None:
                return parts  # each part checked for contradictions as if it came alone
        elif (check := getattr(self, f"_{kind}", None)) is not None:
            check(msg, keys.parse(topic).args)
        epoch = getattr(msg, "epoch", None)
        if self.conflicts and isinstance(epoch, int) and epoch >= 0 and kind not in self.repeated:
            self._first(topic, epoch, data)
        return msg

    def _cdr(self, type_name: str, topic: str, data: bytes) -> CdrMessage:
        """An agent's body traffic: a ROS 2 message of its type in CDR, on its agent's key."""
        self._agent(self._key_id(keys.parse(topic).args[0]))
        try:
            decode_cdr(type_name, data)
        except DecodeError as exc:
            raise Skip(INVALID, str(exc)) from None
        return CdrMessage(type_name=type_name, size=len(data))

    # -- shared checks ----------------------------------------------------------------------
    def _first(self, topic: str, epoch: int, data: bytes) -> None:
        digest = hash(data)
        if self.seen.setdefault((topic, epoch), digest) != digest:
            raise Skip(CONFLICT, f"a different message of epoch {epoch} came first")

    def _epoch(self, epoch: int, last: int | None = None, first: int = 0) -> None:
        if self.scenario is None:
            return
        last = self.epochs if last is None else last
        if not first <= epoch <= last:
            raise Skip(OUT_OF_RANGE, f"epoch {epoch} not in {first}..{last}")

    def _agent(self, i: int, what: str = "agent") -> None:
        if self.scenario is not None and not 1 <= i <= self.n:
            raise Skip(OUT_OF_RANGE, f"{what} {i} not in 1..{self.n}")

    def _endpoint(self, i: int) -> None:
        if self.scenario is not None and not 0 <= i <= self.n:
            raise Skip(OUT_OF_RANGE, f"endpoint {i} not in 0..{self.n}")

    def _dim(self) -> int | None:
        return None if self.scenario is None else self.d

    @staticmethod
    def _key_id(part: str) -> int:
        try:
            return int(part)
        except ValueError:
            raise Skip(UNKNOWN_KEY, f"{part!r} is not an id") from None

    @staticmethod
    def owned_by_agent(sender: str, agent: int) -> bool:
        """``agent/<i>``, or ``pool/<a>`` (a pool is named by its first id) with ``a ≤ i``."""
        role, _, ident = sender.partition("/")
        if role == "agent":
            return ident == str(agent)
        return role == "pool" and ident.isdigit() and int(ident) <= agent

    def _sender(self, msg: Any, owner: str) -> None:
        if msg.sender != owner:
            raise Skip(FORGED, f"sender {msg.sender!r} on a key of {owner!r}")

    def _agent_sender(self, msg: Any, i: int) -> None:
        if not self.owned_by_agent(msg.sender, i):
            raise Skip(FORGED, f"sender {msg.sender!r} on a key of agent {i}")
        if msg.agent != i:
            raise Skip(FORGED, f"agent {msg.agent} on a key of agent {i}")

    def _state(self, msg: CoordinationState, i: int) -> None:
        self._agent_sender(msg, i)
        self._agent(i)
        self._epoch(msg.epoch)
        d = self._dim()
        finite(msg.position, d, "position")
        if msg.velocity is not None:
            finite(msg.velocity, d, "velocity")
        for s in msg.substituted:
            self._agent(s.neighbour, "neighbour")
            if self.scenario is not None and (s.neighbour, i) not in self.links:
                raise Skip(OUT_OF_RANGE, f"no link {s.neighbour}->{i} to substitute")
            finite(s.value, d, "substituted value")

    def _report(self, msg: TokenReport, i: int) -> None:
        self._agent_sender(msg, i)
        self._agent(i)
        self._epoch(msg.epoch, self._last_decided())
        for m in msg.measurements:
            self._agent(m.neighbour, "neighbour")
            if m.z is not None:
                finite(m.z, self._dim(), "measurement")

    def _agent_part(self, msg: AgentEstimate, i: int) -> None:
        self._sender(msg, "leader")
        self._agent(i)
        if msg.agent != i:
            raise Skip(FORGED, f"agent {msg.agent} on a key of agent {i}")
        self._epoch(msg.epoch, self._last_decided())
        for j in msg.neighbours:
            self._agent(j, "neighbour")
        for p in msg.positions:
            if p is not None:
                finite(p, self._dim(), "estimate")
        finite(msg.v_ref, self._dim(), "v_ref")

    def _last_decided(self) -> int | None:
        """The last epoch with decisions, reports and estimates (states go one further)."""
        return None if self.scenario is None else self.epochs - 1

    # -- per kind (named after the channel kinds of recorder.recording.schemas) --------------------------
    def _agent_state(self, msg: CoordinationState, args: Args) -> None:
        self._state(msg, self._key_id(args[0]))

    def _link_state(self, msg: CoordinationState, args: Args) -> None:
        i, j = self._key_id(args[0]), self._key_id(args[1])
        if self.scenario is not None and (i, j) not in self.links:
            raise Skip(OUT_OF_RANGE, f"no formation link {i}->{j}")
        self._state(msg, i)

    def _agent_report(self, msg: TokenReport, args: Args) -> None:
        self._report(msg, self._key_id(args[0]))

    def _leader_report(self, msg: TokenReport, args: Args) -> None:
        self._report(msg, self._key_id(args[0]))

    def _agent_estimate(self, msg: AgentEstimate, args: Args) -> None:
        self._agent_part(msg, self._key_id(args[0]))

    def _link_estimate(self, msg: AgentEstimate, args: Args) -> None:
        self._agent_part(msg, self._key_id(args[0]))  # its key starts at the leader: keys.parse

    def _leader_estimate(self, msg: LeaderEstimate, args: Args) -> None:
        self._sender(msg, "leader")
        self._epoch(msg.epoch, self._last_decided())
        d = self._dim()
        arrays = None if d is None else estimate_arrays(msg, d)
        if self.scenario is not None:
            n = self.n
            sizes = (len(msg.positions), len(msg.covariances), len(msg.observable))
            if sizes != (n, n, n):
                raise Skip(INVALID, f"positions, covariances, observable of sizes {sizes}, not {n}")
            known = arrays is not None and self._edges_known([arrays.tree, arrays.healthy])
            for pair in [] if known else [*msg.tree, *msg.healthy]:  # the one at fault, named
                if (min(pair), max(pair)) not in self.edges:
                    raise Skip(OUT_OF_RANGE, f"edge {pair} not in the formation")
        if arrays is None or not (
            np.isfinite(arrays.positions).all() and np.isfinite(arrays.covariances).all()
        ):  # the one at fault, named
            for p in msg.positions:
                if p is not None:
                    finite(p, d, "estimate")
            for c in msg.covariances:
                if c is not None:
                    if d is not None and len(c) != d:
                        raise Skip(INVALID, f"a covariance with {len(c)} rows, expected {d}")
                    for row in c:
                        finite(row, d, "covariance row")
        finite(msg.x_ref, d, "x_ref")
        finite(msg.v_ref, d, "v_ref")

    def _delivery(self, msg: Delivery, args: Args) -> None:
        self._sender(msg, "netem")
        receiver = self._key_id(args[0])
        if msg.receiver != receiver or msg.phase != args[1]:
            raise Skip(FORGED, f"a delivery for {msg.receiver}/{msg.phase} on {args[0]}/{args[1]}")
        self._endpoint(receiver)
        self._epoch(msg.epoch, self._last_decided())
        for p in msg.packets:
            self._endpoint(p.source)

    def _delivery_batch(self, msg: DeliveryBatch, args: Args) -> None:
        """A pool's deliveries: on its pool's and phase's key, each one with its packets from the
        batch's table as if it came alone."""
        self._sender(msg, "netem")
        pool = self._key_id(args[0])
        if msg.pool != pool or msg.phase != args[1]:
            raise Skip(FORGED, f"a batch for pool {msg.pool}/{msg.phase} on {args[0]}/{args[1]}")
        self._agent(pool)
        self._epoch(msg.epoch, self._last_decided())
        if not msg.packets and not msg.carried:  # recorded before the table: each as alone
            for d in msg.deliveries:
                self._batched(d, pool, msg.phase)
            return
        if len(msg.carried) != len(msg.deliveries):
            raise Skip(INVALID, f"{len(msg.deliveries)} deliveries, {len(msg.carried)} carried")
        for p in msg.packets:
            self._endpoint(p.source)
        size = len(msg.packets)
        for d, ids in zip(msg.deliveries, msg.carried, strict=True):
            if d.packets:
                raise Skip(INVALID, f"the delivery for {d.receiver} has packets of its own")
            if ids and (min(ids) < 0 or max(ids) >= size):
                raise Skip(
                    OUT_OF_RANGE,
                    f"the delivery for {d.receiver} carries {ids}; the batch has {size} packets",
                )
            self._batched(d, pool, msg.phase)

    def _batched(self, d: Delivery, pool: int, phase: str) -> None:
        """One delivery of pool ``pool``'s batch, as if it came alone on its receiver's key."""
        if d.receiver < pool:  # a pool is named by its first agent
            raise Skip(FORGED, f"a delivery for {d.receiver} in pool {pool}'s batch")
        self._delivery(d, (str(d.receiver), phase))

    def _decision(self, msg: DecisionBatch, args: Args) -> None:
        self._sender(msg, "netem")
        check_shape(msg)
        records = msg.records
        if self.scenario is None or self._decisions_fit(msg):
            return  # 44,000 decisions an epoch at 10,000 agents: checked as arrays
        cls, last = LINK_CLASS_OF[msg.phase], self._last_decided()
        for r, (src, dst, epoch) in enumerate(
            zip(records.source, records.target, records.epoch, strict=True)
        ):
            try:  # the one at fault, named
                self._epoch(epoch, last)
                self._endpoint(src)
                self._endpoint(dst)
            except Skip as skip:
                raise Skip(skip.reason, f"record {r}: {skip}") from None
            ok = {
                "formation": (src, dst) in self.links,
                "report": dst == keys.LEADER_ENDPOINT and src != keys.LEADER_ENDPOINT,
                "estimate": src == keys.LEADER_ENDPOINT and dst != keys.LEADER_ENDPOINT,
            }[cls]
            if not ok:
                raise Skip(OUT_OF_RANGE, f"record {r}: no {cls} link {src}->{dst}")

    def _decisions_fit(self, msg: DecisionBatch) -> bool:
        """Whether every record passes the checks of :meth:`_decision`, as arrays."""
        records = msg.records
        try:
            if self.plain_bulk:  # the reader keeps these columns
                columns = decision_columns(msg)
                epoch, source, target = columns["epoch"], columns["source"], columns["target"]
            else:
                epoch = np.array(records.epoch, dtype=np.int64)
                source = np.array(records.source, dtype=np.int64)
                target = np.array(records.target, dtype=np.int64)
        except OverflowError:  # past 63 bits: checked one by one
            return False
        last = self._last_decided()
        latest = self.epochs if last is None else last
        cls = LINK_CLASS_OF[msg.phase]
        if not records_in_range(epoch, source, target, latest, self.n, cls):
            return False
        return cls != "formation" or self.within_links(source * (self.n + 1) + target)

    def _edges_known(self, pairs: list[npt.NDArray[np.int64]]) -> bool:
        """Whether every pair of the (k, 2) arrays is an edge of the formation, in either
        order."""
        ends = np.concatenate(pairs)
        low, high = ends.min(axis=1), ends.max(axis=1)
        if len(ends) and (low.min() < 1 or high.max() > self.n):
            return False
        if self._edge_codes is None:
            edges = sorted(a * (self.n + 1) + b for a, b in self.edges)
            self._edge_codes = np.array(edges, dtype=np.int64)
        return within(low * (self.n + 1) + high, self._edge_codes)

    def within_links(self, codes: npt.NDArray[np.int64]) -> bool:
        """Whether each ``source * (n + 1) + target`` is a formation link of the scenario."""
        if self._codes is None:
            self._codes = np.array(sorted(a * (self.n + 1) + b for a, b in self.links), np.int64)
        return within(codes, self._codes)

    def _link_change(self, msg: LinkChange, args: Args) -> None:
        self._sender(msg, "netem")
        self._endpoint(msg.source)
        self._endpoint(msg.target)

    def _status(self, msg: Status, args: Args) -> None:
        role, ident = args
        owner = f"{role}/{ident}" if role in ("agent", "pool") else role
        self._sender(msg, owner)
        if msg.role != role:
            raise Skip(FORGED, f"role {msg.role!r} on a key of {role!r}")
        self._epoch(msg.epoch, first=-1)

    def _metrics(self, msg: EpochMetrics, args: Args) -> None:
        self._sender(msg, RECORDER)
        self._epoch(msg.epoch)
        d = self._dim()
        for p in [] if all_finite(msg.positions, (d,)) else msg.positions:  # the one at fault
            finite(p, d, "position")
        if self.scenario is not None and len(msg.positions) != self.n:
            raise Skip(INVALID, f"{len(msg.positions)} positions, expected {self.n}")
        errors = (msg.formation_error_m, msg.shape_error_m)
        finite([e for e in errors if e is not None], None, "error")  # None: no edge in the team
        out = msg.out
        if self.scenario is not None and out and not 0 <= min(out) <= max(out) <= self.n:
            for i in out:  # the one at fault, named
                self._endpoint(i)

    def _alive(self, msg: LivelinessEvent, args: Args) -> None:
        claimed = keys.parse(msg.key)
        if (claimed.kind, claimed.args) != ("alive", args) or (msg.role, msg.ident) != args:
            raise Skip(FORGED, f"liveliness of {msg.key} on another key")

    def _foxglove(self, kind: str, data: bytes, own: bool) -> Message:
        """A scene, frames or log line: the SDK's protobuf message; a scene's entities have ids.
        ``own``: on a channel the recorder marked as its own, a scene is only outlined."""
        try:
            msg = scene_outline(data) if own and kind == "scene" else decode_kind(kind, data)
        except DecodeError:
            raise Skip(
                INVALID, f"a {kind} that is not a protobuf {FOXGLOVE[kind].__name__}"
            ) from None
        if kind == "scene" and not all(e.id for e in msg.entities):
            raise Skip(INVALID, "a scene entity without an id")
        return msg


__all__ = [
    "CONFLICT",
    "DERIVED",
    "FORGED",
    "INVALID",
    "ORIGIN",
    "OUT_OF_RANGE",
    "REASONS",
    "RECORDER",
    "UNKNOWN_KEY",
    "Gate",
    "Skip",
    "Skipped",
]
