"""A shared 802.11 channel: one phase's frames through every agent's DCF (docs/model.md §11).

The model alone: netem does not use it yet. :func:`decide_phase` takes the agents' positions
and a phase's :class:`Frames` and gives each frame's fate at each agent
(:class:`PhaseOutcome`, :class:`Cause`), from an :class:`AirConfig` and a :class:`Key`.
"""

from netem.links.wifi.config import AirConfig
from netem.links.wifi.dcf import Key, decide_phase, load_compiled_loop
from netem.links.wifi.frames import BROADCAST, AirError, Cause, Frames, PhaseOutcome
from netem.links.wifi.phy import PHYS, Phy

__all__ = [
    "BROADCAST",
    "PHYS",
    "AirConfig",
    "AirError",
    "Cause",
    "Frames",
    "Key",
    "PhaseOutcome",
    "Phy",
    "decide_phase",
    "load_compiled_loop",
]
