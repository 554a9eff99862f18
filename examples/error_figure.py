"""The report's error figure (formation and shape error per epoch) from ``recorder.load_run``.

python examples/error_figure.py runs/<run_id>/run.mcap errors.png
"""

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from testbed import load_run

run = load_run(sys.argv[1])
ax = run.metrics.plot(x="epoch", y=["formation_error_m", "shape_error_m"], logy=True, grid=True)
ax.set(xlabel="epoch", ylabel="error [m]", title=f"{run.scenario.name}: formation and shape error")
drops = run.decisions.query("link_class == 'formation' and not on_time").groupby("link").size()
print("formation packets lost per link:", drops.to_dict())
print(run.skipped.describe())
plt.savefig(sys.argv[2] if len(sys.argv) > 2 else "errors.png", dpi=120)
