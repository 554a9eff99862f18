"""The interface of a netem layer: one link model spec as a vectorised function of keyed draws.

A layer turns the keyed uniforms of ``(links, epochs)`` into drops, states,
delays, duplicates or reorderings (a ``LayerOutput``) and gives its model's
closed forms (``loss_chain``, ``loss_rate``). Every model's layer lives in its own
module of ``netem.links.linkmodels``; ``netem.links.layer_stack`` runs a stack of them and
``netem.links.models`` gives the semantics (docs/model.md §4, §8).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np
import numpy.typing as npt

from formation.errors import LinkModelError
from formation.keyed_random import Stream, keyed_normal, keyed_uniform
from formation.linkmodels import Spec, kind_code_of
from netem.links.chains import cesaro

Bools = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]
Floats = npt.NDArray[np.float64]
Codes = npt.NDArray[np.int8]

KIND_CODE: dict[str, int] = {}  # tag → the code its draws are keyed by
# tag of each table index (the int8 kinds of coded tables; never leaves the process), in the
# order this process first built a layer of each
MODEL_NAMES: list[str] = []
STATE_NAMES: dict[str, tuple[str, ...]] = {}  # tag → state code → its name


def model_index(tag: str) -> int:
    """A model's index in :data:`MODEL_NAMES` (built once a layer of it is)."""
    return MODEL_NAMES.index(tag)


@dataclass(frozen=True)
class Keys:
    """Key prefix of one or more links: ``src``, ``dst`` are ``(L, 1)``."""

    seed: int
    src: Ints
    dst: Ints

    def _key(self, stream: Stream, kind: str, occ: int, epochs: Ints) -> tuple[Any, ...]:
        """The key of a layer's draws on these links at ``epochs``: (seed, stream, ends, kind, occurrence, epoch)."""
        return (self.seed, int(stream), self.src, self.dst, KIND_CODE[kind], occ, epochs[None, :])

    def uniform(self, stream: Stream, kind: str, occ: int, epochs: Ints, *rest: int) -> Floats:
        """Uniforms ``(L, n)`` for ``epochs`` ``(n,)``."""
        return keyed_uniform(*self._key(stream, kind, occ, epochs), *rest)

    def normal(self, stream: Stream, kind: str, occ: int, epochs: Ints, *rest: int) -> Floats:
        """Standard normals ``(L, n)`` for ``epochs`` ``(n,)``."""
        return keyed_normal(*self._key(stream, kind, occ, epochs), *rest)

    @property
    def n_links(self) -> int:
        return int(self.src.shape[0])


@dataclass
class LayerOutput:
    """One layer's contribution over ``(L, n)``; ``None`` where the layer has none."""

    drop: Bools | None = None
    state: Codes | None = None
    delay_epochs: Ints | None = None
    delay_ms: Floats | None = None
    dup: Bools | None = None
    reorder: Bools | None = None
    chain_prev: Floats | None = None  # delay: correlated uniform before each epoch
    reach_m: Floats | None = None  # a distance layer: delivered iff the link is no longer [m]


def lossless() -> tuple[Floats, Floats]:
    """``(T, loss)`` of a layer that never drops: one state, loss 0."""
    return np.ones((1, 1)), np.zeros(1)


S = TypeVar("S", bound=Spec)


class Layer(Generic[S]):
    """One spec of a stack; a model's layer overrides what its model does, the defaults do nothing.

    ``occurrence`` counts the layers of the same kind before this one in the stack:
    draws are keyed by ``(kind, occurrence)``, and a replaced stack hands chain
    state over by the same pair (``ident``).
    """

    stateful = False  # carries chain state from one block of epochs into the next
    timed = False  # drops by packet time [s] (``drops_at``), applied after the run
    ranged = False  # drops by the link's length [m] (``keeps``), applied after the run
    state_names: tuple[str, ...] = ("",)  # state code → its name in ``Outcome.state``

    def __init__(self, spec: S, occurrence: int) -> None:
        self.spec = spec
        self.kind: str = spec.model
        self.ident = (self.kind, occurrence)
        self.occ = occurrence
        enter_model(self.kind, kind_code_of(type(spec)), self.state_names)

    def run(
        self, keys: Keys, epochs: Ints, carry: npt.NDArray[Any] | None
    ) -> tuple[LayerOutput, Any]:
        """Output over ``(L, n)`` for ``epochs`` ``(n,)`` from chain state ``carry`` (None: initial),
        and the chain state after the last epoch (None for a stateless layer)."""
        return LayerOutput(), None

    def packet(self, keys: Keys, epochs: Ints, seq: int, prev: Floats | None) -> LayerOutput | None:
        """Per-packet draws (``dup``, delays) of packet ``seq`` of each epoch; ``prev`` is the run's
        ``chain_prev``. None for a per-epoch layer, whose packets share the epoch's outcome."""
        return None

    def problem(self) -> str | None:
        """Why the spec cannot run (checked when a stack is built); None when it can."""
        return None

    def drops_at(self, time_s: Floats | float) -> Bools:
        """A timed layer's drops at packet times ``time_s`` ``(n,)`` [s] (or one time, 0-d)."""
        return np.zeros(np.shape(time_s), dtype=np.bool_)

    @staticmethod
    def keeps(reach_m: Floats | float, distance_m: Floats | float) -> Bools:
        """A distance layer's verdicts: delivered iff the link's length ``distance_m`` is at most
        the run's ``reach_m`` (same shape, or one packet's scalars) [m]: one comparison, the same
        in every process."""
        return np.asarray(distance_m <= reach_m, dtype=np.bool_)

    def delivery_at(self, distance_m: Floats) -> Floats:
        """A distance layer's closed form: P(delivered) at link lengths ``distance_m`` [m]."""
        return np.ones(np.shape(distance_m), dtype=np.float64)

    def timing(self) -> str:
        """What a timed layer needs, for the error when no packet time is given."""
        return f"{self.kind} is given in seconds"

    # closed forms (netem.links.closed_forms) -----------------------------------------------------

    def loss_chain(self) -> tuple[Floats, Floats] | None:
        """``(T, loss)``: the layer's loss as a hidden Markov chain started in state 0.

        ``T`` ``(S, S)`` is the transition matrix, ``loss`` ``(S,)`` the loss
        probability in each state. None when the loss is not such a chain.
        """
        return None

    def loss_rate(self) -> float:
        """Long-run fraction of epochs the layer drops: ``π · loss`` of its chain."""
        chain = self.loss_chain()
        if chain is None and self.ranged:
            raise LinkModelError(
                "closed form", f"{self.kind} depends on distance; use expected_delivery_at"
            )
        if chain is None:
            raise LinkModelError("closed form", f"{self.kind} has no closed-form loss rate")
        t, loss = chain
        return float(cesaro(t)[0] @ loss)


def enter_model(tag: str, code: int, state_names: tuple[str, ...]) -> None:
    """Make a model known to the draw keys and the coded tables."""
    if tag in KIND_CODE:
        return
    other = next((t for t, c in KIND_CODE.items() if c == code), None)
    if other is not None:
        raise LinkModelError(
            "registry", f"link models {other!r} and {tag!r} share kind code {code}"
        )
    KIND_CODE[tag] = code
    STATE_NAMES[tag] = state_names
    MODEL_NAMES.append(tag)
    if len(MODEL_NAMES) > 127:
        raise LinkModelError("registry", "more than 127 link models in one process")


__all__ = [
    "KIND_CODE",
    "MODEL_NAMES",
    "STATE_NAMES",
    "Bools",
    "Codes",
    "Floats",
    "Ints",
    "Keys",
    "Layer",
    "LayerOutput",
    "enter_model",
    "lossless",
    "model_index",
]
