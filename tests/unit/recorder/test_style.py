"""One look per strategy, the same in every figure of the project, and none hidden under another."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.figure import Figure

from recorder.reporting import plots
from recorder.reporting.report import write_report_from
from recorder.reporting.style import CHAPTER_LOOKS, look
from testbed.experiments import plots as experiment_plots

OKABE_ITO = {"#000000", "#E69F00", "#56B4E9", "#009E73", "#F0E442", "#0072B2", "#D55E00", "#CC79A7"}


def test_each_chapter_strategy_has_its_own_colour_line_and_marker() -> None:
    looks = list(CHAPTER_LOOKS.values())
    assert len({x.colour for x in looks}) == len({x.marker for x in looks}) == len(looks) == 5
    assert len({(x.line, x.marker) for x in looks}) == 5
    assert {x.colour for x in looks} <= OKABE_ITO


def test_a_plug_in_s_look_is_the_same_in_every_process() -> None:
    code = (
        "import json; from recorder.reporting.style import look; "
        "print(json.dumps([list(vars(look(n)).values()) for n in ('extrapolate', 'mine')]))"
    )
    seen = []
    for seed in ("1", "2"):  # hash() of a string changes with the seed; the look must not
        env = {**os.environ, "PYTHONHASHSEED": seed}
        out = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
        )
        seen.append(json.loads(out.stdout))
    here = [list(vars(look(n)).values()) for n in ("extrapolate", "mine")]
    assert seen == [here, here]
    assert look("extrapolate").colour in OKABE_ITO


def _styles(fig: Figure) -> dict[str, tuple[str, str, str]]:
    """label's first word → (colour, line style, marker) of every labelled line."""
    out = {}
    for ax in fig.axes:
        for line in ax.get_lines():
            name = str(line.get_label()).split(" ")[0]
            if name in CHAPTER_LOOKS:
                out[name] = (
                    str(line.get_color()),
                    str(line.get_linestyle()),
                    str(line.get_marker()),
                )
    return out


def test_every_figure_draws_a_strategy_in_its_look_and_none_hidden(
    sim_results: dict[str, Any], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from testbed.sim.simulate import simulate

    figures: dict[str, Figure] = {}

    def keep(module: Any) -> Any:
        saved = module._save

        def save(fig: Figure, path: Path) -> Path:
            figures[f"{module.__name__}:{path.name}"] = fig
            return saved(fig, path)

        return save

    monkeypatch.setattr(plots, "_save", keep(plots))
    monkeypatch.setattr(experiment_plots, "_save", keep(experiment_plots))
    s = sim_results["estimate"].scenario
    runs = [r.record() for r in sim_results.values()] + [simulate(s, "blend").record()]
    write_report_from(runs, tmp_path)  # hold, estimate and blend: blend moves as estimate does
    series = {s: np.abs(np.random.default_rng(1).normal(size=(20, 3))) for s in CHAPTER_LOOKS}
    experiment_plots.plot_error_bands(series, tmp_path / "bands.png", "t", "error [m]")
    experiment_plots.plot_covariance_over_epochs(
        {s: v[:, 0] for s, v in series.items()}, tmp_path / "c.png", "t"
    )
    experiment_plots.plot_dynamic(series, np.full(20, 4.0), 5, 10, tmp_path / "d.png", "t")
    drawn = {name: _styles(fig) for name, fig in figures.items()}
    for name in ("recorder.reporting.plots:errors.png", "testbed.experiments.plots:bands.png",
                 "testbed.experiments.plots:c.png", "testbed.experiments.plots:d.png"):  # fmt: skip
        assert drawn[name], name
        for strategy, style in drawn[name].items():
            x = look(strategy)
            assert style == (x.colour, x.line, x.marker), (name, strategy)

    top = figures["recorder.reporting.plots:errors.png"].axes[0]
    lines = {str(ln.get_label()): ln for ln in top.get_lines()}
    estimate, blend = lines["estimate"], lines["blend (identical to estimate)"]
    assert np.array_equal(estimate.get_ydata(), blend.get_ydata())
    assert blend.get_zorder() > estimate.get_zorder()  # on top, dashed, its markers elsewhere
    assert blend.get_linestyle() == "--"
    assert estimate.get_markevery()[0] != blend.get_markevery()[0]
