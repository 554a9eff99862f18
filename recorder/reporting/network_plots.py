"""The report's figures of the network: each link's deliveries and the leader's graph over a run.

A run's losses and the leader's graph do not depend on the loss strategy when the links'
models do not, so runs whose arrays are equal to the bit are drawn once, in one panel or
one line named for all of them. Arrays in, a PNG out, as in :mod:`recorder.reporting.plots`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator

from recorder.reporting.plots import MAX_DRAWN, Drawn, _save, group_label, groups
from recorder.reporting.style import BLACK, LOSS_COLOUR, SKY_BLUE, UNKNOWN_COLOUR

Bools = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]
DELIVERED, DROPPED, UNKNOWN = SKY_BLUE, LOSS_COLOUR, UNKNOWN_COLOUR
_LEGEND = [
    Patch(color=DELIVERED, label="delivered"),
    Patch(color=DROPPED, label="dropped"),
    Patch(color=UNKNOWN, label="unknown"),
]


def _rgb(colour: str) -> list[float]:
    return [int(colour[i : i + 2], 16) / 255 for i in (1, 3, 5)]


def _link_shares(
    runs: Sequence[Drawn], links: Sequence[tuple[Bools, Bools]], count: int, path: Path
) -> Path:
    """Many links: the share delivered, dropped and unknown at each epoch, and drops per link."""
    distinct = groups(list(links))
    fig = Figure(figsize=(10, 3.2 * len(distinct)), layout="constrained")
    axes = fig.subplots(len(distinct), 2, squeeze=False, width_ratios=[3, 1])
    for (ax, hist), group in zip(axes, distinct, strict=True):
        delivered, decided = links[group[0]]
        k = np.arange(delivered.shape[0])
        shares = [
            (decided & delivered).mean(axis=1),
            (decided & ~delivered).mean(axis=1),
            (~decided).mean(axis=1),
        ]
        ax.stackplot(k, shares, colors=[DELIVERED, DROPPED, UNKNOWN])
        ax.set_ylim(0.0, 1.0)
        ax.set_ylabel(f"share of {count} links")
        ax.set_xlabel("epoch")
        ax.set_title(group_label(runs, group), fontsize="small")
        ax.legend(handles=_LEGEND, loc="lower left", fontsize="x-small")
        drops = (decided & ~delivered).sum(axis=0)
        hist.hist(drops, bins=np.arange(drops.max() + 2) - 0.5, color=DROPPED)
        hist.set_xlabel("drops per link")
        hist.set_ylabel("links")
    return _save(fig, path)


def plot_link_timeline(
    runs: Sequence[Drawn],
    links: Sequence[tuple[Bools, Bools]],
    link_labels: Sequence[str],
    path: Path,
) -> Path:
    """Per link and epoch: delivered, dropped or unknown; ``links`` of ``(delivered, decided)``
    (E, L) per run, one panel per distinct pair. More than :data:`MAX_DRAWN` links: their
    shares per epoch and the drops per link."""
    if len(link_labels) > MAX_DRAWN:
        return _link_shares(runs, links, len(link_labels), path)
    distinct = groups(list(links))
    height = max(2.0, 0.22 * len(link_labels) + 1.4)
    fig = Figure(figsize=(10, height * len(distinct)), layout="constrained")
    axes = np.atleast_1d(fig.subplots(len(distinct), 1, squeeze=False)[:, 0])
    palette = np.array([_rgb(DROPPED), _rgb(DELIVERED), _rgb(UNKNOWN)])
    for ax, group in zip(axes, distinct, strict=True):
        delivered, decided = links[group[0]]
        ax.set_title(f"{group_label(runs, group)}: each link's packets", fontsize="small")
        if delivered.shape[0] == 0:  # a run that ended before its first epoch
            ax.text(0.5, 0.5, "no epoch recorded", ha="center", va="center", transform=ax.transAxes)
            continue
        code = np.where(decided, delivered.astype(int), 2)
        ax.imshow(palette[code.T], aspect="auto", interpolation="nearest", origin="lower")
        ax.set_yticks(np.arange(len(link_labels)), list(link_labels), fontsize="x-small")
        ax.set_ylabel("link (sender→receiver)")
        ax.set_xlabel("epoch")
        ax.legend(handles=_LEGEND, loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize="x-small")
    return _save(fig, path)


def plot_topology(
    runs: Sequence[Drawn],
    graphs: Sequence[tuple[Bools, Ints, Ints, Ints]],
    expected_rank: int,
    path: Path,
) -> Path:
    """MST size and changes, rigidity rank and components over epochs, a line per distinct run:
    ``graphs`` of ``(tree (E, m), rank (E,), components (E,), rigid (E,))``. Where only rigid
    or not is known (rank −1, a large formation: docs/model.md §2), a marker on the rigid line
    says which."""
    fig = Figure(figsize=(9, 7), layout="constrained")
    ax_tree, ax_rank, ax_comp = fig.subplots(3, 1, sharex=True)
    for group in groups(list(graphs)):
        tree, rank, comps, rigid = graphs[group[0]]
        first = runs[group[0]]
        colour = BLACK if len(group) > 1 else first.look.colour
        label = group_label(runs, group)
        k = np.arange(len(rank))
        changes = (
            np.r_[False, (tree[1:] != tree[:-1]).any(axis=1)] if len(tree) else np.zeros(0, bool)
        )
        size = tree.sum(axis=1) if len(tree) else np.zeros(0)
        ax_tree.step(k, size, where="post", color=colour, label=label)
        if changes.any():
            ax_tree.scatter(
                k[changes], size[changes], marker="x", color=colour, zorder=3, label="tree changed"
            )
        known = rank >= 0
        if known.any():
            ax_rank.step(k[known], rank[known], where="post", color=colour, label=label)
        for value, marker, what in ((1, "o", "rigid"), (0, "v", "not rigid")):
            at = ~known & (rigid[: len(k)] == value)
            if at.any():
                ax_rank.scatter(
                    k[at],
                    np.full(at.sum(), expected_rank),
                    marker=marker,
                    s=12,
                    color=colour,
                    label=f"{label}: {what}, rank not computed",
                )
        ax_comp.step(k[comps >= 0], comps[comps >= 0], where="post", color=colour, label=label)
    ax_rank.axhline(
        expected_rank, color=LOSS_COLOUR, ls="--", lw=1, label=f"rigid: rank {expected_rank}"
    )
    ax_tree.set_ylabel("MST edges")
    ax_tree.set_title("the leader's graph of the links that delivered (healthy subgraph)")
    ax_rank.set_ylabel("rigidity rank")
    ax_comp.set_ylabel("connected components")
    ax_comp.set_xlabel("epoch")
    for ax in (ax_tree, ax_rank, ax_comp):  # counts: from zero, whole numbers
        ax.set_ylim(0, max(ax.get_ylim()[1], 1.0) + 0.5)
        ax.grid(True, alpha=0.3)
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        if ax.has_data():
            ax.legend(loc="best", fontsize="x-small")
    return _save(fig, path)


__all__ = ["plot_link_timeline", "plot_topology"]
