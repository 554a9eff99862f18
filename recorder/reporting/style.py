"""One look per loss strategy, the same in every figure of the project.

Colours are the Okabe–Ito palette (safe under the common colour-vision deficiencies); each
strategy also has its own line style and marker, so a figure still reads in grey. A
strategy that is not the chapter's (a plug-in) gets a look picked from its name, so it is
the same in every run and on every machine. Pure: no matplotlib.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

# Okabe & Ito, "Color Universal Design" (2008)
BLACK = "#000000"
ORANGE = "#E69F00"
SKY_BLUE = "#56B4E9"
BLUISH_GREEN = "#009E73"
BLUE = "#0072B2"
VERMILLION = "#D55E00"
REDDISH_PURPLE = "#CC79A7"
GREY = "#999999"

# what a figure marks besides the strategies
GAIN_COLOUR = BLUISH_GREEN  # an agent comes in, a link delivers
LOSS_COLOUR = VERMILLION  # an agent goes out, a link drops
UNKNOWN_COLOUR = "#DDDDDD"
THRESHOLD_COLOUR = GREY


@dataclass(frozen=True)
class Look:
    """How one strategy is drawn: matplotlib's ``color``, ``linestyle`` and ``marker``."""

    colour: str
    line: str
    marker: str

    def kwargs(self) -> dict[str, str]:
        """The look as keyword arguments of ``Axes.plot``."""
        return {"color": self.colour, "linestyle": self.line, "marker": self.marker}


CHAPTER_LOOKS = {
    "zero": Look(VERMILLION, "-", "x"),
    "hold": Look(ORANGE, "-.", "s"),
    "estimate": Look(BLUE, "-", "o"),
    "blend": Look(BLUISH_GREEN, "--", "^"),
    "drop": Look(REDDISH_PURPLE, ":", "D"),
}
_PLUGIN_COLOURS = (SKY_BLUE, BLACK, GREY)
_PLUGIN_LINES = ("-", "--", "-.", ":")
_PLUGIN_MARKERS = ("v", "P", "*", "X", "h", "<", ">")


def look(strategy: str) -> Look:
    """The look of ``strategy``; a plug-in's is picked by a checksum of its name."""
    if strategy in CHAPTER_LOOKS:
        return CHAPTER_LOOKS[strategy]
    key = zlib.crc32(strategy.encode())  # not hash(): that changes between processes
    return Look(
        _PLUGIN_COLOURS[key % len(_PLUGIN_COLOURS)],
        _PLUGIN_LINES[(key // 3) % len(_PLUGIN_LINES)],
        _PLUGIN_MARKERS[(key // 12) % len(_PLUGIN_MARKERS)],
    )


def palette(n: int) -> list[str]:
    """``n`` colours (agents, curves that are not strategies): the palette's seven, repeated;
    no yellow, unreadable on white."""
    seven = (BLUE, ORANGE, BLUISH_GREEN, VERMILLION, REDDISH_PURPLE, SKY_BLUE, BLACK)
    return [seven[i % len(seven)] for i in range(n)]


__all__ = [
    "BLACK",
    "CHAPTER_LOOKS",
    "GAIN_COLOUR",
    "GREY",
    "LOSS_COLOUR",
    "SKY_BLUE",
    "THRESHOLD_COLOUR",
    "UNKNOWN_COLOUR",
    "Look",
    "look",
    "palette",
]
