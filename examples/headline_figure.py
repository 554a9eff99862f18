"""The README's headline figure: the chapter's experiment, formation error per strategy.

python examples/headline_figure.py docs/images/headline.png   (make figures)

Each strategy fills the lost coordination variables of the failed link 1-2 its own way; the
figure shows which of them keep the formation. Lines that coincide are named together in the
legend, so no strategy hides under another.
"""

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import testbed
from recorder import look

STRATEGIES = ("zero", "hold", "estimate", "blend", "drop")

scenario = testbed.load_scenario("paper")
errors = {
    name: testbed.simulate(scenario, strategy=name, seed=1).frames().metrics for name in STRATEGIES
}
fig, ax = plt.subplots(figsize=(7.5, 3.6), layout="constrained")
drawn: list[str] = []
for name in STRATEGIES:
    same = [
        d
        for d in drawn
        if np.array_equal(errors[d].formation_error_m, errors[name].formation_error_m)
    ]
    drawn.append(name)
    if same:  # drawn already: name it with the line it lies under
        line = next(ln for ln in ax.lines if ln.get_label().startswith(same[0]))
        line.set_label(f"{line.get_label()} = {name} (identical)")
        continue
    metrics = errors[name]
    ax.plot(  # each strategy's one look, as in every report (colour-blind safe)
        metrics.epoch,
        metrics.formation_error_m,
        **look(name).kwargs(),
        markevery=5,
        lw=2,
        label=name,
    )
ax.set_yscale("log")
ax.set(
    xlabel=f"epoch (one per {scenario.control.period_s:g} s)",
    ylabel="formation error [m]",
    title=f"{scenario.name}: link 1-2 fails at epoch 1; which fallback keeps the formation?",
)
ax.grid(True, which="major", alpha=0.3)
ax.legend(title="strategy", loc="best", fontsize=9)
fig.savefig(sys.argv[1] if len(sys.argv) > 1 else "headline.png", dpi=110)
