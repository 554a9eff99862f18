"""One agent-side epoch (docs/model.md §3, §6): fill lost neighbours, consensus, step.

Works on any set of agents and their in-links: the simulator passes the whole
team, an agent process passes itself, and both get the same floats.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from agent.control import drive_unicycle, lookahead_velocity, step_double, step_single
from agent.strategies import LinkMemory, Substitution, substitute
from formation.plugin_api import ControlInputs, command_checked, control_law
from formation.scenario import Scenario, StrategyName

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class InLinks:
    """The in-links ``j → i`` of a set of agents, in the scenario's directed-link order.

    index : (L,) rows of ``scenario.directed_links``; sender, receiver : (L,) agent ids;
    receiver_row : (L,) row of the receiver within the agent set; desired : (L, d) ``d0_i − d0_j``;
    distance_sq : (L,) ``C_ij²``.
    """

    index: npt.NDArray[np.int64]
    sender: npt.NDArray[np.int64]
    receiver: npt.NDArray[np.int64]
    receiver_row: npt.NDArray[np.int64]
    desired: Array
    distance_sq: Array

    @classmethod
    def of(cls, scenario: Scenario, agents: npt.NDArray[np.int64]) -> InLinks:
        links = scenario.directed_links
        ids = np.asarray(agents, dtype=np.int64)
        row_of = np.full(scenario.n + 1, -1, dtype=np.int64)  # agent id -> row, -1 if not ours
        row_of[ids] = np.arange(ids.size)
        index = np.flatnonzero(row_of[links[:, 1]] >= 0).astype(np.int64)
        sender, receiver = links[index, 0], links[index, 1]
        d0 = scenario.offsets
        return cls(
            index=index,
            sender=sender,
            receiver=receiver,
            receiver_row=row_of[receiver],
            desired=d0[receiver - 1] - d0[sender - 1],
            distance_sq=np.repeat(scenario.weights**2, 2)[index],
        )

    def take(self, rows: npt.NDArray[np.int64]) -> InLinks:
        """The links ``rows`` only (the rest are out of the formation graph this epoch)."""
        return InLinks(
            self.index[rows],
            self.sender[rows],
            self.receiver[rows],
            self.receiver_row[rows],
            self.desired[rows],
            self.distance_sq[rows],
        )


@dataclass(frozen=True)
class AgentStep:
    positions: Array  # (a, d) x[k+1] [m]
    velocities: Array  # (a, d) [m/s] (double integrator; zeros otherwise)
    memory: LinkMemory
    substitution: Substitution
    headings: Array | None = None  # (a,) θ[k+1] [rad] (unicycle; None otherwise)
    saturated: npt.NDArray[np.int64] | None = None  # (a,) sub-steps of epoch k with a clipped speed
    drive: Array | None = (
        None  # (a, 2) the look-ahead points' velocity over epoch k [m/s] (unicycle)
    )


def agent_epoch(
    scenario: Scenario,
    strategy: StrategyName,
    epoch: int,
    links: InLinks,
    x: Array,
    velocities: Array,
    arrived: Mask,
    received: Array,
    z: Array,
    memory: LinkMemory,
    estimate: Array,
    has_estimate: Mask,
    v_ref_prev: Array,
    v_ref: Array,
    headings: Array | None = None,
    agents: npt.NDArray[np.int64] | None = None,
) -> AgentStep:
    """Advance a set of agents from ``x[k]`` to ``x[k+1]``.

    Parameters
    ----------
    x, velocities : (a, d) the agents' states [m], [m/s]
    arrived : (L,) in-link packet of epoch ``k`` arrived in time; received (L, d) its ``x_j[k]``
    z : (L, d) relative measurements where arrived [m]
    memory : per in-link memory from epoch ``k − 1``
    estimate : (L, d) leader's ``x̂_j[k]``; has_estimate (L,)
    v_ref_prev : (L, d) ``v_ref[k − 1]`` as each receiver knows it; v_ref (a, d) ``v_ref[k]`` as known
    headings : (a,) ``θ[k]`` [rad], unicycle dynamics only (``x`` are then the look-ahead points)
    agents : (a,) the agents' ids, named when a plug-in fails (default: ``1..a``)
    """
    if agents is None:
        agents = np.arange(1, x.shape[0] + 1, dtype=np.int64)
    ctl = scenario.control
    sub, memory = substitute(
        strategy,
        scenario.strategy.params_of(strategy),
        epoch,
        arrived,
        received,
        memory,
        estimate,
        has_estimate,
        v_ref_prev,
        ctl.period_s,
        links.receiver,
    )
    relative = np.where(arrived[:, None], z, x[links.receiver_row] - sub.values)
    inputs = ControlInputs(
        n=x.shape[0],
        receivers=links.receiver_row,
        relative=relative,
        desired=links.desired,
        distance_sq=links.distance_sq,
        used=sub.used,
        epsilon=ctl.epsilon,
        period_s=ctl.period_s,
        positions=x,
        velocities=velocities,
        dynamics=ctl.dynamics,
        epoch=epoch,
        time_s=epoch * ctl.period_s,
    )
    cmd = command_checked(
        ctl.controller, control_law(ctl.controller), inputs, ctl.law_params, agents, epoch
    )
    if ctl.dynamics == "single":
        return AgentStep(step_single(x, cmd, v_ref, ctl.period_s), velocities, memory, sub)
    if ctl.dynamics == "unicycle":
        if headings is None:
            raise ValueError("dynamics = 'unicycle' needs the agents' headings")
        u = lookahead_velocity(cmd, v_ref, ctl.period_s)
        nxt, th, sat = drive_unicycle(x, headings, u, ctl.period_s, ctl.unicycle.limits)
        return AgentStep(nxt, velocities, memory, sub, th, sat, u)
    nxt, vel = step_double(x, velocities, cmd, v_ref, ctl.period_s, ctl.damping)
    return AgentStep(nxt, vel, memory, sub)
