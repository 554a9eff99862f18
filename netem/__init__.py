"""The netem service: every packet of a run through its link's loss and delay models.

``python -m netem`` runs it over Zenoh (:mod:`netem.node`); the testbed's simulator takes the
same decisions for a batch of seeds from :func:`delivery_plan`, and measures link lengths with
:func:`link_lengths` as netem does.
"""

from netem.matrix import DeliveryPlan, delivery_plan, link_lengths

__all__ = ["DeliveryPlan", "delivery_plan", "link_lengths"]
