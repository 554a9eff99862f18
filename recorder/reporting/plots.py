"""The report's figures (docs/model.md §7): arrays in, a PNG out. The experiments draw theirs in ``testbed.experiments.plots``.

Each function takes plain numpy arrays and labels, so a recording and the
in-process simulator plot the same way; functions taking a list of series draw
several runs (strategies) on the same axes. Figures are built with
:class:`matplotlib.figure.Figure` and the Agg canvas: no pyplot state, no display.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse

Array = npt.NDArray[np.float64]
DPI = 100


def _save(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=DPI)
    return path


def _log_axis(ax: Axes, values: Sequence[Array]) -> None:
    finite = np.concatenate([v[np.isfinite(v)] for v in values]) if values else np.zeros(0)
    if (
        finite.size
        and (finite > 0).any()
        and finite.max() / max(finite[finite > 0].min(), 1e-300) > 50
    ):
        ax.set_yscale("log")


def plot_errors(
    series: Sequence[tuple[str, Array, Array]],
    path: Path,
    marks: Sequence[tuple[int, str]] = (),
) -> Path:
    """Formation and shape error over epochs: ``series`` of ``(label, formation (P,), shape (P,))`` [m].

    ``marks``: ``(epoch, text)`` drawn as vertical lines, the text starting with the change:
    red where an agent goes out (``lost``, ``leave``, ``crash``), green where it comes in;
    dashed when unplanned (``lost``, ``back``), dotted for the scenario's events.
    """
    fig = Figure(figsize=(9, 6.5), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True)
    for label, form, shape in series:
        top.plot(np.arange(len(form)), form, label=label)
        bottom.plot(np.arange(len(shape)), shape, label=label)
    _log_axis(top, [s[1] for s in series])
    _log_axis(bottom, [s[2] for s in series])
    top.set_ylabel("formation error [m]")
    top.set_title("RMS over edges of ||x_i − x_j|| − C_ij")
    bottom.set_ylabel("shape error [m]")
    bottom.set_xlabel("epoch")
    for epoch, text in marks:
        what = text.split()[0]
        color = "tab:red" if what in ("lost", "leave", "crash") else "tab:green"
        style = "--" if what in ("lost", "back") else ":"
        for ax in (top, bottom):
            ax.axvline(epoch, color=color, linestyle=style, linewidth=0.9, alpha=0.8)
        top.annotate(
            text,
            (epoch, 0.98),
            xycoords=("data", "axes fraction"),
            fontsize="small",
            color=color,
            rotation=90,
            va="top",
            ha="right",
            zorder=5,
            bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8},
        )
    for ax in (top, bottom):
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    return _save(fig, path)


def plot_trajectories(
    runs: Sequence[tuple[str, Array]],
    edges: npt.NDArray[np.int64],
    leader: int,
    epochs: Sequence[int],
    path: Path,
) -> Path:
    """Trajectories of every agent, the formation drawn at ``epochs``; ``runs`` of ``(label, (P, n, d))``.

    A 3-D run is drawn projected on the x–y plane. Teams of more than :data:`MAX_DRAWN`
    agents get the aggregate view of :func:`_team_at_epochs` instead: their trajectories
    would be a smear.
    """
    if runs and runs[0][1].shape[1] > MAX_DRAWN:
        return _team_at_epochs(runs, edges, leader, epochs, path)
    cols = len(runs)
    fig = Figure(figsize=(5.5 * cols, 5.2), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, cols, squeeze=False)[0])
    for ax, (label, x) in zip(axes, runs, strict=True):
        n = x.shape[1]
        colors = [f"C{i % 10}" for i in range(n)]
        for i in range(n):
            ax.plot(
                x[:, i, 0], x[:, i, 1], color=colors[i], lw=1.0, alpha=0.8, label=f"agent {i + 1}"
            )
        shades = np.linspace(0.35, 1.0, max(len(epochs), 1))
        for shade, k in zip(shades, epochs, strict=False):
            if not 0 <= k < len(x) or not np.isfinite(x[k]).all():
                continue
            for i, j in edges:
                a, b = x[k, i - 1], x[k, j - 1]
                ax.plot([a[0], b[0]], [a[1], b[1]], color="k", alpha=float(shade), lw=1.2)
            ax.scatter(
                x[k, :, 0], x[k, :, 1], c=colors, s=25, zorder=3, edgecolors="k", linewidths=0.5
            )
            ax.annotate(
                f"k={k}",
                x[k, leader - 1, :2],
                fontsize="x-small",
                xytext=(4, 4),
                textcoords="offset points",
            )
        ax.set_title(label)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="best", fontsize="x-small")
    return _save(fig, path)


MAX_DRAWN = 60
"""Agents (trajectories) or links (timeline rows) up to which each is drawn on its own."""


def _team_at_epochs(
    runs: Sequence[tuple[str, Array]],
    edges: npt.NDArray[np.int64],
    leader: int,
    epochs: Sequence[int],
    path: Path,
) -> Path:
    """A large team: its edges at ``epochs`` (one collection each) and the reference's path."""
    cols = len(runs)
    fig = Figure(figsize=(5.5 * cols, 5.2), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, cols, squeeze=False)[0])
    for ax, (label, x) in zip(axes, runs, strict=True):
        for index, k in enumerate(epochs):
            if not 0 <= k < len(x):
                continue
            seen = np.isfinite(x[k]).all(axis=1)
            e = edges[seen[edges[:, 0] - 1] & seen[edges[:, 1] - 1]] - 1
            segments = np.stack([x[k, e[:, 0], :2], x[k, e[:, 1], :2]], axis=1)
            ax.add_collection(
                LineCollection(list(segments), colors=f"C{index}", linewidths=0.3, label=f"k={k}")
            )
        ax.plot(
            x[:, leader - 1, 0], x[:, leader - 1, 1], color="k", lw=1.2, label="reference agent"
        )
        ax.autoscale()
        ax.set_title(f"{label}: {x.shape[1]} agents, formation at chosen epochs")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="x-small")
    return _save(fig, path)


def _link_shares(
    runs: Sequence[tuple[str, npt.NDArray[np.bool_], npt.NDArray[np.bool_]]], count: int, path: Path
) -> Path:
    """Many links: the share delivered, dropped and unknown at each epoch, and drops per link."""
    fig = Figure(figsize=(10, 3.2 * len(runs)), layout="constrained")
    axes = fig.subplots(len(runs), 2, squeeze=False, width_ratios=[3, 1])
    for (ax, hist), (label, delivered, decided) in zip(axes, runs, strict=True):
        k = np.arange(delivered.shape[0])
        shares = [
            (decided & delivered).mean(axis=1),
            (decided & ~delivered).mean(axis=1),
            (~decided).mean(axis=1),
        ]
        ax.stackplot(
            k,
            shares,
            colors=["#2ca02c", "#d62728", "#cccccc"],
            labels=["delivered", "dropped", "unknown"],
        )
        ax.set_ylim(0.0, 1.0)
        ax.set_ylabel(f"share of {count} links")
        ax.set_xlabel("epoch")
        ax.set_title(f"{label}: links delivered, dropped, unknown", fontsize="small")
        ax.legend(loc="lower left", fontsize="x-small")
        drops = (decided & ~delivered).sum(axis=0)
        hist.hist(drops, bins=np.arange(drops.max() + 2) - 0.5, color="#d62728")
        hist.set_xlabel("drops per link")
        hist.set_ylabel("links")
    return _save(fig, path)


def plot_link_timeline(
    runs: Sequence[tuple[str, npt.NDArray[np.bool_], npt.NDArray[np.bool_]]],
    link_labels: Sequence[str],
    path: Path,
) -> Path:
    """Per-link delivered (green) / dropped (red) / unknown (grey) by epoch; ``(label, delivered, decided)``.

    More than :data:`MAX_DRAWN` links: their shares per epoch and the drops per link.
    """
    if len(link_labels) > MAX_DRAWN:
        return _link_shares(runs, len(link_labels), path)
    rows = len(runs)
    height = max(2.0, 0.22 * len(link_labels) + 1.2)
    fig = Figure(figsize=(10, height * rows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, 1, squeeze=False)[:, 0])
    palette = np.array([[0.84, 0.15, 0.16], [0.17, 0.63, 0.17], [0.8, 0.8, 0.8]])
    for ax, (label, delivered, decided) in zip(axes, runs, strict=True):
        code = np.where(decided, delivered.astype(int), 2)
        if code.shape[0] == 0:  # a run that ended before its first epoch
            ax.text(0.5, 0.5, "no epoch recorded", ha="center", va="center", transform=ax.transAxes)
            continue
        ax.imshow(palette[code.T], aspect="auto", interpolation="nearest", origin="lower")
        ax.set_yticks(np.arange(len(link_labels)), list(link_labels), fontsize="x-small")
        ax.set_title(
            f"{label}: links delivered (green), dropped (red), unknown (grey)", fontsize="small"
        )
        ax.set_xlabel("epoch")
    return _save(fig, path)


def plot_topology(
    runs: Sequence[
        tuple[
            str,
            npt.NDArray[np.bool_],
            npt.NDArray[np.int64],
            npt.NDArray[np.int64],
            npt.NDArray[np.int64],
        ]
    ],
    expected_rank: int,
    path: Path,
) -> Path:
    """MST changes, rigidity rank and components over epochs; ``(label, tree (E, m), rank (E,),
    components (E,), rigid (E,))``. Where only rigid or not is known (rank −1, a large
    formation: docs/model.md §2), a marker on the rigid line says which."""
    fig = Figure(figsize=(9, 7), layout="constrained")
    ax_tree, ax_rank, ax_comp = fig.subplots(3, 1, sharex=True)
    for index, (label, tree, rank, comps, rigid) in enumerate(runs):
        k = np.arange(len(rank))
        changes = (
            np.r_[False, (tree[1:] != tree[:-1]).any(axis=1)] if len(tree) else np.zeros(0, bool)
        )
        size = tree.sum(axis=1) if len(tree) else np.zeros(0)
        ax_tree.step(k, size, where="post", label=f"{label}: tree edges")
        ax_tree.scatter(k[changes], size[changes], marker="x", color=f"C{index}", zorder=3)
        known = rank >= 0
        if known.any():
            ax_rank.step(k[known], rank[known], where="post", label=label)
        for value, marker, what in ((1, "o", "rigid"), (0, "v", "not rigid")):
            at = ~known & (rigid[: len(k)] == value)
            if at.any():
                ax_rank.scatter(
                    k[at],
                    np.full(at.sum(), expected_rank),
                    marker=marker,
                    s=12,
                    color=f"C{index}",
                    label=f"{label}: {what}, rank not computed",
                )
        ax_comp.step(k[comps >= 0], comps[comps >= 0], where="post", label=label)
    ax_rank.axhline(expected_rank, color="k", ls="--", lw=1, label=f"rigid ({expected_rank})")
    ax_tree.set_ylabel("MST edges (x: change)")
    ax_rank.set_ylabel("rigidity rank\n(healthy subgraph)")
    ax_comp.set_ylabel("components")
    ax_comp.set_xlabel("epoch")
    for ax in (ax_tree, ax_rank, ax_comp):
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="x-small")
    return _save(fig, path)


def _ellipse(ax: Axes, errors: Array, color: str) -> None:
    """The 2-σ ellipse of the first two coordinates of ``errors`` (N, d)."""
    if errors.shape[0] < 3:
        return
    cov = np.cov(errors[:, :2], rowvar=False)
    vals, vecs = np.linalg.eigh(cov)
    angle = float(np.degrees(np.arctan2(vecs[1, 1], vecs[0, 1])))
    w, h = 4 * np.sqrt(np.maximum(vals[::-1], 0.0))
    mean = errors[:, :2].mean(axis=0)
    ax.add_patch(
        Ellipse(
            (float(mean[0]), float(mean[1])),
            float(w),
            float(h),
            angle=angle,
            fill=False,
            color=color,
            lw=1.5,
        )
    )


def plot_covariance(runs: Sequence[tuple[str, Array, Array]], path: Path) -> Path:
    """Substitution errors ``x̃ − x`` and estimation errors ``x̂ − x`` with 2-σ ellipses; ``(label, sub (N, d), est (M, d))``."""
    fig = Figure(figsize=(11, 5), layout="constrained")
    ax_sub, ax_est = fig.subplots(1, 2)
    for index, (label, sub, est) in enumerate(runs):
        color = f"C{index}"
        for ax, err in ((ax_sub, sub), (ax_est, est)):
            if err.shape[0] == 0:
                continue
            trace = (
                np.trace(np.atleast_2d(np.cov(err, rowvar=False))) if err.shape[0] > 1 else np.nan
            )
            ax.scatter(
                err[:, 0],
                err[:, 1],
                s=6,
                alpha=0.4,
                color=color,
                label=f"{label} (tr Σ = {trace:.3g} m²)",
            )
            _ellipse(ax, err, color)
    ax_sub.set_title("substitution error x̃_j − x_j (lost packets)")
    ax_est.set_title("estimation error x̂ − x (leader's BLUE)")
    for ax in (ax_sub, ax_est):
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.grid(True, alpha=0.3)
        if ax.has_data():
            ax.legend(loc="best", fontsize="x-small")
        else:
            ax.text(0.5, 0.5, "none recorded", transform=ax.transAxes, ha="center", va="center")
    return _save(fig, path)


def plot_nees(runs: Sequence[tuple[str, Array]], d: int, path: Path) -> Path:
    """NEES per scored agent and epoch: histogram and running mean against ``d`` (honest estimator)."""
    fig = Figure(figsize=(11, 4.5), layout="constrained")
    ax_hist, ax_mean = fig.subplots(1, 2)
    for label, values in runs:
        if values.size == 0:
            continue
        ax_hist.hist(
            values,
            bins=40,
            histtype="step",
            density=True,
            label=f"{label} (mean {values.mean():.3g})",
        )
        ax_mean.plot(np.cumsum(values) / np.arange(1, values.size + 1), label=label)
    for ax in (ax_hist, ax_mean):
        ax.grid(True, alpha=0.3)
    ax_mean.axhline(d, color="k", ls="--", lw=1, label=f"d = {d}")
    ax_hist.set_xlabel("NEES")
    ax_hist.set_title("distribution (χ²_d for an honest estimator)")
    ax_mean.set_xlabel("sample")
    ax_mean.set_ylabel("running mean")
    for ax in (ax_hist, ax_mean):
        if ax.has_data():
            ax.legend(loc="best", fontsize="x-small")
    return _save(fig, path)


def plot_queue_depths(runs: Sequence[tuple[str, dict[str, Any]]], path: Path) -> Path:
    """Each capacity queue's depth over the run: the largest a packet found per epoch.

    ``runs``: (label, the summary's ``queues``: name → ``max_depth_by_epoch``, epoch → depth).
    """
    fig = Figure(figsize=(11, 3.8), layout="constrained")
    ax = fig.subplots()
    for label, queues in runs:
        for name, q in queues.items():
            series = q["max_depth_by_epoch"]
            epochs = np.array([int(k) for k in series], dtype=float)
            ax.step(epochs, list(series.values()), where="post", label=f"{label}: {name}", lw=1)
    ax.set_xlabel("epoch")
    ax.set_ylabel("depth [packets]")
    ax.grid(True, alpha=0.3)
    if ax.has_data():
        ax.legend(loc="best", fontsize="x-small")
    return _save(fig, path)


__all__ = [
    "plot_covariance",
    "plot_errors",
    "plot_link_timeline",
    "plot_nees",
    "plot_queue_depths",
    "plot_topology",
    "plot_trajectories",
]
