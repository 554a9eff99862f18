"""A node's one loop: the generator of its epochs and the waits it yields (shell.timing)."""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass

from shell.service import Incoming


@dataclass(frozen=True)
class Wait:
    """The loop waits for epoch ``epoch``'s inputs of a phase whose realtime deadline is at
    ``at`` of the period (``formation.realtime``).

    ``complete``: whether nothing more the phase would take can come. Lockstep waits until
    it holds (required); realtime until the deadline, or sooner once it holds if given.
    """

    epoch: int
    at: float
    complete: Callable[[], bool] | None = None


# A node's epochs: yields a Wait per phase; sent back whether it ended before its deadline.
Loop = Generator[Wait, bool, None]
Route = Callable[[Incoming], None]
