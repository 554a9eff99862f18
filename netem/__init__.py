"""The netem service: every packet of a run through its link's loss and delay models.

``python -m netem`` runs it over Zenoh (:mod:`netem.node`); the testbed's simulator takes the
same decisions for a batch of seeds from :func:`delivery_plan`, and measures link lengths with
:func:`link_lengths` as netem does. :class:`Layer`, :class:`Keys` and :class:`LayerOutput`
are what a link model plug-in implements (docs/plugins.md).
"""

from netem.links.air_network import AIR, CAUSES, AirPlanner, air_of
from netem.links.capacity_plan import CapacityPlanner, capacity_plan
from netem.links.layer import Keys, Layer, LayerOutput
from netem.links.layer_stack import probe_stack
from netem.links.matrix import DeliveryPlan, delivery_plan, link_lengths

__all__ = [
    "AIR",
    "CAUSES",
    "AirPlanner",
    "CapacityPlanner",
    "DeliveryPlan",
    "Keys",
    "Layer",
    "LayerOutput",
    "air_of",
    "capacity_plan",
    "delivery_plan",
    "link_lengths",
    "probe_stack",
]
