"""The agent service: dynamics, consensus formation control and loss strategies.

``python -m agent`` runs one agent (or a pool) over Zenoh (:mod:`agent.node`); the testbed's
simulator runs the same epoch, :func:`agent_epoch`, over a batch of seeds, with the same
measurement noise and link memory.
"""

from agent.control import (
    body_step,
    body_velocity,
    heading_vector,
    held_velocity_step,
    reference_heading,
    unicycle_arc,
    wrap_angle,
)
from agent.epoch import AgentStep, InLinks, agent_epoch
from agent.measurement import measurement_noise
from agent.strategies import LinkMemory, Substitution, state_width

__all__ = [
    "AgentStep",
    "InLinks",
    "LinkMemory",
    "Substitution",
    "agent_epoch",
    "body_step",
    "body_velocity",
    "heading_vector",
    "held_velocity_step",
    "measurement_noise",
    "reference_heading",
    "state_width",
    "unicycle_arc",
    "wrap_angle",
]
