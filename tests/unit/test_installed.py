"""The tests run against the installed product, not the checkout (``make test``).

``make test`` installs the packages non-editable and sets ``PYTHONSAFEPATH=1``: without it a
``python -m <service>`` started in the checkout, as the launcher starts the services, puts
the checkout first on its path and runs the working tree. An editable install fails here too.
"""

from __future__ import annotations

import importlib
import os
import re
import sysconfig
from pathlib import Path

import pytest

from testbed.runtime.processes import ProcessGroup

ROOT = Path(__file__).resolve().parents[2]
SITE = Path(sysconfig.get_paths()["purelib"]).resolve()
PACKAGES = (
    "formation",
    "shell",
    "body",
    "analysis",
    "agent",
    "leader",
    "netem",
    "recorder",
    "testbed",
)
HINT = "run the tests with `make test`: it installs the product (not editable) for them"


def from_site_packages(path: Path, package: str) -> bool:
    path = path.resolve()
    return path.is_relative_to(SITE / package) and not path.is_relative_to(ROOT / package)


@pytest.mark.parametrize("package", PACKAGES)
def test_the_tests_import_the_installed_package(package: str) -> None:
    origin = Path(str(importlib.import_module(package).__file__))
    assert from_site_packages(origin, package), f"{package} from {origin}, not {SITE}; {HINT}"


def test_a_service_started_as_the_launcher_starts_it_runs_the_installed_package(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``python -m agent --help`` through the launcher's :class:`ProcessGroup`, in the
    checkout; ``PYTHONVERBOSE`` makes it log the file of every module it imports."""
    monkeypatch.chdir(ROOT)
    group = ProcessGroup(tmp_path)
    child = group.start("agent", "agent", "--help", env={"PYTHONVERBOSE": "1"})
    try:
        assert child.proc.wait(timeout=60) == 0, child.tail()
    finally:
        group.stop_all()
    log = child.log_path.read_text(errors="replace")
    loaded = re.findall(r"^# code object from '?([^'\n]+)'?$", log, flags=re.M)
    agent = [Path(p) for p in loaded if f"{os.sep}agent{os.sep}" in p]
    assert agent, f"no agent module in the child's import log:\n{log[-2000:]}"
    wrong = [str(p) for p in agent if not from_site_packages(p, "agent")]
    assert not wrong, f"the child imported {wrong}, not {SITE / 'agent'}; {HINT}"
