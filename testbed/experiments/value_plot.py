"""The headline figure of ``formation experiment value``: every strategy's error per case.

Grouped bars, one panel per controller, one colour per strategy (``recorder.look``,
as in every figure: Okabe–Ito, safe for the common colour-vision deficiencies), the bar the mean over the seeds and
its whisker the standard deviation, on a log axis. A bar equal to an earlier one of its case in
every seed, bit for bit, is hatched and says so; a strategy that diverged is marked at the top;
the cases where estimate pays, and where drop is better, are named over their bars.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from recorder import look
from testbed.experiments.value_report import Row, verdict

VERDICTS = {"pays": "estimate\npays", "worse": "drop\nbetter"}  # the regions named over a case
_META = {"Software": None}  # no version string in the file: same inputs, same bytes


def plot_value_map(
    rows: Sequence[Row],
    strategies: Sequence[str],
    controllers: Sequence[str],
    keep_m: float,
    path: Path,
) -> Path:
    """Mean judged final error [m] per case (x), strategy (bar) and controller (panel)."""
    cases = list(dict.fromkeys(r.case for r in rows))
    fig = Figure(figsize=(15, 4.2 * len(controllers)), layout="constrained")
    axes = fig.subplots(len(controllers), 1, sharex=True, squeeze=False)[:, 0]
    width = 0.8 / len(strategies)
    top = 10.0
    for ax, controller in zip(axes, controllers, strict=True):
        mine = {r.case: r for r in rows if r.controller == controller}
        for k, s in enumerate(strategies):
            x = np.arange(len(cases)) + (k - (len(strategies) - 1) / 2) * width
            colour = look(s).colour
            for i, case in enumerate(cases):
                e = mine[case].errors[s]
                finite = e[np.isfinite(e)]
                if finite.size < e.size:
                    ax.plot(x[i], top * 0.7, "x", color=colour, ms=6)
                if not finite.size:
                    continue
                same = _equal_to_earlier(mine[case], s, strategies)
                ax.bar(
                    x[i],
                    np.mean(finite),
                    width,
                    yerr=np.std(finite),
                    color=colour,
                    hatch="////" if same else None,
                    edgecolor="white" if same else colour,
                    error_kw={"lw": 0.6, "ecolor": "0.3"},
                    label=s if i == 0 else None,
                )
        for i, case in enumerate(cases):
            said = VERDICTS.get(verdict(mine[case]))
            if said:
                ax.text(i, top * 0.25, said, ha="center", fontsize=7, weight="bold")
        ax.axhline(keep_m, color="0.4", lw=0.8, ls="--")
        ax.set_yscale("log")
        ax.set_ylim(1e-3, top)
        ax.set_ylabel("final error [m]")
        ax.set_title(
            f"{controller}: mean ± std over the seeds; dashed: kept below {keep_m:g} m; "
            "×: diverged; hatched: equal to an earlier strategy of the case, bit for bit",
            fontsize=9,
        )
    axes[0].legend(ncols=len(strategies), fontsize=8, loc="upper left")
    axes[-1].set_xticks(np.arange(len(cases)), cases, rotation=30, ha="right", fontsize=8)
    fig.savefig(path, dpi=100, metadata=_META)
    return path


def _equal_to_earlier(row: Row, strategy: str, strategies: Sequence[str]) -> bool:
    earlier = strategies[: list(strategies).index(strategy)]
    mine = row.errors[strategy].tobytes()
    return any(row.errors[s].tobytes() == mine for s in earlier)


__all__ = ["plot_value_map"]
