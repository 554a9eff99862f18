"""The agent service: dynamics, consensus formation control and loss strategies."""

from agent.control import displacement_command, distance_command, step_double, step_single
from agent.measurement import measurement_noise, relative_measurement
from agent.strategies import LinkMemory, Substitution, substitute

__all__ = [
    "LinkMemory",
    "Substitution",
    "displacement_command",
    "distance_command",
    "measurement_noise",
    "relative_measurement",
    "step_double",
    "step_single",
    "substitute",
]
