"""The headless ROS 2 plant: the robots of a scenario's ``[body]``, without a robot (docs/robots.md)."""

from testbed.plant.node import Plant, PlantTiming
from testbed.plant.robots import Robots

__all__ = ["Plant", "PlantTiming", "Robots"]
