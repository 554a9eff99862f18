"""The leader's epoch (docs/model.md §4–§5): healthy edges → Kruskal forest → BLUE → rigidity rank.

:class:`Leader` checks a scenario's graphs once; :meth:`Leader.epochs` then runs an
epoch for ``B`` independent runs of it at once. The batch simulator
(``testbed.sim.batch``) passes its seeds, the leader process (``leader.node``) a
batch of one. Every run of a batch gets the floats it gets alone, so the leader
process, the simulator and the batch agree bit for bit. :func:`leader_epoch` is
one run's epoch with its rigidity, as a :class:`LeaderEpoch`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from formation.scenario import Scenario
from leader.dense import DENSE_MAX_AGENTS
from leader.estimation import BlueBatch, BlueResult, MeasurementGraph, Solver
from leader.mst import KruskalGraph
from leader.rigidity import HealthyRigidity

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]


@dataclass(frozen=True)
class LeaderEpoch:
    """What the leader knows after epoch ``k``.

    healthy, tree : (m,) per formation edge; components : forest components
    estimate : the BLUE (positions (n, d), covariances (n, d, d), observable (n,))
    rigidity_rank : rank of the healthy subgraph on the shape ``d0`` (−1 where only rigid or
    not was known: large redundant formations, leader.rigidity); rigid : whether it is full
    """

    healthy: Mask
    tree: Mask
    components: int
    estimate: BlueResult
    rigidity_rank: int
    rigid: bool


@dataclass(frozen=True)
class LeaderEpochs:
    """What the leader knows after epoch ``k`` in each of ``B`` runs; axis 0 is the run.

    healthy, tree : (B, m) per formation edge; components : (B,) forest components
    estimate : the BLUE of every run (positions (B, n, d), covariances (B, n, d, d) or None,
    observable (B, n))
    rigidity_rank, rigid : (B,), or None when no rigidity tracker was given
    """

    healthy: Mask
    tree: Mask
    components: Ints
    estimate: BlueBatch
    rigidity_rank: Ints | None
    rigid: Mask | None

    def member(self, b: int) -> LeaderEpoch:
        """Run ``b`` as one leader epoch (needs the rigidity)."""
        if self.rigidity_rank is None or self.rigid is None:
            raise ValueError("member(): these epochs were computed without a rigidity tracker")
        return LeaderEpoch(
            healthy=self.healthy[b],
            tree=self.tree[b],
            components=int(self.components[b]),
            estimate=self.estimate.member(b),
            rigidity_rank=int(self.rigidity_rank[b]),
            rigid=bool(self.rigid[b]),
        )


class Leader:
    """The leader's epoch for one scenario, its graphs checked once, run epoch after epoch.

    Parameters
    ----------
    scenario : the runs' scenario; ``scenario.directed_links[l] = (j, i)`` is link ``j → i``
    rigidity : the scenario's rigidity tracker, kept across epochs (None: no rigidity)
    """

    def __init__(self, scenario: Scenario, rigidity: HealthyRigidity | None) -> None:
        n, d = scenario.n, scenario.dimension
        self.scenario = scenario
        self.rigidity = rigidity
        self.forest = KruskalGraph.of(n, scenario.edge_array, scenario.weights)
        self._last_forests: tuple[tuple[bytes, tuple[int, ...]], Mask, Ints] | None = None
        noise = scenario.noise_covariance
        self.exact = not np.any(noise)  # ideal sensors: any equal weighting is exact
        # (receiver i, sender j) of each link: z = x_i − x_j
        oriented = scenario.directed_links[:, ::-1]
        cov = np.eye(d) if self.exact else noise
        self.measurements = MeasurementGraph.of(n, d, oriented, cov, scenario.reference_agent)
        self.solver: Solver = "dense" if n <= DENSE_MAX_AGENTS else "auto"  # never by batch size
        self.either = scenario.estimator.edge_rule == "either"
        self.on_tree = scenario.estimator.edges == "tree"

    def epochs(
        self, known: Mask, z: Array, x_ref: Array, *, covariances: bool = True
    ) -> LeaderEpochs:
        """Process one epoch's reports of ``B`` runs.

        Parameters
        ----------
        known : (B, L) the measurement of link ``l`` (taken by its receiver ``i``) reached the leader
        z : (B, L, d) ``z_ij = x_i − x_j + ε_ij`` where known [m]
        x_ref : (d,) the reference agent's position [m]
        covariances : whether to compute the estimate's covariance blocks
        """
        size, n = known.shape[0], self.scenario.n
        per_edge = known.reshape(size, -1, 2)  # links 2e and 2e + 1: the two directions of edge e
        healthy = np.asarray(per_edge.any(axis=2) if self.either else per_edge.all(axis=2))
        tree, labels = self._forests(healthy)
        estimate = self._estimate(known, z, x_ref, healthy, tree, labels, covariances)
        ranks, rigid = (None, None) if self.rigidity is None else self.rigidity.check(healthy)
        return LeaderEpochs(
            healthy=healthy,
            tree=tree,
            components=n - tree.sum(axis=1, dtype=np.int64),
            estimate=estimate,
            rigidity_rank=ranks,
            rigid=rigid,
        )

    def _forests(self, healthy: Mask) -> tuple[Mask, Ints]:
        """Kruskal's forests of ``healthy``; the last epoch's again when its edges are the same
        (a team that lost no link keeps its forest)."""
        key = healthy.tobytes(), healthy.shape
        last = self._last_forests  # read once: replaced whole, never changed
        if last is None or last[0] != key:
            tree, labels = self.forest.forests(healthy)
            tree.flags.writeable = labels.flags.writeable = False  # shared by later epochs
            last = self._last_forests = key, tree, labels
        return last[1], last[2]

    def covariances(self, known: Mask, z: Array, x_ref: Array, epochs: LeaderEpochs) -> Array:
        """The covariance blocks of ``epochs`` (computed without them), after their estimates.

        known, z, x_ref : as given to :meth:`epochs`. Returns (B, n, d, d) [m²], the floats
        :meth:`epochs` gives with ``covariances=True``.
        """
        est = self._estimate(known, z, x_ref, epochs.healthy, epochs.tree, None, True)
        if est.covariances is None:  # MeasurementGraph.estimate returns what it is asked for
            raise RuntimeError("the estimate came back without the covariances it was asked for")
        return est.covariances

    def _estimate(
        self,
        known: Mask,
        z: Array,
        x_ref: Array,
        healthy: Mask,
        tree: Mask,
        labels: Ints | None,
        covariances: bool,
    ) -> BlueBatch:
        use = known & np.repeat(tree if self.on_tree else healthy, 2, axis=1)
        # Every used-edge set spans the healthy graph, as the forest does: the forest's components.
        estimate = self.measurements.estimate(
            z, x_ref, use, covariances=covariances, solver=self.solver, labels=labels
        )
        if self.exact and estimate.covariances is not None:
            estimate.covariances[~np.isnan(estimate.covariances)] = 0.0
        return estimate


def leader_epoch(
    scenario: Scenario, known: Mask, z: Array, x_ref: Array, rigidity: HealthyRigidity | None = None
) -> LeaderEpoch:
    """Process one epoch's reports: :meth:`Leader.epochs` for one run.

    Parameters
    ----------
    scenario : the run's scenario; ``scenario.directed_links[l] = (j, i)`` is link ``j → i``
    known : (L,) the measurement of link ``l`` (taken by its receiver ``i``) reached the leader
    z : (L, d) ``z_ij = x_i − x_j + ε_ij`` where known [m]
    x_ref : (d,) the reference agent's position [m]
    rigidity : the scenario's rigidity tracker, kept across epochs (made here if None)
    """
    tracker = rigidity or HealthyRigidity(scenario.offsets, scenario.edge_array)
    leader = Leader(scenario, tracker)
    batch = leader.epochs(np.asarray(known, dtype=bool)[None], np.asarray(z)[None], x_ref)
    return batch.member(0)
