"""Plug-ins: what the registry costs the built-ins, and a user's strategy against ``hold``.

1. The batched simulator (``run_batch``, the sweep's core) with ``hold`` and ``estimate`` as
   they run now, through the registry and its checked calls (``fill_checked``,
   ``command_checked``), against the same with those calls made directly (no shape or
   finiteness checks): the ratio is what the registry's checks cost. Baseline: the direct
   calls, same run.
2. The example package's ``extrapolate`` (examples/formation-plugins-example, installed by
   ``make bench``) against ``hold``, cells per second of the batched sweep, same run.

Seed 1 (the members' seeds 1..B); 30 % Bernoulli loss on every link. Each figure is the best
of 5 alternating rounds of this process's CPU time (``time.process_time``): on a shared 2-core
machine wall time swings by ±30 % with the neighbours' load, CPU time far less.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import importlib

from formation.scenario import Scenario
from testbed.sim.batch import plan_batch, run_batch

ROOT = Path(__file__).resolve().parents[1]
SEED = 1
MEMBERS = 16
LOSS = {"formation_default": [{"model": "bernoulli", "p_loss": 0.3}]}


@contextmanager
def unchecked() -> Iterator[None]:
    """The plug-ins called directly, without the checks of their answers (the baseline)."""

    def fill(name: str, strategy: Any, inputs: Any, params: Any, receivers: Any) -> Any:
        return strategy.fill(inputs, params)

    def command(name: str, law: Any, inputs: Any, params: Any, agents: Any, epoch: int) -> Any:
        return law.command(inputs, params)

    # The one place a benchmark reaches inside a service: it swaps the checked calls themselves.
    strategies = importlib.import_module("agent.strategies")
    epoch = importlib.import_module("agent.epoch")
    saved = strategies.fill_checked, epoch.command_checked
    strategies.fill_checked, epoch.command_checked = fill, command
    try:
        yield
    finally:
        strategies.fill_checked, epoch.command_checked = saved


def cells_per_s(scenario: Scenario, strategy: str, repeats: int = 3) -> float:
    """Best of ``repeats``: runs (cells) of the batch per second, detail off as in a sweep."""
    plan = plan_batch(scenario, list(range(SEED, SEED + MEMBERS)))
    best = float("inf")
    for _ in range(repeats):
        start = time.process_time()
        run_batch(plan, strategy, detail=False)
        best = min(best, time.process_time() - start)
    return MEMBERS / best


def interleaved(
    a: Callable[[], float], b: Callable[[], float], rounds: int = 3
) -> tuple[float, float]:
    """The best of ``a`` and of ``b`` over alternating rounds (a slow spell hits both)."""
    ra, rb = 0.0, 0.0
    for _ in range(rounds):
        ra, rb = max(ra, a()), max(rb, b())
    return ra, rb


def main() -> None:
    teams = [
        ("paper, 5 agents", Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(epochs=200, network=LOSS)),
        ("grid20, 20 agents", Scenario.from_file(ROOT / "scenarios/grid20.toml").with_overrides(epochs=100, network=LOSS)),
    ]  # fmt: skip
    print(
        f"{MEMBERS} members (seeds {SEED}..{SEED + MEMBERS - 1}), 30 % Bernoulli loss, best of 5 (CPU time)"
    )
    print("\n1. the registry's checked calls against direct calls (baseline), cells/s")
    print(f"{'team':<20} {'strategy':<10} {'direct':>9} {'checked':>9} {'ratio':>7}")
    for label, scenario in teams:
        for strategy in ("hold", "estimate"):

            def direct(s: Scenario = scenario, st: str = strategy) -> float:
                with unchecked():
                    return cells_per_s(s, st, 1)

            base, checked = interleaved(
                direct, lambda s=scenario, st=strategy: cells_per_s(s, st, 1)
            )
            print(f"{label:<20} {strategy:<10} {base:9.1f} {checked:9.1f} {checked / base:7.3f}")
    print("\n2. the example's extrapolate against hold (baseline), cells/s")
    print(f"{'team':<20} {'hold':>9} {'extrapolate':>12} {'ratio':>7}")
    for label, scenario in teams:
        hold, extra = interleaved(
            lambda s=scenario: cells_per_s(s, "hold", 1),
            lambda s=scenario: cells_per_s(s, "extrapolate", 1),
        )
        print(f"{label:<20} {hold:9.1f} {extra:12.1f} {extra / hold:7.3f}")


if __name__ == "__main__":
    main()
