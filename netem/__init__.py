"""The netem service: every packet of a run through its link's loss and delay models.

``python -m netem`` runs it over Zenoh (:mod:`netem.node`); the testbed's simulator takes the
same decisions for a batch of seeds from :func:`delivery_plan`, and measures link lengths with
:func:`link_lengths` as netem does. :class:`LinkModel`, :func:`delivery_matrix`,
:func:`schedule` and :func:`expected_delivery_at` are the link-model library the benchmarks
time and check against closed forms. :class:`Layer`, :class:`Keys` and :class:`LayerOutput`
are what a link model plug-in implements (docs/plugins.md).
"""

from netem.links.capacity import QueueParams, serve_queue  # capacity (docs/model.md §9)
from netem.links.capacity_plan import CapacityPlanner, capacity_plan
from netem.links.closed_forms import expected_delivery_at
from netem.links.layer import Keys, Layer, LayerOutput
from netem.links.layer_stack import probe_stack
from netem.links.matrix import DeliveryPlan, delivery_plan, link_lengths
from netem.links.models import LinkModel, delivery_matrix, schedule

__all__ = [
    "CapacityPlanner",
    "DeliveryPlan",
    "Keys",
    "Layer",
    "LayerOutput",
    "LinkModel",
    "QueueParams",
    "capacity_plan",
    "delivery_matrix",
    "delivery_plan",
    "expected_delivery_at",
    "link_lengths",
    "probe_stack",
    "schedule",
    "serve_queue",
]
