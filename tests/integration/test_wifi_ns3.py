"""The air model against ns-3, live: the same phases through both (docs/model.md §11).

ns-3 runs in its own process (``testkit.ns3_air``). The test skips only where the optional
extra ``[ns3]`` is absent; ``make wifi-ns3-check`` installs it and runs this file.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from netem.links.wifi import BROADCAST, AirConfig, Frames, Key, decide_phase
from testkit.ns3_air import arrivals, phase_request, run_ns3

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("ns") is None, reason="ns-3 (the [ns3] extra) is not installed"
)

MSDU_BYTES = 236
US = 1000


def crowd(rng: np.random.Generator) -> tuple[np.ndarray, Frames]:
    """10 agents within 20 m, each broadcasting once in 20 ms."""
    r = 10.0 * np.sqrt(rng.uniform(0.0, 1.0, 10))
    a = rng.uniform(0.0, 2 * np.pi, 10)
    ready = rng.integers(0, 20_000 * US, 10)
    positions = np.column_stack([r * np.cos(a), r * np.sin(a)])
    return positions, Frames.of(np.arange(10), BROADCAST, MSDU_BYTES, ready)


def hidden_pair(rng: np.random.Generator) -> tuple[np.ndarray, Frames]:
    """0 and 2, 80 m apart, each broadcasting once in 1 ms; 1 between them hears both."""
    positions = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]])
    return positions, Frames.of([0, 2], BROADCAST, MSDU_BYTES, rng.integers(0, 1000 * US, 2))


def delivery_and_latency(arrival: np.ndarray, frames: Frames) -> tuple[int, int, int]:
    """(deliveries, addressed receivers, summed latency [ns]) of one phase's broadcasts."""
    to = np.ones(arrival.shape, dtype=bool)
    to[np.arange(len(frames)), frames.sender] = False
    got = to & (arrival >= 0)
    return int(got.sum()), int(to.sum()), int((arrival - frames.ready_ns[:, None])[got].sum())


def test_the_model_delivers_as_ns3_does(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cases = {
        "crowd": [crowd(rng) for _ in range(30)],
        "hidden": [hidden_pair(rng) for _ in range(300)],
    }
    batch = [
        phase_request(
            "ofdm", 6.0, x, f.sender, f.receiver, f.payload_bytes, f.ready_ns, seed, 1 + k
        )
        for k, (x, f) in enumerate(p for phases in cases.values() for p in phases)
    ]
    replies, _ = run_ns3(batch)
    config = AirConfig()
    k = 0
    for c, (name, phases) in enumerate(cases.items()):
        model, ns3 = np.zeros(3), np.zeros(3)
        for j, (positions, frames) in enumerate(phases):
            out = decide_phase(config, positions, frames, Key(seed, c, j))
            model += delivery_and_latency(out.arrival_ns, frames)
            ns3 += delivery_and_latency(arrivals(replies[k], len(frames), 3 if c else 10), frames)
            k += 1
        delivery = (model[0] / model[1], ns3[0] / ns3[1])
        latency = (model[2] / model[0], ns3[2] / ns3[0])
        assert delivery[0] == pytest.approx(delivery[1], abs=0.02), name
        assert latency[0] == pytest.approx(latency[1], rel=0.10), name
