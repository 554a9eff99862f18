"""The agent service: dynamics, consensus formation control and loss strategies.

``python -m agent`` runs one agent (or a pool) over Zenoh (:mod:`agent.node`); the testbed's
simulator runs the same epoch, :func:`agent_epoch`, over a batch of seeds, with the same
measurement noise and link memory.
"""

from agent.control import (
    axle_centre,
    body_step,
    body_velocity,
    drive_unicycle,
    held_velocity_step,
    reference_heading,
    substep_s,
    unicycle_arc,
    unicycle_substep,
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
    "axle_centre",
    "body_step",
    "body_velocity",
    "drive_unicycle",
    "held_velocity_step",
    "measurement_noise",
    "reference_heading",
    "state_width",
    "substep_s",
    "unicycle_arc",
    "unicycle_substep",
    "wrap_angle",
]
