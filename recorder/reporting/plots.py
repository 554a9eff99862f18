"""The report's figures (docs/model.md §7): arrays in, a PNG out. The experiments draw theirs in ``testbed.experiments.plots``.

Each function takes plain numpy arrays and, per run, a :class:`Drawn` (its label, its
strategy's look from :mod:`recorder.reporting.style` and a note when it moves identically to
another run), so a recording and the in-process simulator plot the same way. A run never
hides under another: every line carries its strategy's markers at its own epochs, and
a note says when two are identical. What is identical in every run (the links' losses,
the leader's graph and estimate) is drawn once. Figures are built with
:class:`matplotlib.figure.Figure` and the Agg canvas: no pyplot state, no display.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse
from scipy.stats import chi2

from recorder.reporting.style import (
    BLACK,
    GAIN_COLOUR,
    GREY,
    LOSS_COLOUR,
    THRESHOLD_COLOUR,
    Look,
    palette,
)

Array = npt.NDArray[np.float64]
DPI = 100
MARKS = 10  # markers along a line: enough to tell two coinciding lines apart
# x̂ − x depends on the noise, not on where the agents are; its rounding does
SAME_ESTIMATE = 1e-6


@dataclass(frozen=True)
class Drawn:
    """How one run is drawn: its label, its strategy's look and a note ("identical to …")."""

    label: str
    look: Look
    note: str = ""

    @property
    def legend(self) -> str:
        return f"{self.label} ({self.note})" if self.note else self.label


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


def _line(ax: Axes, index: int, count: int, run: Drawn, x: npt.ArrayLike, y: Array) -> None:
    """``y`` over ``x`` in ``run``'s look, its markers offset from the other runs'."""
    step = max(len(y) // MARKS, count, 1)
    style: dict[str, Any] = run.look.kwargs()
    ax.plot(
        x,
        y,
        **style,
        markevery=(index % step, step),
        markersize=5,
        markerfacecolor="none" if index % 2 else run.look.colour,
        lw=1.4,
        zorder=2 + index,
        label=run.legend,
    )


def groups(arrays: Sequence[tuple[npt.NDArray[Any], ...]], rtol: float = 0.0) -> list[list[int]]:
    """Indices of ``arrays`` (one tuple per run) grouped by equality, in order: to the bit, or
    within ``rtol`` of each other (values computed the same way from different positions)."""
    out: list[list[int]] = []
    for i, a in enumerate(arrays):
        for g in out:
            if all(_equal(x, y, rtol) for x, y in zip(a, arrays[g[0]], strict=True)):
                g.append(i)
                break
        else:
            out.append([i])
    return out


def _equal(x: npt.NDArray[Any], y: npt.NDArray[Any], rtol: float) -> bool:
    if x.shape != y.shape:
        return False
    if rtol and x.dtype.kind == "f":
        return bool(np.allclose(x, y, rtol=rtol, atol=0.0, equal_nan=True))
    return bool(np.array_equal(x, y, equal_nan=x.dtype.kind == "f"))


def group_label(runs: Sequence[Drawn], group: Sequence[int], rtol: float = 0.0) -> str:
    """``every run`` when a group holds them all, else their labels; how equal they are."""
    how = "identical" if not rtol else f"equal within {rtol:g}"
    if len(group) == len(runs) > 1:
        return f"every run ({len(runs)}, {how})"
    names = ", ".join(runs[i].label for i in group)
    return f"{names} ({how})" if len(group) > 1 else names


def plot_errors(
    runs: Sequence[Drawn],
    errors: Sequence[tuple[Array, Array]],
    path: Path,
    marks: Sequence[tuple[int, str]] = (),
    keep_m: float | None = None,
    floor_m: float | None = None,
) -> Path:
    """Formation and shape error over epochs: ``errors`` of ``(formation (P,), shape (P,))`` [m].

    ``keep_m``: the keep threshold, ``floor_m``: the noise floor, drawn on the formation error.
    ``marks``: ``(epoch, text)`` drawn as vertical lines, the text starting with the change:
    vermillion where an agent goes out (``lost``, ``leave``, ``crash``), bluish green where it
    comes in; dashed when unplanned (``lost``, ``back``), dotted for the scenario's events.
    """
    fig = Figure(figsize=(9, 6.5), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True)
    for index, (run, (form, shape)) in enumerate(zip(runs, errors, strict=True)):
        _line(top, index, len(runs), run, np.arange(len(form)), form)
        _line(bottom, index, len(runs), run, np.arange(len(shape)), shape)
    _log_axis(top, [e[0] for e in errors])
    _log_axis(bottom, [e[1] for e in errors])
    if keep_m is not None:
        top.axhline(keep_m, color=THRESHOLD_COLOUR, ls="--", lw=1, label=f"keep: {keep_m:g} m")
    if floor_m is not None:
        top.axhline(
            floor_m, color=THRESHOLD_COLOUR, ls=":", lw=1, label=f"noise floor {floor_m:.2g} m"
        )
    top.set_ylabel("formation error [m]")
    top.set_title("RMS over edges of ||x_i − x_j|| − C_ij")
    bottom.set_ylabel("shape error [m]")
    bottom.set_xlabel("epoch")
    for epoch, text in marks:
        what = text.split()[0]
        color = LOSS_COLOUR if what in ("lost", "leave", "crash") else GAIN_COLOUR
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
    top.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
    return _save(fig, path)


MAX_DRAWN = 60
"""Agents (trajectories) or links (timeline rows) up to which each is drawn on its own."""


def _panels(count: int, width: float = 4.6) -> tuple[Figure, list[Axes]]:
    """A grid of ``count`` panels, at most three a row; spare cells hidden."""
    cols = min(3, max(count, 1))
    rows = -(-count // cols)
    fig = Figure(figsize=(max(width * cols, 6.4), width * rows + 0.6), layout="constrained")
    grid = list(np.atleast_1d(fig.subplots(rows, cols, squeeze=False).ravel()))
    for spare in grid[count:]:
        spare.set_visible(False)
    return fig, grid[:count]


def plot_trajectories(
    runs: Sequence[Drawn],
    positions: Sequence[Array],
    edges: npt.NDArray[np.int64],
    offsets: Array,
    leader: int,
    failed: npt.NDArray[np.bool_],
    epochs: Sequence[int],
    path: Path,
) -> Path:
    """One panel per run: the agents' paths, the formation at ``epochs``, the target shape at
    the last epoch (placed on the reference agent ``leader``) and the ``failed`` (m,) edges.

    positions : (P, n, d) per run [m]; offsets : (n, d) the shape ``d0`` [m]. A 3-D run is
    drawn projected on the x–y plane. Teams of more than :data:`MAX_DRAWN` agents get the
    aggregate view of :func:`_team_at_epochs`: their trajectories would be a smear.
    """
    if positions and positions[0].shape[1] > MAX_DRAWN:
        return _team_at_epochs(runs, positions, edges, leader, epochs, path)
    fig, axes = _panels(len(runs))
    shown = [k for k in epochs if positions and 0 <= k < len(positions[0])]
    for ax, run, x in zip(axes, runs, positions, strict=True):
        n = x.shape[1]
        colours = palette(n)
        for i in range(n):
            ax.plot(x[:, i, 0], x[:, i, 1], color=colours[i], lw=0.8, alpha=0.6)
        last = _last_finite(x)
        for order, k in enumerate(shown):
            if not np.isfinite(x[k]).all():
                continue
            final = k == shown[-1]
            shade = GREY if not final else run.look.colour
            _shape(ax, x[k], edges, shade, "-" if final else ":", f"k = {k}", 1.6 if final else 0.9)
            ax.scatter(
                x[k, :, 0],
                x[k, :, 1],
                c=colours,
                s=30 if final else 12,
                zorder=4 + order,
                edgecolors=BLACK,
                linewidths=0.4,
            )
        if last is not None:
            target = x[last, leader - 1] + (offsets - offsets[leader - 1])
            _shape(ax, target, edges, BLACK, "--", f"target at k = {last}", 0.8)
            down = edges[failed] - 1
            for a, b in down:
                seg = x[last, [a, b], :2]
                ax.plot(seg[:, 0], seg[:, 1], color=GREY, lw=3, ls=(0, (1, 1.5)))
                ax.plot(*seg.mean(axis=0), marker="X", color=BLACK, mec="white", ms=11, zorder=9)
            if len(down):
                ax.plot(
                    [],
                    [],
                    color=GREY,
                    lw=3,
                    ls=(0, (1, 1.5)),
                    marker="X",
                    mfc=BLACK,
                    mec="white",
                    ms=10,
                    label="link down",
                )
        title = run.label + (f"\n({run.note})" if run.note else "")
        ax.set_title(title, fontsize="medium", color=run.look.colour)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
    if axes:
        axes[0].legend(loc="best", fontsize="x-small")
    fig.suptitle("formation at chosen epochs, target shape dashed", fontsize="medium")
    return _save(fig, path)


def _last_finite(x: Array) -> int | None:
    whole = np.flatnonzero(np.isfinite(x).all(axis=(1, 2)))
    return int(whole[-1]) if whole.size else None


def _shape(
    ax: Axes, x: Array, edges: npt.NDArray[np.int64], colour: str, style: Any, label: str, lw: float
) -> None:
    """The formation's edges at positions ``x`` (n, d), one legend entry."""
    segments = np.stack([x[edges[:, 0] - 1, :2], x[edges[:, 1] - 1, :2]], axis=1)
    ax.add_collection(
        LineCollection(list(segments), colors=colour, linestyles=style, linewidths=lw, label=label)
    )


def _team_at_epochs(
    runs: Sequence[Drawn],
    positions: Sequence[Array],
    edges: npt.NDArray[np.int64],
    leader: int,
    epochs: Sequence[int],
    path: Path,
) -> Path:
    """A large team: its edges at ``epochs`` (one collection each) and the reference's path."""
    fig, axes = _panels(len(runs), width=5.0)
    shades = palette(max(len(epochs), 1))
    for ax, run, x in zip(axes, runs, positions, strict=True):
        for index, k in enumerate(epochs):
            if not 0 <= k < len(x):
                continue
            seen = np.isfinite(x[k]).all(axis=1)
            e = edges[seen[edges[:, 0] - 1] & seen[edges[:, 1] - 1]] - 1
            segments = np.stack([x[k, e[:, 0], :2], x[k, e[:, 1], :2]], axis=1)
            ax.add_collection(
                LineCollection(
                    list(segments), colors=shades[index], linewidths=0.3, label=f"k = {k}"
                )
            )
        ax.plot(
            x[:, leader - 1, 0], x[:, leader - 1, 1], color=BLACK, lw=1.2, label="reference agent"
        )
        ax.autoscale()
        ax.set_title(f"{run.label}: {x.shape[1]} agents", color=run.look.colour)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal", adjustable="datalim")
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


def _trace(err: Array) -> float:
    return float(np.trace(np.atleast_2d(np.cov(err, rowvar=False)))) if err.shape[0] > 1 else np.nan


def plot_covariance(
    runs: Sequence[Drawn], substitution: Sequence[Array], estimation: Sequence[Array], path: Path
) -> Path:
    """Substitution errors ``x̃ − x`` per run and estimation errors ``x̂ − x`` (once where the
    runs' are identical) with 2-σ ellipses; ``(N, d)`` and ``(M, d)`` per run [m]."""
    fig = Figure(figsize=(11, 5), layout="constrained")
    ax_sub, ax_est = fig.subplots(1, 2)
    none = []
    for run, err in zip(runs, substitution, strict=True):
        if err.shape[0] == 0:
            none.append(run.label)
            continue
        ax_sub.scatter(
            err[:, 0],
            err[:, 1],
            s=10,
            alpha=0.5,
            color=run.look.colour,
            marker=run.look.marker,
            label=f"{run.legend} (tr Σ = {_trace(err):.3g} m²)",
        )
        _ellipse(ax_sub, err, run.look.colour)
    if none:
        ax_sub.text(
            0.02,
            0.02,
            "no substitution: " + ", ".join(none),
            transform=ax_sub.transAxes,
            fontsize="x-small",
            va="bottom",
        )
    for group in groups([(e,) for e in estimation], SAME_ESTIMATE):
        err, first = estimation[group[0]], runs[group[0]]
        if err.shape[0] == 0:
            continue
        colour = BLACK if len(group) > 1 else first.look.colour
        ax_est.scatter(
            err[:, 0],
            err[:, 1],
            s=8,
            alpha=0.5,
            color=colour,
            label=f"{group_label(runs, group, SAME_ESTIMATE)}: tr Σ = {_trace(err):.3g} m²",
        )
        _ellipse(ax_est, err, colour)
    ax_sub.set_title("substitution error x̃_j − x_j (lost packets), 2σ ellipses")
    ax_est.set_title("estimation error x̂ − x (leader's BLUE)")
    for ax in (ax_sub, ax_est):
        ax.set_xlabel("error in x [m]")
        ax.set_ylabel("error in y [m]")
        ax.grid(True, alpha=0.3)
        if ax.collections:
            ax.legend(loc="best", fontsize="x-small")
        else:
            ax.text(0.5, 0.5, "none recorded", transform=ax.transAxes, ha="center", va="center")
    return _save(fig, path)


def plot_nees(runs: Sequence[Drawn], values: Sequence[Array], d: int, path: Path) -> Path:
    """NEES per scored agent and epoch, once per distinct set of values, against χ²_d.

    Left: the histogram and the χ²_d density with its 95 % interval; right: the running mean
    and the 95 % band of the mean of ``N`` independent χ²_d values (χ²_{Nd} / N).
    """
    fig = Figure(figsize=(11, 4.5), layout="constrained")
    ax_hist, ax_mean = fig.subplots(1, 2)
    longest = 0
    for group in groups([(v,) for v in values], SAME_ESTIMATE):
        v, first = values[group[0]], runs[group[0]]
        if v.size == 0:
            continue
        colour = BLACK if len(group) > 1 else first.look.colour
        label = f"{group_label(runs, group, SAME_ESTIMATE)}: mean {v.mean():.3g}"
        ax_hist.hist(v, bins=40, histtype="step", density=True, color=colour, label=label)
        ax_mean.plot(np.cumsum(v) / np.arange(1, v.size + 1), color=colour, label=label)
        longest = max(longest, v.size)
    lo, hi = chi2.ppf([0.025, 0.975], d)
    grid = np.linspace(1e-3, max(hi * 1.5, 1.0), 200)
    ax_hist.plot(grid, chi2.pdf(grid, d), color=GREY, lw=1.5, label=f"χ²_{d} density")
    ax_hist.axvspan(lo, hi, color=GREY, alpha=0.12, label=f"χ²_{d} 95 %: {lo:.2g}–{hi:.2g}")
    if longest:
        count = np.arange(1, longest + 1)
        band = chi2.ppf([[0.025], [0.975]], count * d) / count
        ax_mean.fill_between(
            count - 1, band[0], band[1], color=GREY, alpha=0.2, label="95 % band of the mean"
        )
    ax_mean.axhline(d, color=GREY, ls="--", lw=1, label=f"expected: d = {d}")
    ax_hist.set_xlabel("NEES (dimensionless)")
    ax_hist.set_ylabel("density")
    ax_hist.set_title(f"NEES of each agent's position estimate (d = {d} coordinates)")
    ax_mean.set_xlabel("sample (agent and epoch)")
    ax_mean.set_ylabel("running mean of NEES")
    ax_mean.set_title("running mean, and an honest estimator's 95 % band")
    for ax in (ax_hist, ax_mean):
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="x-small")
    return _save(fig, path)


def plot_queue_depths(runs: Sequence[tuple[Drawn, dict[str, Any]]], path: Path) -> Path:
    """Each capacity queue's depth over the run: the largest a packet found per epoch.

    ``runs``: (run, the summary's ``queues``: name → ``max_depth_by_epoch``, epoch → depth).
    """
    fig = Figure(figsize=(11, 3.8), layout="constrained")
    ax = fig.subplots()
    styles = ("-", "--", ":", "-.")
    for run, queues in runs:
        for q_index, (name, q) in enumerate(queues.items()):
            series = q["max_depth_by_epoch"]
            epochs = np.array([int(k) for k in series], dtype=float)
            ax.step(
                epochs,
                list(series.values()),
                where="post",
                label=f"{run.label}: {name}",
                lw=1,
                color=run.look.colour,
                ls=styles[q_index % len(styles)],
            )
    ax.set_xlabel("epoch")
    ax.set_ylabel("depth [packets]")
    ax.grid(True, alpha=0.3)
    if ax.has_data():
        ax.legend(loc="best", fontsize="x-small")
    return _save(fig, path)


__all__ = [
    "MAX_DRAWN",
    "Drawn",
    "group_label",
    "groups",
    "plot_covariance",
    "plot_errors",
    "plot_nees",
    "plot_queue_depths",
    "plot_trajectories",
]
