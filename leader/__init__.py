"""The leader service: each epoch's Kruskal forest, BLUE and rigidity check (docs/model.md §4–§5).

``python -m leader`` runs it over Zenoh (:mod:`leader.node`); the testbed's simulator runs
:class:`Leader` over a batch of seeds, with :class:`HealthyRigidity` when it wants the rank.
The benchmarks time :func:`minimum_spanning_forest` and :func:`blue` alone, clearing the
symbolic factorisations' cache between rounds (:func:`clear_cache`).
"""

from leader.epoch import Leader, LeaderEpochs
from leader.estimation import BlueResult, blue
from leader.mst import minimum_spanning_forest
from leader.rigidity import HealthyRigidity
from leader.symbolic import clear_cache

__all__ = [
    "BlueResult",
    "HealthyRigidity",
    "Leader",
    "LeaderEpochs",
    "blue",
    "clear_cache",
    "minimum_spanning_forest",
]
