"""examples/walkthrough.ipynb runs as written, top to bottom, in a Jupyter kernel (nbclient):
it loads, simulates, compares, records a real run over Zenoh on 127.0.0.1 and plots."""

from __future__ import annotations

from pathlib import Path

import nbclient
import nbformat
import pytest

pytestmark = [pytest.mark.integration, pytest.mark.slow]

NOTEBOOK = Path(__file__).resolve().parents[2] / "examples" / "walkthrough.ipynb"


def test_the_walkthrough_runs_and_its_recording_equals_the_simulation(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("TMPDIR", str(tmp_path))  # the kernel inherits it: the recording goes there
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(
        notebook,
        timeout=240,  # per cell: the recorded run starts a router, netem, a leader, 5 agents
        kernel_name="python3",
        record_timing=False,
        resources={"metadata": {"path": str(NOTEBOOK.parent)}},
    )
    client.execute()  # a failing cell raises CellExecutionError with its traceback
    code = [cell for cell in notebook.cells if cell.cell_type == "code"]
    checks = [cell for cell in code if "np.array_equal" in cell.source]
    assert len(checks) == 2  # estimate = blend; the recording = the simulation
    for cell in checks:
        (result,) = [o for o in cell.outputs if o.output_type == "execute_result"]
        assert result["data"]["text/plain"] == "True", cell.source
    plots = [o for o in code[-1].outputs if "image/png" in o.get("data", {})]
    assert len(plots) == 1
    assert len(list(tmp_path.glob("walkthrough-*/*/run.mcap"))) == 1
