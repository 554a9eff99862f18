"""Nothing bypasses netem, in a real run: a link netem drops every epoch never carries a packet
from its sender to its receiver, read back from everything the run carried (the recording holds
every key of the run, netem's deliveries included)."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from formation.scenario import Scenario
from testbed.runtime.launcher import launch
from testbed.sim.simulate import simulate

pytestmark = pytest.mark.integration

EPOCHS = 6


def test_a_link_netem_drops_entirely_never_reaches_its_receiver(
    paper_path: Path, tmp_path: Path, runs_dir: Path
) -> None:
    cut = tmp_path / "cut.toml"  # link 1-2 down both ways from epoch 0, not 1
    cut.write_text(
        paper_path.read_text().replace(
            'models = [{ model = "outage", start = 1 }]',
            'models = [{ model = "outage", start = 0 }]',
        )
    )
    scenario = Scenario.from_file(cut).with_overrides(epochs=EPOCHS)
    outcome = launch(scenario, runs_dir=runs_dir)
    carried: dict[str, list[Any]] = defaultdict(list)  # key under the run's prefix → messages
    with (outcome.run_dir / "run.mcap").open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            key = channel.topic.partition(f"/{outcome.run_id}/")[2]
            if key.startswith(("inbox/", "agent/")):
                carried[key].append(json.loads(message.data))
    for receiver, sender in ((2, 1), (1, 2)):
        deliveries = carried[f"inbox/{receiver}/state"]  # all that reaches an agent's states
        assert [d["epoch"] for d in deliveries] == list(range(EPOCHS))
        for d in deliveries:
            sources = {p["source"] for p in d["packets"]}
            assert sender not in sources and sender in d["lost"], d
            assert sources  # its other neighbours' packets pass
        tokens = [
            m["token"]
            for r in carried[f"agent/{receiver}/report"]
            for m in r["measurements"]
            if m["neighbour"] == sender
        ]
        assert tokens == [0] * EPOCHS  # and the receiver never counted one as arrived
    np.testing.assert_array_equal(outcome.positions, simulate(scenario).positions)
