"""Example plug-ins for the formation testbed (docs/plugins.md walks through each).

- ``extrapolate``: a loss strategy, the last received position moved on by the reference
  velocity for every epoch since it was sent;
- ``saturated``: a controller, the displacement law with each agent's step clipped;
- ``jammer``: a link model that drops everything on chosen links during a schedule.
"""
