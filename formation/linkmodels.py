"""Link models as the scenario names them: the vocabulary netem implements (``netem.links.linkmodels``).

Each model is a small frozen pydantic model tagged by ``model``; a link carries a
stack of them (e.g. an outage on top of Bernoulli loss), applied in order. Names
follow Linux ``tc netem`` where it has one (see ``man tc-netem``).
Epoch-valued fields are used in lockstep mode, millisecond fields in realtime.

Every model is a link model plug-in (``formation.plugin_registry``): its spec is found by
its tag in the entry-point group ``formation.link_models`` (ours are registered in this
project's ``pyproject.toml``, a user's in theirs), or by ``"package.module:Name"``. A spec
names its netem layer (``layer``, ``"module:attribute"``) and the code its draws are keyed
by (``kind_code``: ours are pinned, 0..11, so that every seed keeps its numbers; a plug-in's
is derived from its tag). How to write one: docs/plugins.md.
"""

from __future__ import annotations

import zlib
from functools import cache
from typing import Annotated, Any, ClassVar, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PlainSerializer,
    SerializationInfo,
    ValidationError,
    ValidatorFunctionWrapHandler,
    WithJsonSchema,
    WrapValidator,
    model_validator,
)
from pydantic_core import InitErrorDetails, PydanticCustomError

from formation.errors import NO_VALUE, PLUGIN_LABELS, PluginError
from formation.plugin_registry import find, is_reference, names, registered

Probability = Annotated[float, Field(ge=0.0, le=1.0)]


class Spec(BaseModel):
    """Base of the link model specs; ``model`` is the tag a subclass fixes with a literal.

    A distance model (its verdict depends on the link's length at the epoch) sets the class
    attribute ``by_distance = True``. ``layer`` names the netem layer that runs it
    (``"module:attribute"``); ``kind_code``, when set, is the code its draws are keyed by.
    """

    model_config = ConfigDict(
        extra="forbid", frozen=True, populate_by_name=True, allow_inf_nan=False
    )
    by_distance: ClassVar[bool] = False
    layer: ClassVar[str] = ""
    kind_code: ClassVar[int | None] = None

    model: str


class Up(Spec):
    """Always delivers."""

    layer: ClassVar[str] = "netem.links.linkmodels.up:LAYER"
    kind_code: ClassVar[int | None] = 0
    model: Literal["up"] = "up"


class Down(Spec):
    """Never delivers."""

    layer: ClassVar[str] = "netem.links.linkmodels.down:LAYER"
    kind_code: ClassVar[int | None] = 1
    model: Literal["down"] = "down"


class Bernoulli(Spec):
    """Independent loss with probability ``p_loss`` (tc: ``loss random P [CORR]``).

    ``correlation`` follows tc netem's old correlated-random reading: the uniform
    used at packet k is ``corr * u[k-1] + (1 - corr) * fresh``.
    """

    layer: ClassVar[str] = "netem.links.linkmodels.bernoulli:LAYER"
    kind_code: ClassVar[int | None] = 2
    model: Literal["bernoulli"] = "bernoulli"
    p_loss: Probability
    correlation: Probability = 0.0


class GilbertElliott(Spec):
    """Two-state Markov loss (tc: ``loss gemodel p [r [1-h [1-k]]]``).

    ``p`` = P(good → bad), ``r`` = P(bad → good), ``1-h`` = loss probability in
    the bad state, ``1-k`` = loss probability in the good state.
    """

    layer: ClassVar[str] = "netem.links.linkmodels.gilbert_elliott:LAYER"
    kind_code: ClassVar[int | None] = 3
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

    layer: ClassVar[str] = "netem.links.linkmodels.markov4:LAYER"
    kind_code: ClassVar[int | None] = 4
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

    layer: ClassVar[str] = "netem.links.linkmodels.outage:LAYER"
    kind_code: ClassVar[int | None] = 5
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

    layer: ClassVar[str] = "netem.links.linkmodels.delay:LAYER"
    kind_code: ClassVar[int | None] = 6
    model: Literal["delay"] = "delay"
    epochs: int = Field(0, ge=0)
    jitter_epochs: int = Field(0, ge=0)
    ms: float = Field(0.0, ge=0.0)
    jitter_ms: float = Field(0.0, ge=0.0)
    distribution: Literal["uniform", "normal", "pareto", "paretonormal"] = "uniform"
    correlation: Probability = 0.0


class Duplicate(Spec):
    """Deliver an extra copy with probability ``p`` (tc: ``duplicate P``)."""

    layer: ClassVar[str] = "netem.links.linkmodels.duplicate:LAYER"
    kind_code: ClassVar[int | None] = 7
    model: Literal["duplicate"] = "duplicate"
    p: Probability


class Reorder(Spec):
    """With probability ``p`` a packet skips the delay of the stack (tc: ``reorder P gap N``)."""

    layer: ClassVar[str] = "netem.links.linkmodels.reorder:LAYER"
    kind_code: ClassVar[int | None] = 8
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
    layer: ClassVar[str] = "netem.links.linkmodels.range:LAYER"
    kind_code: ClassVar[int | None] = 9
    model: Literal["range"] = "range"
    max_range_m: float = Field(gt=0.0)  # [m]


class Logistic(Spec):
    """Distance: packet reception ratio ``1 / (1 + exp((d − d50_m) / width_m))`` at length ``d``."""

    by_distance: ClassVar[bool] = True
    layer: ClassVar[str] = "netem.links.linkmodels.logistic:LAYER"
    kind_code: ClassVar[int | None] = 10
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
    layer: ClassVar[str] = "netem.links.linkmodels.log_distance:LAYER"
    kind_code: ClassVar[int | None] = 11
    model: Literal["log_distance"] = "log_distance"
    tx_power_dbm: float = 0.0  # P_t [dBm]
    path_loss_d0_db: float = 40.0  # PL(d0) [dB]
    d0_m: float = Field(1.0, gt=0.0)  # reference distance [m]
    n: float = Field(2.0, gt=0.0)  # path-loss exponent
    sigma_db: float = Field(0.0, ge=0.0)  # shadowing standard deviation [dB]
    shadowing_correlation: float = Field(0.0, ge=0.0, lt=1.0)  # per epoch
    sensitivity_dbm: float = -70.0  # receiver threshold [dBm]


BUILTIN_CODES = 64  # kind codes below this are ours; a plug-in's is derived from its tag


def kind_code_of(cls: type[Spec]) -> int:
    """The code a model's draws are keyed by: pinned for ours, from the tag for a plug-in's
    (so it does not depend on which other plug-ins are installed)."""
    if cls.kind_code is not None:
        return cls.kind_code
    tag = cls.model_fields["model"].default
    return BUILTIN_CODES + zlib.crc32(str(tag).encode()) % (2**31 - BUILTIN_CODES)


@cache
def spec_class(tag: str) -> type[Spec]:
    """The spec class of link model ``tag`` (a registered tag, or ``"package.module:Name"``)."""
    cls = find("link_model", tag).load()
    if not (isinstance(cls, type) and issubclass(cls, Spec)):
        raise PluginError("link_model", tag, f"{cls!r} is not a formation.linkmodels.Spec class")
    field = cls.model_fields.get("model")
    own = None if field is None else field.default
    if not is_reference(tag) and own != tag:
        raise PluginError("link_model", tag, f"its spec's model tag is {own!r}, not {tag!r}")
    if not isinstance(own, str) or not own:
        raise PluginError(
            "link_model", tag, "its spec has no default model tag (model: Literal[...])"
        )
    if ":" not in cls.layer:
        raise PluginError(
            "link_model",
            tag,
            f"layer = {cls.layer!r}; expected the netem layer as 'module:attribute'",
        )
    return cls


def spec_classes() -> dict[str, type[Spec]]:
    """Every registered link model's spec, by tag."""
    return {tag: spec_class(tag) for tag in names("link_model")}


def _validate_spec(value: Any, handler: ValidatorFunctionWrapHandler) -> Spec:
    if isinstance(value, Spec):
        return value
    if not isinstance(value, dict):
        raise ValueError(f"expected a table with a model tag, got {value!r}")
    tag = value.get("model")
    if not isinstance(tag, str):
        known = ", ".join(names("link_model"))
        raise ValueError(
            f"a link model needs its tag: model = one of {known}, or 'package.module:Name'"
        )
    try:
        cls = spec_class(tag)
    except PluginError as exc:
        raise ValueError(str(exc)) from None
    data = value if not is_reference(tag) else {**value, "model": cls.model_fields["model"].default}
    try:
        return cls.model_validate(data)
    except ValidationError as exc:
        raise _named(exc, tag) from None


def _named(exc: ValidationError, tag: str) -> ValidationError:
    """``exc`` with each problem naming link model plug-in ``tag``; paths and values kept."""
    label = f"{PLUGIN_LABELS['link_model']} plug-in {tag!r}: "
    errors: list[InitErrorDetails] = []
    for err in exc.errors():
        if err["type"] == "extra_forbidden":
            problem = "unknown parameter"
        elif err["type"] == "missing":
            problem = "required parameter is missing"
        else:
            problem = err["msg"].removeprefix("Value error, ")
        kind = PydanticCustomError(
            "link_model_parameter", "{problem}", {"problem": label + problem}
        )
        detail: InitErrorDetails = {"type": kind, "loc": err["loc"], "input": err["input"]}
        if err["type"] == "missing":
            detail["input"] = NO_VALUE
        errors.append(detail)
    return ValidationError.from_exception_data(exc.title, errors)


def _dump_spec(spec: Spec, info: SerializationInfo) -> dict[str, Any]:
    out = spec.model_dump(
        mode=info.mode, by_alias=bool(info.by_alias), exclude_none=info.exclude_none
    )
    out["model"] = _name_of(type(spec))
    return out


@cache
def _name_of(cls: type[Spec]) -> str:
    """How a spec is found again: its tag where that is registered to it, else its import path
    (the resolved scenario every process reads names it so)."""
    tag = cls.model_fields["model"].default
    entry = registered("link_model").get(tag)
    if entry is not None and entry.target == f"{cls.__module__}:{cls.__qualname__}":
        return str(tag)
    try:
        if spec_class(tag) is cls:
            return str(tag)
    except PluginError:
        pass
    return f"{cls.__module__}:{cls.__qualname__}"


# A link model as a scenario or netem's run-time change gives it: found by its tag.
LinkModelSpec = Annotated[
    Spec,
    WrapValidator(_validate_spec),
    PlainSerializer(_dump_spec),
    WithJsonSchema({"type": "object", "required": ["model"]}),
]


def is_distance_spec(spec: Spec) -> bool:
    return type(spec).by_distance


__all__ = [
    "BUILTIN_CODES",
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
    "is_distance_spec",
    "kind_code_of",
    "spec_class",
    "spec_classes",
]
