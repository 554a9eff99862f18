"""The simulator computes its metrics with the analysis package, below the services: importing
it loads no network, recording or visualisation library."""

from __future__ import annotations

import json
import subprocess
import sys

HEAVY = ("zenoh", "foxglove", "mcap", "google.protobuf", "pandas", "matplotlib")


def test_importing_the_simulator_loads_no_zenoh_foxglove_mcap_or_protobuf() -> None:
    code = (
        "import json, sys, testbed.sim.simulate; "
        f"print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == []
