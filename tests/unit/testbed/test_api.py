"""``testbed``'s root is the user's scripting API (docs/api.md): a promise, as httpx's ``__all__``.

Its names are the ones docs/api.md describes, each resolves, ``import testbed`` and a whole
simulation load no network stack, and README.md's notebook runs as written.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import testbed

ROOT = Path(__file__).resolve().parents[3]
NETWORK_STACK = ("zenoh", "foxglove", "mcap", "google.protobuf")


def _documented() -> list[str]:
    """The first column of docs/api.md's table: `name(args)` or `Name`."""
    rows = re.findall(r"^\| `(\w+)[^`]*` \|", (ROOT / "docs/api.md").read_text(), re.M)
    return rows


def _python(code: str, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        env={**os.environ, "MPLBACKEND": "Agg", **env},
        capture_output=True,
        text=True,
        timeout=240,
    )


def test_all_is_what_the_docs_promise() -> None:
    documented = _documented()
    assert len(documented) == len(set(documented)), "docs/api.md lists a name twice"
    assert sorted(documented) == sorted(testbed.__all__)
    order = sorted(testbed.__all__, key=lambda n: (0 if n[0].isupper() else 1, n))
    assert testbed.__all__ == order  # as ruff's RUF022 sorts


@pytest.mark.parametrize("name", testbed.__all__)
def test_every_name_resolves(name: str) -> None:
    assert getattr(testbed, name) is not None


def test_an_unknown_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="module 'testbed' has no attribute 'simulat'"):
        testbed.simulat  # noqa: B018


def test_a_simulation_loads_no_network_stack() -> None:
    code = f"""
import sys, testbed
loaded = [m for m in {NETWORK_STACK!r} if m in sys.modules]
assert not loaded, f"import testbed loaded {{loaded}}"
run = testbed.simulate(testbed.load_scenario("scenarios/paper.toml"), strategy="hold", epochs=8)
frames = run.frames()
assert len(frames.metrics) == 9, len(frames.metrics)
print(sorted(m for m in {NETWORK_STACK!r} if m in sys.modules))
"""
    done = _python(code)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_the_readme_notebook_runs_as_written(tmp_path: Path) -> None:
    readme = (ROOT / "README.md").read_text()
    section = readme.split("## Scripting", 1)[1]
    notebook = re.search(r"```python\n(.*?)```", section, re.S)
    assert notebook, "README.md's Scripting section has no python block"
    lines = [line for line in notebook.group(1).splitlines() if line and not line.startswith("#")]
    assert len(lines) <= 6, lines  # an import and five lines
    figure = tmp_path / "notebook.png"
    check = f"""
import matplotlib.pyplot as plt
(axes,) = plt.gcf().axes
assert len(axes.lines) == 1 and len(axes.lines[0].get_xdata()) > 1
plt.savefig({str(figure)!r})
"""
    done = _python(notebook.group(1) + check)
    assert done.returncode == 0, done.stderr
    assert figure.stat().st_size > 0
