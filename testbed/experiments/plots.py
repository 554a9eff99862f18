"""Figures of ``formation experiment`` and ``formation sweep`` (matplotlib, Agg, no pyplot state).

Each function takes arrays and writes one PNG. Kept out of ``recorder/reporting/plots.py`` (the per-run
report's plots) because these compare many runs; the same conventions: SI units on the axes,
each strategy in its one look (``recorder.look``: colour, line style, marker) with its markers
at its own epochs, so a strategy identical to another stays visible, and ``notes`` (strategy →
"identical to …") in the legend. Files written once.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from recorder import THRESHOLD_COLOUR, look, palette

Array = npt.NDArray[np.float64]
MARKS = 10  # markers along a curve: enough to tell two coinciding curves apart
_META = {"Software": None}  # no version string in the file: same inputs, same bytes


def _save(fig: Figure, path: Path) -> Path:
    fig.savefig(path, dpi=110, metadata=_META)
    return path


def _label(name: str, notes: Mapping[str, str]) -> str:
    return f"{name} ({notes[name]})" if name in notes else name


def _curve(ax: Axes, index: int, count: int, name: str, y: Array, label: str | None) -> None:
    """``y`` over its epochs in ``name``'s look, its markers offset from the other curves'."""
    step = max(len(y) // MARKS, count, 1)
    style: dict[str, Any] = look(name).kwargs()
    ax.plot(
        np.arange(len(y)),
        y,
        **style,
        markevery=(index % step, step),
        markersize=5,
        lw=1.4,
        markerfacecolor="none" if index % 2 else style["color"],
        zorder=2 + index,
        label=label,
    )


def plot_agent_positions(
    positions: Mapping[str, Array],
    desired: Array,
    agents: Sequence[int],
    path: Path,
    title: str,
    notes: Mapping[str, str] | None = None,
) -> Path:
    """x and y of ``agents`` over the epochs, one column per strategy (figs 7.7–7.11).

    positions : strategy → (E + 1, n, d) true positions [m]; desired : (E + 1, n, d) the slots
    ``x_ref + d0_i − d0_r`` [m]; notes : strategy → a note in its column's title.
    """
    notes = notes or {}
    names = list(positions)
    fig = Figure(figsize=(3.2 * len(names), 5.4), layout="constrained")
    axes = fig.subplots(2, len(names), sharex=True, sharey="row", squeeze=False)
    styles = ["-", "--", ":", "-."]
    for c, name in enumerate(names):
        x = positions[name]
        epochs = np.arange(x.shape[0])
        colour = look(name).colour
        for row, coord in enumerate("xy"):
            ax = axes[row, c]
            for a_i, agent in enumerate(agents):
                ls = styles[a_i % len(styles)]
                ax.plot(epochs, x[:, agent - 1, row], ls, color=colour, label=f"agent {agent}")
                ax.plot(
                    epochs,
                    desired[:, agent - 1, row],
                    ls,
                    color="0.6",
                    lw=0.8,
                    label=f"slot of {agent}",
                )
            ax.set_ylabel(f"{coord} [m]" if c == 0 else "")
            if row == 0:
                ax.set_title(_label(name, notes).replace(" (", "\n("), color=colour, fontsize=9)
            else:
                ax.set_xlabel("epoch")
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(title + "; grey: each agent's slot in the formation", fontsize=10)
    return _save(fig, path)


def plot_strategy_paths(
    positions: Mapping[str, Array],
    desired: Array,
    agents: Sequence[int],
    path: Path,
    title: str,
    notes: Mapping[str, str] | None = None,
) -> Path:
    """The plane paths of ``agents`` per strategy, with their slots (grey); at most three
    panels a row."""
    notes = notes or {}
    names = list(positions)
    cols = min(3, len(names))
    rows = -(-len(names) // cols)
    fig = Figure(figsize=(3.6 * cols, 3.4 * rows + 0.4), layout="constrained")
    grid = fig.subplots(rows, cols, squeeze=False).ravel()
    for spare in grid[len(names) :]:
        spare.set_visible(False)
    for ax, name in zip(grid, names, strict=False):
        x, style = positions[name], look(name)
        for agent in agents:
            ax.plot(desired[:, agent - 1, 0], desired[:, agent - 1, 1], color="0.6", lw=0.8)
            ax.plot(x[:, agent - 1, 0], x[:, agent - 1, 1], color=style.colour, ls=style.line)
            ax.plot(*x[-1, agent - 1, :2], style.marker, color=style.colour, ms=5)
            ax.annotate(f"agent {agent}", x[-1, agent - 1, :2], fontsize=7)
        ax.set_title(_label(name, notes), color=style.colour, fontsize=9)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    fig.suptitle(title + "; grey: the agents' slots", fontsize=10)
    return _save(fig, path)


def plot_error_bands(
    series: Mapping[str, Array],
    path: Path,
    title: str,
    ylabel: str,
    log: bool = True,
    marks: Sequence[tuple[int, str]] = (),
    notes: Mapping[str, str] | None = None,
    keep_m: float | None = None,
    floor_m: float | None = None,
) -> Path:
    """Median and 10–90 % band over seeds of a per-epoch quantity per strategy.

    series : strategy → (E + 1, S) values [m] (seeds in columns); marks : (epoch, label) lines;
    notes : strategy → a legend note; keep_m, floor_m : the keep threshold and the noise floor
    [m], drawn where given.
    """
    notes = notes or {}
    fig = Figure(figsize=(8.0, 4.4), layout="constrained")
    ax = fig.subplots()
    for index, (name, v) in enumerate(series.items()):
        epochs = np.arange(v.shape[0])
        with np.errstate(all="ignore"):
            lo, med, hi = np.nanpercentile(v, [10, 50, 90], axis=1)
        _curve(ax, index, len(series), name, med, _label(name, notes))
        if name not in notes:  # an identical band would only darken the first
            ax.fill_between(epochs, lo, hi, color=look(name).colour, alpha=0.12, lw=0)
    if keep_m is not None:
        ax.axhline(keep_m, color=THRESHOLD_COLOUR, ls="--", lw=1, label=f"keep: {keep_m:g} m")
    if floor_m is not None:
        ax.axhline(
            floor_m, color=THRESHOLD_COLOUR, ls=":", lw=1, label=f"noise floor {floor_m:.2g} m"
        )
    for epoch, label in marks:
        ax.axvline(epoch, color="0.3", ls="--", lw=0.8)
        ax.annotate(
            label,
            (epoch, 1.0),
            xycoords=("data", "axes fraction"),
            fontsize=7,
            ha="left",
            va="top",
            rotation=90,
        )
    if log:
        ax.set_yscale("log")
    ax.set_xlabel("epoch")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return _save(fig, path)


def plot_covariance_over_epochs(
    traces: Mapping[str, Array], path: Path, title: str, notes: Mapping[str, str] | None = None
) -> Path:
    """Trace of the substitution error covariance at each epoch (over seeds), per strategy.

    traces : strategy → (E,) [m²], NaN where fewer than two errors.
    """
    notes = notes or {}
    fig = Figure(figsize=(8.0, 4.2), layout="constrained")
    ax = fig.subplots()
    for index, (name, v) in enumerate(traces.items()):
        _curve(ax, index, len(traces), name, v, _label(name, notes))
    ax.set_yscale("log")
    ax.set_xlabel("epoch")
    ax.set_ylabel("tr Cov(x̃ − x) [m²]")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return _save(fig, path)


def plot_alpha_curve(
    alphas: Array, curves: Mapping[str, Array], best: Mapping[str, float], path: Path, title: str
) -> Path:
    """A quantity against blend's ``α``, one line per measurement, the best ``α`` marked."""
    fig = Figure(figsize=(6.5, 4.0), layout="constrained")
    ax = fig.subplots()
    colours = palette(len(curves))
    for i, (label, v) in enumerate(curves.items()):
        colour = colours[i]
        ax.plot(alphas, v, "o-", color=colour, ms=3, label=label)
        if label in best:
            j = int(np.argmin(np.abs(alphas - best[label])))
            ax.plot(alphas[j], v[j], "*", color=colour, ms=12)
    ax.set_yscale("log")
    ax.set_xlabel("α (blend)")
    ax.set_ylabel("ratio to α = 1 (estimate)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    return _save(fig, path)


def plot_phase(
    success: Mapping[tuple[str, str, str], Array],
    critical: Mapping[tuple[str, str, str], float | None],
    losses: Sequence[float],
    grid: tuple[Sequence[str], Sequence[str], Sequence[str]],
    threshold_m: float,
    path: Path,
) -> Path:
    """Success fraction over loss rate × strategy, one panel per topology and loss model.

    ``success[(topology, model, strategy)]`` : (L,) fraction of seeds kept at each of ``losses``;
    ``critical`` the critical rate of each (None: not even the first); ``grid`` is (topologies,
    models, strategies).
    """
    topologies, models, strategies = grid
    rows, cols = len(models), len(topologies)
    fig = Figure(
        figsize=(3.6 * cols + 0.8, 0.45 * len(strategies) * rows + 1.4 * rows),
        layout="constrained",
    )
    axes = fig.subplots(rows, cols, squeeze=False, sharex=True)
    xs = np.asarray(losses, dtype=float)
    step = float(np.min(np.diff(xs))) if xs.size > 1 else 0.05
    image: Any = None
    for r, model in enumerate(models):
        for c, name in enumerate(topologies):
            ax = axes[r, c]
            cells = np.array([success[(name, model, s)] for s in strategies])
            image = ax.imshow(
                cells,
                aspect="auto",
                cmap="viridis",
                vmin=0.0,
                vmax=1.0,
                interpolation="nearest",
                extent=(
                    xs[0] - step / 2,
                    xs[-1] + step / 2,
                    len(strategies) - 0.5,
                    -0.5,
                ),
            )
            for i, s in enumerate(strategies):
                crit = critical[(name, model, s)]
                if crit is not None:
                    ax.plot([crit + step / 2] * 2, [i - 0.5, i + 0.5], color="w", lw=2)
            ax.set_yticks(range(len(strategies)), list(strategies))
            ax.set_title(f"{name}, {model}", fontsize=9)
            if r == rows - 1:
                ax.set_xlabel("loss probability")
    if image is not None:
        fig.colorbar(
            image,
            ax=axes,
            shrink=0.8,
            label=f"fraction of seeds with shape error < {threshold_m:g} m",
        )
    return _save(fig, path)


def plot_dynamic(
    shape_err: Mapping[str, Array],
    tree_edges: Array,
    leave: int,
    join: int,
    path: Path,
    title: str,
    notes: Mapping[str, str] | None = None,
) -> Path:
    """Shape error over the active edges (median over seeds) and the leader's tree size."""
    fig = Figure(figsize=(7.0, 5.5), layout="constrained")
    ax, ax2 = fig.subplots(2, 1, sharex=True, height_ratios=(3, 1))
    for index, (name, v) in enumerate(shape_err.items()):
        with np.errstate(all="ignore"):
            med = np.nanmedian(v, axis=1)
        _curve(ax, index, len(shape_err), name, med, _label(name, notes or {}))
    for a in (ax, ax2):
        a.axvline(leave, color="0.3", ls="--", lw=0.8)
        a.axvline(join, color="0.3", ls=":", lw=0.8)
        a.grid(alpha=0.3)
    ax.annotate("leaves", (leave, 1.0), xycoords=("data", "axes fraction"), fontsize=7, va="top")
    ax.annotate("joins", (join, 1.0), xycoords=("data", "axes fraction"), fontsize=7, va="top")
    ax.set_yscale("log")
    ax.set_ylabel("shape error, active edges [m]")
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=10)
    ax2.step(np.arange(tree_edges.shape[0]), tree_edges, where="post", color="k")
    ax2.set_ylabel("edges in the\nleader's tree")
    ax2.set_xlabel("epoch")
    return _save(fig, path)


def plot_range_phase(
    success: Mapping[tuple[str, str], Array],
    critical: Mapping[tuple[str, str], float | None],
    ranges: Sequence[float],
    cases: Sequence[str],
    strategies: Sequence[str],
    threshold_m: float,
    path: Path,
    xlabel: str = "radio range d50 / longest edge",
    columns: int | None = None,
    easiest: Literal["low", "high"] = "high",
    reference: float | None = 1.0,
) -> Path:
    """Success fraction over radio range (or ``xlabel``'s axis) × strategy, one panel per case,
    ``columns`` panels a row (default: all in one).

    ``success[(case, strategy)]`` : (R,) fraction of seeds kept at each of ``ranges`` (multiples
    of the longest edge, evenly spaced); ``critical`` the least range from which every larger
    one keeps (None: not even the largest), marked white on its left edge; with ``easiest =
    "low"`` the largest point up to which every smaller one keeps, marked on its right edge.
    ``reference``: where a dashed line marks the axis (the longest edge's length; None: none).
    """
    cols = columns or len(cases)
    rows = -(-len(cases) // cols)
    fig = Figure(
        figsize=(4.2 * cols + 0.8, rows * (0.45 * len(strategies) + 1.6)), layout="constrained"
    )
    grid = fig.subplots(rows, cols, squeeze=False, sharey=True).ravel()
    for spare in grid[len(cases) :]:
        spare.set_visible(False)
    axes = grid[: len(cases)]
    xs = np.asarray(ranges, dtype=float)
    step = float(np.min(np.diff(xs))) if xs.size > 1 else 0.25
    image: Any = None
    for ax, case in zip(axes, cases, strict=True):
        cells = np.array([success[(case, s)] for s in strategies])
        image = ax.imshow(
            cells,
            aspect="auto",
            cmap="viridis",
            vmin=0.0,
            vmax=1.0,
            interpolation="nearest",
            extent=(xs[0] - step / 2, xs[-1] + step / 2, len(strategies) - 0.5, -0.5),
        )
        for i, s in enumerate(strategies):
            crit = critical[(case, s)]
            if crit is not None:
                edge = crit - step / 2 if easiest == "high" else crit + step / 2
                ax.plot([edge] * 2, [i - 0.5, i + 0.5], color="w", lw=2)
        if reference is not None:  # below: the longest links out of range
            ax.axvline(reference, color="0.8", lw=0.8, ls="--")
        if easiest == "low":  # a count (team sizes): a tick at each point
            ax.set_xticks(xs, [f"{x:g}" for x in xs])
        ax.set_yticks(range(len(strategies)), list(strategies))
        ax.set_title(case, fontsize=9)
        ax.set_xlabel(xlabel, fontsize=8)
    if image is not None:
        fig.colorbar(
            image,
            ax=axes,
            shrink=0.8,
            label=f"fraction of seeds with final error < {threshold_m:g} m",
        )
    return _save(fig, path)


__all__ = [
    "plot_agent_positions",
    "plot_alpha_curve",
    "plot_covariance_over_epochs",
    "plot_dynamic",
    "plot_error_bands",
    "plot_phase",
    "plot_range_phase",
    "plot_strategy_paths",
]
