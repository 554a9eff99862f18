"""The leader service: each epoch's Kruskal forest, BLUE and rigidity check (docs/model.md §4–§5).

``python -m leader`` runs it over Zenoh (:mod:`leader.node`); the testbed's simulator runs
:class:`Leader` over a batch of seeds, with :class:`HealthyRigidity` when it wants the rank.
"""

from leader.epoch import Leader, LeaderEpochs
from leader.rigidity import HealthyRigidity

__all__ = [
    "HealthyRigidity",
    "Leader",
    "LeaderEpochs",
]
