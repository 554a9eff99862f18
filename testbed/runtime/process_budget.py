"""How many agent processes a realtime run can afford on this machine (issue 18 item 3).

Every agent process wakes several times per epoch (publish, two deadlines), and a wake-up
that finds the cores busy comes late: the packet is then a deadline miss of the testbed's
own making. On 2 cores at 20 Hz, 5 agent processes missed none and 20 missed 1.2–1.9 %
(issue 18's figures), so the budget is :data:`PROCESSES_PER_CORE_AT_10HZ` agent processes
per core at 10 epochs/s, in proportion to the period. A pool steps all its agents at once
(agent/node.py), so fewer, larger pools cost little. Since session 12 (receivers decide as
soon as nothing more can come, Zenoh's shared memory off) 20 processes at 20 Hz and 50 at
10 Hz missed 0.01-0.02 %, but 50 at 20 Hz and 20 at 50 Hz missed nearly everything: the
budget keeps its margin below that cliff.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

PROCESSES_PER_CORE_AT_10HZ = 5.0
# netem forwards each realtime packet in Python: past about this many per second and core
# it falls behind, whatever the pools (bench_realtime, seed 1, 2 cores, session 12: 100 agents
# at 10 Hz, ~5,900 packets/s, missed 0.00 %; 200 at 10 Hz, ~11,900/s, 1.0 %; 100 at 20 Hz 32 %)
NETEM_PACKETS_PER_CORE_S = 4000.0


@dataclass(frozen=True)
class Layout:
    """``pools``: agent processes (None: one per agent, the launcher's default); ``why``."""

    pools: int | None
    why: str


def realtime_layout(
    n: int, period_s: float, cores: int | None = None, packets_per_epoch: int = 0
) -> Layout:
    """The layout for ``n`` agents at one epoch per ``period_s`` on ``cores`` (os.cpu_count()).

    ``packets_per_epoch``: what netem forwards in one (states on every directed link, a
    report and an estimate per agent); above netem's budget ``why`` says to expect misses.
    """
    cores = cores or os.cpu_count() or 1
    budget = max(1, int(cores * PROCESSES_PER_CORE_AT_10HZ * period_s / 0.1))
    rule = (
        f"{cores} cores, {n} agents, {1 / period_s:g} epochs/s: at most {budget} agent "
        f"processes ({PROCESSES_PER_CORE_AT_10HZ:g} per core at 10 epochs/s)"
    )
    rate = packets_per_epoch / period_s
    if rate > NETEM_PACKETS_PER_CORE_S * cores:
        rule += (
            f"; warning: netem would forward {rate:,.0f} packets/s, above the "
            f"{NETEM_PACKETS_PER_CORE_S * cores:,.0f} it keeps up with here: expect deadline "
            "misses (a longer period or a smaller team)"
        )
    if n <= budget:
        return Layout(None, f"one process per agent ({rule})")
    size = -(-n // budget)  # ceil
    return Layout(budget, f"{budget} pools of up to {size} agents ({rule})")
