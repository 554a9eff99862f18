"""The ``formation`` command's parser: quick to start, every argument explained, every table in units."""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
from pathlib import Path

import pytest
from rich.console import Console

from formation.scenario import Scenario
from testbed.cli import build_parser
from testbed.cli.commands import COMMANDS
from testbed.cli.recorder import INFO_COLUMNS, LINK_COLUMNS
from testbed.cli.run import REALTIME_COLUMNS, RUN_COLUMNS
from testbed.cli.tables import LABELS, SUMMARY_COLUMNS, print_summaries
from testbed.sim.simulate import simulate

HEAVY = ("numpy", "scipy", "zenoh", "pandas", "matplotlib", "pydantic")


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def test_help_imports_no_numerics_nor_network(tmp_path: Path) -> None:
    code = (
        "import json, sys\n"
        "from testbed.cli import main\n"
        "code = main(['--help'])\n"
        f"print(json.dumps([code, [m for m in {HEAVY!r} if m in sys.modules]]))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout.splitlines()[-1]) == [0, []]
    assert "simulate" in proc.stdout and "scenarios" in proc.stdout


def test_each_command_s_help_imports_no_numerics_nor_network(tmp_path: Path) -> None:
    light = list(COMMANDS)  # replay and ros2-plant too: their Zenoh flags load no Zenoh
    code = (
        "import contextlib, io, json, sys\n"
        "from testbed.cli import main\n"
        "out = []\n"
        f"for name in {light!r}:\n"
        "    with contextlib.redirect_stdout(io.StringIO()) as text:\n"
        "        code = main([name, '--help'])\n"
        "    said = text.getvalue()\n"
        f"    out.append([name, code, 'examples:' in said, [m for m in {HEAVY!r} if m in sys.modules]])\n"
        "print(json.dumps(out))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    # one interpreter for all: the first command that loads a heavy module is named
    assert json.loads(proc.stdout.splitlines()[-1]) == [[name, 0, True, []] for name in light]


def test_the_value_experiment_s_epochs_in_its_help_are_its_own() -> None:
    from testbed.cli.experiment import VALUE_EPOCHS
    from testbed.experiments.value import EPOCHS

    assert VALUE_EPOCHS == EPOCHS


@pytest.mark.parametrize("name", list(COMMANDS))
def test_every_argument_has_help_and_every_command_examples(name: str) -> None:
    sub = _subparsers(build_parser(name))[name]
    missing = [
        a.dest
        for a in sub._actions
        if not isinstance(a, argparse._HelpAction) and not (a.help and a.help.strip())
    ]
    assert missing == [], f"formation {name}: arguments without help: {missing}"
    assert sub.epilog and sub.epilog.startswith("examples:\n  formation ")
    assert f"formation {name}" in sub.epilog


def test_the_listing_says_what_each_command_registers() -> None:
    full = build_parser(every=True)
    (sub,) = (a for a in full._actions if isinstance(a, argparse._SubParsersAction))
    registered = {a.dest: a.help for a in sub._choices_actions}
    assert registered == {name: c.summary for name, c in COMMANDS.items()}


def test_one_command_imports_its_own_module_only() -> None:
    code = (
        "import sys\n"
        "from testbed.cli import build_parser\n"
        "build_parser('scenarios')\n"
        "print(sorted(m for m in sys.modules if m.startswith('testbed.cli.')))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert proc.stdout.strip() == "['testbed.cli.commands', 'testbed.cli.scenarios']"


@pytest.mark.parametrize(
    "columns",
    [SUMMARY_COLUMNS, RUN_COLUMNS + REALTIME_COLUMNS, INFO_COLUMNS, LINK_COLUMNS],
    ids=["simulate", "run", "info-channels", "info-links"],
)
def test_every_number_column_names_its_unit(columns: tuple[str, ...]) -> None:
    no_unit = [c for c in columns if c not in LABELS and not c.rstrip().endswith("]")]
    assert no_unit == []


def test_the_printed_summary_shows_every_unit() -> None:
    scenario = Scenario.from_file("paper").with_overrides(epochs=3)
    out = io.StringIO()
    summary = simulate(scenario, strategy="estimate", seed=1).summary()
    print_summaries([summary], "units", Console(file=out, width=300))
    units = {c[c.rindex("[") :] for c in SUMMARY_COLUMNS if c not in LABELS}
    assert units == {"[m]", "[m²]", "[pkts]", "[-]", "[#]"}
    assert [u for u in units if u not in out.getvalue()] == []
