"""``formation netem --help`` says how a queue's parameters map to Linux's (docs/model.md §9)."""

from __future__ import annotations

import re

from testbed.cli import build_parser


def test_netem_help_gives_the_kernel_mapping_of_a_queue() -> None:
    parser = build_parser("netem")
    netem = next(
        a
        for a in parser._subparsers._group_actions  # type: ignore[union-attr]
    ).choices["netem"]
    text = " ".join(netem.format_help().split())
    for rule in (
        r"overhead_bytes \[B\] added to each payload: 42 for UDP over IPv4 on Ethernet",
        r"burst_bytes \[B\] tbf's burst; 0 is netem rate",
        r"limit_bytes \[B\] tbf's limit",
        r"limit_packets a pfifo child of tbf",
        r"oldest: a pfifo_head_drop child",
        r"rate_bps \[bit/s\] the rate, a multiple of 8",
    ):
        assert re.search(rule, text), rule
