"""Decisions of many links at once, for the in-process simulator and sweeps (docs/model.md §4).

``delivery_plan`` runs every link's stack over all epochs, vectorised over links
with equal stacks; what a distance model decides (``range``, ``logistic``,
``log_distance``) is left to the epoch, once the simulator knows where the agents
are (``DeliveryPlan.at``). Each column equals ``netem.links.models.LinkModel`` of that link,
decision by decision, given the same link lengths.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from formation.errors import LinkModelError
from formation.linkmodels import LinkModelSpec
from netem.links.layer import Bools, Floats, Ints, Keys, Layer
from netem.links.layer_stack import LinkMatrix, build_stack, check_key, run_stack


@dataclass(frozen=True)
class DistanceGroup:
    """Links sharing a stack with distance layers: their columns, those layers and their reach [m]."""

    columns: Ints  # (g,) columns of the matrix
    layers: tuple[Layer[Any], ...]
    reach_m: tuple[Floats, ...]  # per layer (g, n_epochs) [m]: delivered iff no longer


@dataclass(frozen=True)
class DeliveryPlan:
    """Decisions of ``L`` links over ``n`` epochs, every layer but the distance ones applied.

    ``base`` is the matrix without the distance layers (exactly the final one when
    ``groups`` is empty); ``at`` and ``matrix`` add them from the link lengths.
    """

    base: LinkMatrix
    groups: tuple[DistanceGroup, ...]

    @property
    def ranged(self) -> bool:
        """Do some links decide by their length?"""
        return bool(self.groups)

    def keep(self, epoch: int, distance_m: Floats) -> Bools:
        """``(L,)``: False where a distance layer drops epoch ``epoch``'s packet, the links
        ``distance_m`` ``(L,)`` [m] long."""
        keep = np.ones(self.base.delivered.shape[1], dtype=np.bool_)
        for g in self.groups:
            d = distance_m[g.columns]
            ok = np.ones(g.columns.shape, dtype=np.bool_)
            for layer, reach_m in zip(g.layers, g.reach_m, strict=True):
                ok &= layer.keeps(reach_m[:, epoch], d)
            keep[g.columns] = ok
        return keep

    def at(self, epoch: int, distance_m: Floats) -> tuple[Bools, npt.NDArray[np.int8], Ints]:
        """Epoch ``epoch``'s ``delivered``, ``copies``, ``delay_epochs``, each ``(L,)``."""
        b = self.base
        if not self.groups:
            return b.delivered[epoch], b.copies[epoch], b.delay_epochs[epoch]
        keep = self.keep(epoch, distance_m)
        return (
            b.delivered[epoch] & keep,
            np.where(keep, b.copies[epoch], 0).astype(np.int8),
            np.where(keep, b.delay_epochs[epoch], 0),
        )

    def matrix(self, distances_m: npt.ArrayLike | None = None) -> LinkMatrix:
        """The whole ``LinkMatrix``, given every epoch's link lengths ``(n, L)`` [m]."""
        if not self.groups:
            return self.base
        if distances_m is None:
            raise LinkModelError(
                "matrix", "a stack has a distance model; pass distances_m (n_epochs, L) [m]"
            )
        d = np.asarray(distances_m, dtype=np.float64)
        b = self.base
        if d.shape != b.delivered.shape:
            raise LinkModelError(
                "matrix", f"distances_m has shape {d.shape}; expected {b.delivered.shape}"
            )
        keep = np.ones(d.shape, dtype=np.bool_)
        for g in self.groups:
            ok = np.ones((g.columns.shape[0], d.shape[0]), dtype=np.bool_)
            for layer, reach_m in zip(g.layers, g.reach_m, strict=True):
                ok &= layer.keeps(reach_m, d[:, g.columns].T)
            keep[:, g.columns] = ok.T
        return LinkMatrix(
            b.delivered & keep,
            np.where(keep, b.copies, 0).astype(np.int8),
            np.where(keep, b.delay_epochs, 0),
            np.where(keep, b.delay_ms, 0.0),
            b.reordered & keep,
        )


def delivery_plan(
    specs_per_link: Sequence[Sequence[LinkModelSpec]],
    seed: int,
    links: npt.ArrayLike,
    n_epochs: int,
    times_s: npt.ArrayLike | None = None,
) -> DeliveryPlan:
    """Every link's decisions over epochs ``0 .. n_epochs - 1``, the distance layers left open.

    Links with equal stacks are computed together: stateless layers over
    ``(links, epochs)`` in one go, Markov chains vectorised across links with a
    loop over epochs.

    Parameters
    ----------
    specs_per_link : sequence of L stacks
    seed : int
    links : (L, 2) int array
        ``(src, dst)`` of each directed link.
    n_epochs : int
    times_s : (n_epochs,) array [s], optional
        Packet times, needed when a realtime outage window is in a stack.
    """
    pairs = np.asarray(links, dtype=np.int64)
    if pairs.ndim != 2 or pairs.shape[1] != 2:
        raise LinkModelError("matrix", f"links has shape {pairs.shape}; expected (L, 2)")
    if len(specs_per_link) != pairs.shape[0]:
        raise LinkModelError(
            "matrix", f"{len(specs_per_link)} stacks for {pairs.shape[0]} links; expected one each"
        )
    times = None if times_s is None else np.asarray(times_s, dtype=np.float64)
    if times is not None and times.shape != (n_epochs,):
        raise LinkModelError("matrix", f"times_s has shape {times.shape}; expected ({n_epochs},)")
    n_links = pairs.shape[0]
    delivered = np.zeros((n_links, n_epochs), np.bool_)
    copies = np.zeros((n_links, n_epochs), np.int8)
    delay_epochs = np.zeros((n_links, n_epochs), np.int64)
    delay_ms = np.zeros((n_links, n_epochs), np.float64)
    reordered = np.zeros((n_links, n_epochs), np.bool_)
    # Links sharing one stack object are grouped by identity first: hashing the models
    # of every link of a large team costs more than deciding them.
    by_object: dict[int, tuple[Sequence[LinkModelSpec], list[int]]] = {}
    for i, specs in enumerate(specs_per_link):
        by_object.setdefault(id(specs), (specs, []))[1].append(i)
    groups: dict[tuple[LinkModelSpec, ...], list[int]] = {}
    for specs, members in by_object.values():
        groups.setdefault(tuple(specs), []).extend(members)
    ranged: list[DistanceGroup] = []
    for stack_specs, members in groups.items():
        idx = np.sort(np.asarray(members, dtype=np.int64))
        name = f"{pairs[idx[0], 0]}→{pairs[idx[0], 1]}"
        for j in (0, 1):
            ends = pairs[idx, j]
            for v in ends[ends < 0][:1].tolist():  # int64: none reaches 2**63
                check_key(name, "src" if j == 0 else "dst", v)
        check_key(name, "seed", seed)
        stack = build_stack(stack_specs, name)
        keys = Keys(seed, pairs[idx, 0:1], pairs[idx, 1:2])
        piece, _ = run_stack(stack, keys, 0, n_epochs, {})
        if times is not None:
            piece.apply_times(times)
        elif stack.timed:
            raise LinkModelError(name, "a stack has an outage in seconds; pass times_s")
        if stack.ranged:
            layers = tuple(stack.layers[i] for i in stack.ranged)
            ranged.append(DistanceGroup(idx, layers, tuple(piece.reach_m[i] for i in stack.ranged)))
        d, c, de, dms, r = piece.final()
        delivered[idx], copies[idx], delay_epochs[idx], delay_ms[idx], reordered[idx] = (
            d,
            c,
            de,
            dms,
            r,
        )
    base = LinkMatrix(
        np.ascontiguousarray(delivered.T),
        np.ascontiguousarray(copies.T),
        np.ascontiguousarray(delay_epochs.T),
        np.ascontiguousarray(delay_ms.T),
        np.ascontiguousarray(reordered.T),
    )
    return DeliveryPlan(base, tuple(ranged))


def delivery_matrix(
    specs_per_link: Sequence[Sequence[LinkModelSpec]],
    seed: int,
    links: npt.ArrayLike,
    n_epochs: int,
    times_s: npt.ArrayLike | None = None,
    distances_m: npt.ArrayLike | None = None,
) -> LinkMatrix:
    """Decisions of many links at once: column ``l`` equals ``schedule(specs_per_link[l], seed,
    *links[l], n_epochs)``.

    ``distances_m`` ``(n_epochs, L)`` [m]: every link's length at every epoch, needed when
    a stack has a distance model (a simulator that moves the agents uses ``delivery_plan``).
    Returns ``delivered``, ``copies``, ``delay_epochs``, ``delay_ms``, ``reordered``, each
    ``(n_epochs, L)``.
    """
    return delivery_plan(specs_per_link, seed, links, n_epochs, times_s).matrix(distances_m)


def link_lengths(src_m: npt.ArrayLike, dst_m: npt.ArrayLike) -> Floats:
    """Distances ``(L,)`` [m] between the ends ``src_m``, ``dst_m`` ``(L, d)`` [m] of ``L`` links.

    The simulator measures its links with this and netem each packet's with :func:`link_length`:
    both sum the squared coordinates in coordinate order (IEEE operations, one by one), so
    their verdicts agree bit for bit.
    """
    diff = np.asarray(src_m, dtype=np.float64) - np.asarray(dst_m, dtype=np.float64)
    total = diff[..., 0] * diff[..., 0]
    for c in range(1, diff.shape[-1]):
        total = total + diff[..., c] * diff[..., c]
    return np.asarray(np.sqrt(total), dtype=np.float64)


def link_length(src_m: Sequence[float], dst_m: Sequence[float]) -> float:
    """One link's :func:`link_lengths` [m], in plain floats (netem measures every packet's)."""
    if len(src_m) == 2 == len(dst_m):  # the plane, unrolled: the same operations in that order
        dx, dy = src_m[0] - dst_m[0], src_m[1] - dst_m[1]
        return math.sqrt(dx * dx + dy * dy)
    total = 0.0
    for c, (a, b) in enumerate(zip(src_m, dst_m, strict=True)):
        diff = a - b
        total = diff * diff if c == 0 else total + diff * diff
    return math.sqrt(total)


__all__ = [
    "DeliveryPlan",
    "DistanceGroup",
    "delivery_matrix",
    "delivery_plan",
    "link_length",
    "link_lengths",
]
