"""Link models as the scenario names them: the vocabulary netem implements (``netem.links.linkmodels``).

Each model is a small frozen pydantic model tagged by ``model``; a link carries a
stack of them (e.g. an outage on top of Bernoulli loss), applied in order. Names
follow Linux ``tc netem`` where it has one (see ``man tc-netem``).
Epoch-valued fields are used in lockstep mode, millisecond fields in realtime.

``LinkModelSpec`` is the one list of models: the scenario's tags, ``MODEL_NAMES``
and ``SPEC_OF`` are read from it. A model's position in it is its kind code in
netem's keyed draws, so a new model is appended, never inserted (how to add one:
``netem/links/linkmodels/__init__.py``).
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, model_validator

Probability = Annotated[float, Field(ge=0.0, le=1.0)]


class Spec(BaseModel):
    """Base of the link model specs; ``model`` is the tag a subclass fixes with a literal.

    A distance model (its verdict depends on the link's length at the epoch) sets the class
    attribute ``by_distance = True``; :data:`DISTANCE_MODELS` is read from it.
    """

    model_config = ConfigDict(
        extra="forbid", frozen=True, populate_by_name=True, allow_inf_nan=False
    )
    by_distance: ClassVar[bool] = False

    model: str


class Up(Spec):
    """Always delivers."""

    model: Literal["up"] = "up"


class Down(Spec):
    """Never delivers."""

    model: Literal["down"] = "down"


class Bernoulli(Spec):
    """Independent loss with probability ``p_loss`` (tc: ``loss random P [CORR]``).

    ``correlation`` follows tc netem's old correlated-random reading: the uniform
    used at packet k is ``corr * u[k-1] + (1 - corr) * fresh``.
    """

    model: Literal["bernoulli"] = "bernoulli"
    p_loss: Probability
    correlation: Probability = 0.0


class GilbertElliott(Spec):
    """Two-state Markov loss (tc: ``loss gemodel p [r [1-h [1-k]]]``).

    ``p`` = P(good → bad), ``r`` = P(bad → good), ``1-h`` = loss probability in
    the bad state, ``1-k`` = loss probability in the good state.
    """

    model: Literal["gilbert_elliott"] = "gilbert_elliott"
    p: Probability
    r: Probability = 1.0
    one_minus_h: Probability = Field(1.0, alias="1-h")
    one_minus_k: Probability = Field(0.0, alias="1-k")


class Markov4(Spec):
    """tc netem's four-state loss model (``loss state p13 [p31 [p32 [p23 [p14]]]]``).

    States as in Linux ``sch_netem.c``: 1 good reception, 2 burst reception, 3 loss
    within a burst, 4 isolated loss; the chain moves first, then the packet is lost if
    the new state is 3 or 4.
    """

    model: Literal["markov4"] = "markov4"
    p13: Probability
    p31: Probability = 1.0
    p32: Probability = 0.0
    p23: Probability = 1.0
    p14: Probability = 0.0

    @model_validator(mode="after")
    def _rows(self) -> Markov4:
        if self.p13 + self.p14 > 1.0:
            raise ValueError(f"p13 + p14 = {self.p13 + self.p14:g} must be <= 1")
        if self.p31 + self.p32 > 1.0:
            raise ValueError(f"p31 + p32 = {self.p31 + self.p32:g} must be <= 1")
        return self


class Outage(Spec):
    """Link down from ``start`` (inclusive) to ``end`` (exclusive; None = forever).

    With ``every``, the window repeats each ``every`` epochs. ``start_s``/``end_s``
    give the same window in seconds for realtime mode.
    """

    model: Literal["outage"] = "outage"
    start: int = Field(0, ge=0)
    end: int | None = Field(None, ge=0)
    every: int | None = Field(None, gt=0)
    start_s: float | None = Field(None, ge=0.0)
    end_s: float | None = Field(None, ge=0.0)

    @model_validator(mode="after")
    def _window(self) -> Outage:
        if self.end is not None and self.end <= self.start:
            raise ValueError(f"end = {self.end} must be greater than start = {self.start}")
        if self.every is not None and self.end is not None and self.end - self.start > self.every:
            raise ValueError(f"window {self.start}..{self.end} is longer than every = {self.every}")
        return self


class Delay(Spec):
    """Delay with jitter (tc: ``delay TIME [JITTER [CORR]] distribution DIST``).

    Lockstep delays are whole epochs (``epochs`` ± ``jitter_epochs``); realtime
    delays are milliseconds (``ms`` ± ``jitter_ms``).
    """

    model: Literal["delay"] = "delay"
    epochs: int = Field(0, ge=0)
    jitter_epochs: int = Field(0, ge=0)
    ms: float = Field(0.0, ge=0.0)
    jitter_ms: float = Field(0.0, ge=0.0)
    distribution: Literal["uniform", "normal", "pareto", "paretonormal"] = "uniform"
    correlation: Probability = 0.0


class Duplicate(Spec):
    """Deliver an extra copy with probability ``p`` (tc: ``duplicate P``)."""

    model: Literal["duplicate"] = "duplicate"
    p: Probability


class Reorder(Spec):
    """With probability ``p`` a packet skips the delay of the stack (tc: ``reorder P gap N``)."""

    model: Literal["reorder"] = "reorder"
    p: Probability
    gap: int = Field(1, ge=1)


class Range(Spec):
    """Distance: delivered iff the link's length ``d`` at the epoch is at most ``max_range_m``.

    Distance models (``range``, ``logistic``, ``log_distance``) decide by the true
    positions of the link's ends at the epoch: a control link's leader end is the
    scenario's ``network.access_point``.
    """

    by_distance: ClassVar[bool] = True
    model: Literal["range"] = "range"
    max_range_m: float = Field(gt=0.0)  # [m]


class Logistic(Spec):
    """Distance: packet reception ratio ``1 / (1 + exp((d − d50_m) / width_m))`` at length ``d``."""

    by_distance: ClassVar[bool] = True
    model: Literal["logistic"] = "logistic"
    d50_m: float = Field(gt=0.0)  # [m] where half the packets arrive
    width_m: float = Field(gt=0.0)  # [m] how gradual the fall is


class LogDistance(Spec):
    """Distance: log-distance path loss with log-normal shadowing and a receiver threshold.

    ``PL(d) = PL(d0) + 10 n log10(d / d0) + X_σ`` [dB] (Rappaport, *Wireless
    Communications*, 2nd ed., eq. 4.69); the packet arrives iff
    ``tx_power_dbm − PL(d) ≥ sensitivity_dbm``. ``X_σ`` ~ N(0, sigma_db²) per link
    and epoch, AR(1) over epochs with ``shadowing_correlation``; ``d < d0_m`` counts as ``d0_m``.
    """

    by_distance: ClassVar[bool] = True
    model: Literal["log_distance"] = "log_distance"
    tx_power_dbm: float = 0.0  # P_t [dBm]
    path_loss_d0_db: float = 40.0  # PL(d0) [dB]
    d0_m: float = Field(1.0, gt=0.0)  # reference distance [m]
    n: float = Field(2.0, gt=0.0)  # path-loss exponent
    sigma_db: float = Field(0.0, ge=0.0)  # shadowing standard deviation [dB]
    shadowing_correlation: float = Field(0.0, ge=0.0, lt=1.0)  # per epoch
    sensitivity_dbm: float = -70.0  # receiver threshold [dBm]


LinkModelSpec = Annotated[
    Up
    | Down
    | Bernoulli
    | GilbertElliott
    | Markov4
    | Outage
    | Delay
    | Duplicate
    | Reorder
    | Range
    | Logistic
    | LogDistance,
    Field(discriminator="model"),
]

SPEC_OF: dict[str, type[Spec]] = {
    cls.model_fields["model"].default: cls for cls in get_args(get_args(LinkModelSpec)[0])
}  # tag → spec class, in the union's order
MODEL_NAMES: tuple[str, ...] = tuple(SPEC_OF)  # a tag's index is its kind code in keyed draws
DISTANCE_MODELS: tuple[type[Spec], ...] = tuple(c for c in SPEC_OF.values() if c.by_distance)

__all__ = [
    "DISTANCE_MODELS",
    "MODEL_NAMES",
    "SPEC_OF",
    "Bernoulli",
    "Delay",
    "Down",
    "Duplicate",
    "GilbertElliott",
    "LinkModelSpec",
    "LogDistance",
    "Logistic",
    "Markov4",
    "Outage",
    "Range",
    "Reorder",
    "Spec",
    "Up",
]
