"""Wire messages: pydantic v2 models sent as JSON (docs/architecture.md "Wire").

Every message carries ``run_id``, ``sender``, ``seq`` (per publisher), ``epoch``
and ``stamp_ns`` (the sender's monotonic clock) and a ``kind`` tag. Positions
are lists of floats; JSON floats round-trip exactly, so a distributed run and
the in-process simulator compute on the same numbers.
"""

from __future__ import annotations

import operator
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field


class _Message(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    run_id: str
    sender: str  # "agent/3", "leader", "netem", ...
    seq: int = Field(ge=0)
    epoch: int = Field(ge=-1)
    stamp_ns: int = Field(ge=0)


class Substitute(BaseModel):
    """A value ``x̃_j`` an agent used for neighbour ``j``'s lost packet (docs/model.md §6)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    neighbour: int
    value: list[float]
    fallback: bool = False


class CoordinationState(_Message):
    """Agent ``i``'s coordination variable ``x_i[k]`` (true position in the testbed) [m].

    ``substituted`` lists the values the agent used at epoch ``k − 1`` for lost
    packets, so a recording can measure the substitution error against the truth.
    A unicycle (``dynamics = "unicycle"``; ``position`` is its look-ahead point) adds its
    ``heading`` ``θ_i[k]`` [rad] and ``saturated``, the sub-steps of epoch ``k − 1`` whose
    speed command was clipped to its limits.
    """

    kind: Literal["state"] = "state"
    agent: int
    position: list[float]
    velocity: list[float] | None = None
    substituted: list[Substitute] = []
    heading: float | None = None
    saturated: int | None = Field(None, ge=0)
    # sent late as its agent waited for its robot's pose; on the wire only when set, so every
    # other message keeps its size (capacity queues count bytes)
    robot_silent: bool = Field(False, exclude_if=operator.not_)


class Measurement(BaseModel):
    """One neighbour in a token report: token 1/0 and the measurement ``z_ij`` if it arrived."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    neighbour: int
    token: Literal[0, 1]
    z: list[float] | None = None


class TokenReport(_Message):
    """Agent ``i``'s tokens and relative measurements of epoch ``k`` to the leader (docs/model.md §4)."""

    kind: Literal["report"] = "report"
    agent: int
    measurements: list[Measurement]
    # sent late as its agent waited for its robot's pose; on the wire only when set, so every
    # other message keeps its size (capacity queues count bytes)
    robot_silent: bool = Field(False, exclude_if=operator.not_)


class LeaderEstimate(_Message):
    """The leader's epoch-``k`` output (docs/model.md §4–§5): BLUE, tree, rigidity, reference velocity.

    ``positions[i − 1]`` is agent ``i``'s estimate (None if unobservable);
    ``covariances[i − 1]`` its d×d block. ``tree`` and ``healthy`` list edges as id pairs.
    """

    kind: Literal["estimate"] = "estimate"
    positions: list[list[float] | None]
    covariances: list[list[list[float]] | None]
    observable: list[bool]
    tree: list[tuple[int, int]]
    healthy: list[tuple[int, int]]
    components: int
    rigidity_rank: int
    rigid: bool
    x_ref: list[float]
    v_ref: list[float]
    reports_received: int


class AgentEstimate(_Message):
    """What agent ``agent`` uses of the leader's epoch-``k`` estimate (docs/model.md §6).

    ``positions[m]`` is ``x̂_j`` of ``j = neighbours[m]`` (None if unobservable), for
    every in-neighbour ``j``; ``v_ref`` the reference velocity. One per agent, so
    netem's control link ``0 → i`` carries what ``i`` needs, not the whole team's.
    """

    kind: Literal["agent_estimate"] = "agent_estimate"
    agent: int
    neighbours: list[int]
    positions: list[list[float] | None]
    v_ref: list[float]


class BundlePart(BaseModel):
    """One agent's message in a :class:`Bundle`: ``message`` exactly as it would have been
    published on that agent's own key, with its ``seq`` there."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    agent: int  # the agent whose key it stands for: a report's sender, an estimate's receiver
    seq: int = Field(ge=0)
    message: str


class Bundle(_Message):
    """Several agents' messages of one ``phase`` and ``epoch`` from one sender, as one
    message: netem takes each part as if it came alone on its agent's key."""

    kind: Literal["bundle"] = "bundle"
    phase: Literal["state", "report", "estimate"]
    parts: list[BundlePart]


class DeliveredPacket(BaseModel):
    """One packet netem delivers in a :class:`Delivery` (``sent_epoch < epoch`` when delayed).

    ``message`` is the sender's payload exactly as published: netem does not parse it, the
    receiver validates it (a malformed one is counted and skipped, the rest still count).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    source: int
    seq: int
    sent_epoch: int
    copies: int = 1
    message: str


class Delivery(_Message):
    """netem to one receiver: the packets of ``phase`` it passed to it.

    Lockstep: everything of ``epoch``, at once. Sent once every live sender's packet of
    the epoch was handled, so it also closes the epoch: ``packets`` is all there is;
    ``lost`` lists the sources whose packet was dropped or delayed past this epoch;
    ``dead`` the sources no longer alive. Realtime: what one wake-up of netem's forwarded
    to the receiver; ``epoch`` is the newest packet's, ``lost`` and ``dead`` are empty.
    """

    kind: Literal["delivery"] = "delivery"
    receiver: int
    phase: Literal["state", "report", "estimate"]
    packets: list[DeliveredPacket]
    lost: list[int]
    dead: list[int] = []


class DeliveryBatch(_Message):
    """netem to a pool process (lockstep): the pool's receivers' deliveries of ``phase`` and
    ``epoch`` in one message (``pool``: the pool's first agent).

    A packet goes to several of a pool's receivers, so each distinct one is in ``packets``
    once: ``deliveries[k]``'s packets are ``packets[i]`` for ``i`` in ``carried[k]`` (its own
    ``packets`` empty). A batch without ``packets`` and ``carried`` (as recorded before the
    table) holds each delivery as it would go alone.
    """

    kind: Literal["delivery_batch"] = "delivery_batch"
    pool: int
    phase: Literal["state", "report", "estimate"]
    packets: list[DeliveredPacket] = Field(default_factory=list)
    deliveries: list[Delivery]
    carried: list[list[int]] = Field(default_factory=list)


class Judgement(BaseModel):
    """What netem decided on a packet, shared by the records of a batch decided alike."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    verdict: Literal["pass", "drop", "duplicate", "delayed"]
    delay_epochs: int = 0
    delay_ms: float = 0.0
    model: str = ""
    state: str = ""
    # through a capacity queue (formation.capacity): its name, its depth when the packet
    # came [packets] and the packet's time in the queues [ms]; a queue's drop has its reason
    # (queue_full, queue_late, oversize) as ``model``
    queue: str | None = None
    queue_depth: int | None = None
    sojourn_ms: float | None = None


class Decision(Judgement):
    """One netem verdict on one packet: a row of a :class:`DecisionBatch`."""

    source: int
    target: int
    link_class: Literal["formation", "report", "estimate"]
    epoch: int
    seq: int


class DecisionColumns(BaseModel):
    """A batch's records as columns, entry ``r`` of each the ``r``-th record: its link's ends,
    its packet's epoch and seq, and its decision (an index into the batch's ``judgements``).

    The columns have one length and every index is a judgement's; the trust gate checks both
    (``recorder.reading.trust``), naming the column or value at fault.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    source: list[int]
    target: list[int]
    epoch: list[int]
    seq: list[int]
    judgement: list[int]


# Each link class belongs to one phase (docs/architecture.md "Wire"): a batch's records are
# its phase's.
LINK_CLASS_OF: dict[str, Literal["formation", "report", "estimate"]] = {
    "state": "formation",
    "report": "report",
    "estimate": "estimate",
}


class DecisionBatch(_Message):
    """Decisions netem took in one phase: of one epoch, or of several clean ones (each record
    has its epoch), as columns (``records``) over the batch's distinct ``judgements``."""

    kind: Literal["decisions"] = "decisions"
    phase: Literal["state", "report", "estimate"]
    judgements: list[Judgement]
    records: DecisionColumns

    @classmethod
    def of_rows(
        cls,
        *,
        phase: Literal["state", "report", "estimate"],
        decisions: list[Decision],
        **header: Any,
    ) -> DecisionBatch:
        """A batch of ``decisions`` (each of ``phase``'s link class), ``header`` its
        message fields."""
        names = tuple(Judgement.model_fields)
        judged: dict[tuple[Any, ...], int] = {}  # a judgement's values → its index
        index = [
            judged.setdefault(tuple(getattr(d, name) for name in names), len(judged))
            for d in decisions
        ]
        columns = DecisionColumns(
            source=[d.source for d in decisions],
            target=[d.target for d in decisions],
            epoch=[d.epoch for d in decisions],
            seq=[d.seq for d in decisions],
            judgement=index,
        )
        judgements = [Judgement(**dict(zip(names, values, strict=True))) for values in judged]
        return cls(phase=phase, judgements=judgements, records=columns, **header)


def decision_rows(batch: DecisionBatch) -> list[Decision]:
    """A checked batch's records as rows (a struct of it too: attributes are read)."""
    cls, r, judgements = LINK_CLASS_OF[batch.phase], batch.records, batch.judgements
    return [
        Decision(
            source=s,
            target=t,
            link_class=cls,
            epoch=e,
            seq=q,
            **{name: getattr(judgements[j], name) for name in Judgement.model_fields},
        )
        for s, t, e, q, j in zip(r.source, r.target, r.epoch, r.seq, r.judgement, strict=True)
    ]


class LinkChange(_Message):
    """A run-time change of a link's model stack, accepted by netem (recorded)."""

    kind: Literal["link_change"] = "link_change"
    source: int
    target: int
    link_class: Literal["formation", "report", "estimate"]
    models: list[dict[str, object]]
    from_epoch: int


class Status(_Message):
    """A process's progress and counters (epochs done, malformed payloads per key)."""

    kind: Literal["status"] = "status"
    role: str
    state: Literal["ready", "running", "done", "error"]
    epochs_done: int = 0
    malformed: dict[str, int] = {}
    sent: dict[str, int] = {}  # messages published per key
    delivered: dict[str, int] = {}  # netem: packets delivered per link, named by its key
    detail: str = ""


class EpochMetrics(_Message):
    """Per-epoch metrics from the true states (docs/model.md §7), written by the recorder.

    ``out``: the agents with no state of the epoch (out of the team, planned or not); their
    ``positions`` are where their bodies were last seen (the initial ones before that), and
    the errors are over the edges between the others (None when no edge is).
    """

    kind: Literal["metrics"] = "metrics"
    formation_error_m: float | None
    shape_error_m: float | None
    positions: list[list[float]]
    out: list[int] = []


Message = Annotated[
    CoordinationState
    | TokenReport
    | LeaderEstimate
    | AgentEstimate
    | Bundle
    | Delivery
    | DeliveryBatch
    | DecisionBatch
    | LinkChange
    | Status
    | EpochMetrics,
    Field(discriminator="kind"),
]

ALL_MODELS: tuple[type[BaseModel], ...] = (
    CoordinationState,
    TokenReport,
    LeaderEstimate,
    AgentEstimate,
    Bundle,
    Delivery,
    DeliveryBatch,
    DecisionBatch,
    LinkChange,
    Status,
    EpochMetrics,
)
