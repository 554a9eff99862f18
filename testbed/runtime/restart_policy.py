"""What the launcher does when a process dies before the run's end (``formation run --restart``).

Its own module, with no imports, so that ``formation run --help`` lists the choices without
loading the launcher (numpy, Zenoh).
"""

from __future__ import annotations

from typing import Literal

RestartPolicy = Literal["no", "on-failure"]
RESTART_POLICIES: tuple[RestartPolicy, ...] = ("no", "on-failure")

__all__ = ["RESTART_POLICIES", "RestartPolicy"]
