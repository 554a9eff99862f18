"""The shared air in a run: the scenario's [network.air], netem's lockstep and the simulator
deciding the same packets the same way, each drop with its cause."""

from __future__ import annotations

import math
import threading
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
import orjson
import pytest

import testbed
from analysis import summarise
from formation.air import AIR_CAUSES, RATES_MBPS
from formation.errors import TestbedError
from formation.scenario import Scenario
from netem.links.air_network import AIR, CAUSES, AirNetwork
from netem.links.wifi import PHYS
from netem.proxy.lockstep import LockstepCore
from netem.proxy.progress import Progress
from netem.proxy.records import Ledger
from netem.proxy.routes import Links, Route
from testkit.lockstep_wire import Wire, receivers


def on_air(paper: Scenario, epochs: int, **air: object) -> Scenario:
    """The paper's team on one channel, its senders starting within 50 µs: frames collide."""
    network = paper.network.model_dump(by_alias=True)
    network["access_point"] = [0.0, 0.0]
    network["formation_default"] = [{"model": "bernoulli", "p_loss": 0.1}]
    network["air"] = {"links": "all", "start_spread_us": 50.0, **air}
    return paper.with_overrides(epochs=epochs, network=network)


def test_the_scenario_knows_the_models_rates() -> None:
    for name, phy in PHYS.items():
        assert [round(r * 1000) for r in RATES_MBPS[name]] == list(phy.rates_kbps)
    assert set(AIR_CAUSES) == set(CAUSES) - {"delivered", "not_addressed"}


@pytest.mark.parametrize(
    ("air", "match"),
    [
        ("rate_mbps = 7", r"x\.toml: network\.air\.rate_mbps = 7\.0; ofdm has the rates 6, 9"),
        ('links = "control"', r"network\.air\.links = 'control'; control links on the air need"),
        ('phy = "ac"', r"network\.air\.phy = 'ac'; Input should be 'ofdm'"),
        ("cw_min = 64\ncw_max = 32", r"network\.air\.cw_min = 64; above cw_max 32"),
        (
            '[[network.capacity]]\nscope = "radio"\nagent = 2\nrate_bps = 1e4\n'
            '[runtime]\nmode = "realtime"',
            r"runtime\.mode = 'realtime'; the shared air with capacity queues runs in lockstep",
        ),
        (
            'reports = "with_states"\nlinks = "formation"',
            r"network\.air\.reports = 'with_states'; with the states needs links = \"all\"",
        ),
        (
            'reports = "with_states"\nlinks = "all"\n[runtime]\nmode = "realtime"',
            r"runtime\.mode = 'realtime'; the reports with the states .* run in lockstep",
        ),
        ('control_channel = "air2"', r"network\.air\.control_channel = 'air2'; Input should be"),
    ],
)
def test_a_wrong_air_names_the_file_field_and_value(
    paper_path: Path, tmp_path: Path, air: str, match: str
) -> None:
    path = tmp_path / "x.toml"
    path.write_text(paper_path.read_text() + f"\n[network.air]\n{air}\n")
    with pytest.raises(TestbedError, match=match):
        Scenario.from_file(path)


def test_a_phase_is_the_same_for_the_same_key_and_its_packets_in_any_order(
    paper: Scenario,
) -> None:
    net = AirNetwork(on_air(paper, 5), 3)
    x = paper.initial_positions(3)
    links = [(int(a), int(b)) for a, b in paper.directed_links]
    phases = [net.phase(k, "state", links, x) for k in range(20)]
    k = next(k for k, got in enumerate(phases) if any(v.cause == "collision" for v in got))
    first = phases[k]
    assert first == net.phase(k, "state", links[::-1], x)[::-1]
    assert any(got != first for got in phases)  # other epochs, other draws
    unicast = AirNetwork(on_air(paper, 5, states="unicast"), 3).phase(k, "state", links, x)
    assert {v.frames for v in unicast} == {len(links)} and {v.frames for v in first} == {paper.n}


def test_a_late_frame_is_late(paper: Scenario) -> None:
    s = on_air(paper, 5, start_spread_us=0.0).with_overrides(
        control={**paper.control.model_dump(), "period_s": 0.001}
    )
    # a state phase of 0.2 ms: a frame takes longer
    (got,) = AirNetwork(s, 1).phase(0, "state", [(1, 3)], paper.initial_positions(1))
    assert got.cause == "late" and math.isnan(got.arrival_ms)
    (alone,) = AirNetwork(on_air(paper, 5), 1).phase(
        0, "state", [(1, 3)], paper.initial_positions(1)
    )
    assert alone.passed and 0.0 < alone.arrival_ms < 1.0


def lockstep_records(scenario: Scenario, seed: int, x: np.ndarray) -> dict[tuple[int, ...], object]:
    """netem's lockstep core fed the states (positions ``x`` (E, n, d)), reports and estimates
    of every epoch in a shuffled order; its decision records by (source, target, epoch)."""
    links, wire = Links(scenario, seed), Wire(receivers(scenario))
    core = LockstepCore(links, scenario.epochs, Progress(links.agents, scenario.epochs, lambda: None),
                        Ledger(), wire)  # fmt: skip
    rng = np.random.default_rng(seed)
    agents = list(range(1, scenario.n + 1))
    for k in range(scenario.epochs):
        states = [orjson.dumps({"position": x[k, i - 1].tolist()}) for i in agents]
        first: list[tuple[Route, bytes]] = [(("state", i, 0), states[i - 1]) for i in agents]
        first += [(("report", i, 0), b"{}") for i in agents]
        for p in rng.permutation(len(first)):
            core.packet(first[p][0], k, k, first[p][1])
        for i in rng.permutation(agents):
            core.packet(("estimate", 0, int(i)), k, k, b"{}")
    core.flush()  # the records waiting for their batch
    assert not wire.early
    return {(d.source, d.target, d.epoch): d for d in wire.decisions}


def test_netem_lockstep_drops_what_the_simulator_drops_for_the_same_cause(
    paper: Scenario, seed: int
) -> None:
    scenario = on_air(paper, 12)
    # agent 2's radio too slow for its states: what its queue drops never takes the air
    network = scenario.network.model_dump(by_alias=True)
    network["capacity"] = [{"scope": "radio", "agent": 2, "rate_bps": 12_000.0, "limit_packets": 2}]
    scenario = scenario.with_overrides(network=network)
    sim = testbed.simulate(scenario, seed=seed)
    made = sim.decisions_made()
    got = lockstep_records(scenario, seed, sim.positions)
    assert len(got) == len(made.epoch)
    for r in range(len(made.epoch)):
        d = got[(int(made.source[r]), int(made.target[r]), int(made.epoch[r]))]
        assert (d.verdict != "drop") == (made.verdict[r] == "pass")
        if made.queue[r] == AIR:
            assert (d.queue, d.model) == (AIR, made.model[r])
        elif d.verdict != "drop":
            assert d.queue == AIR and d.sojourn_ms is not None and d.sojourn_ms > 0.0
    causes = Counter(d.model for d in got.values() if d.verdict == "drop")
    # a packet a link model drops never takes the air: its record names the model
    assert causes["collision"] > 0 and causes["bernoulli"] > 0 and causes["outage"] > 0
    assert causes["queue_late"] > 0
    air_losses = sim.summary()["air_losses"]  # what formation simulate says
    assert air_losses == {c: causes[c] for c in AIR_CAUSES}
    full = summarise(replace(sim.record(), decisions=made))  # as a recording's summary
    assert full["air_losses"] == air_losses and AIR not in full["queues"]  # the air is no queue
    assert full["air"]["formation"]["losses"]["collision"] == causes["collision"]
    assert all(d.queue == "radio 2" for d in got.values() if d.model.startswith("queue_"))
    assert all(d.queue is None for d in got.values() if d.model in ("bernoulli", "outage"))


def test_the_air_is_shown_and_set_while_running_from_the_next_epoch(paper: Scenario) -> None:
    from formation import keys
    from formation.messages import LinkChange
    from netem.link_config import LinkConfig
    from shell import MemoryBus, Service

    scenario = on_air(paper, 30)
    links, wire = Links(scenario, 1), Wire(receivers(scenario))
    progress = Progress(links.agents, scenario.epochs, lambda: None)
    core = LockstepCore(links, scenario.epochs, progress, Ledger(), wire)
    bus = MemoryBus()
    changes: list[LinkChange] = []
    bus.declare_subscriber(
        keys.netem_change("r"),
        lambda s: changes.append(LinkChange.model_validate_json(s.payload.to_bytes())),
    )
    config = LinkConfig(Service(bus, "r", "netem", 0), links, progress, core, threading.Lock())
    progress.epoch_seen = 7
    shown = config.answer({"op": "show"})["air"]
    assert (shown["links"], shown["rate_mbps"], shown["start_spread_us"]) == ("all", 6.0, 50.0)
    answer = config.answer({"op": "air", "air": {"rate_mbps": 12, "shadowing_sigma_db": 4}})
    assert answer["ok"] and answer["from_epoch"] == 8
    air = links.air
    assert air is not None
    assert air.at(7)[1].rate_mbps == 6.0 and air.at(8)[1].rate_mbps == 12.0
    assert air.at(8)[1].shadowing_sigma_db == 4.0
    assert config.answer({"op": "show"})["air"]["rate_mbps"] == 12.0
    # recorded as a change of every link on the air, from that epoch
    assert len(changes) == len(links.models) and {c.from_epoch for c in changes} == {8}
    assert changes[0].models[0]["model"] == "air"
    assert config.answer({"op": "air", "air": {"rate_mbps": 7}}) == {
        "ok": False,
        "error": "rate_mbps = 7.0; ofdm has the rates 6, 9, 12, 18, 24, 36, 48, 54 Mb/s",
    }
    assert not config.answer({"op": "air", "air": {"estimation_traffic": "when_used"}})["ok"]
    refused = config.answer({"op": "air", "air": {"links": "formation"}})
    assert refused == {
        "ok": False,
        "error": "links: which links take the air, and when, is the scenario's",
    }


def test_realtime_holds_each_packet_until_the_models_arrival_and_never_changes_a_settled_one(
    paper: Scenario,
) -> None:
    from netem.proxy.realtime_air import RealtimeAir

    air = RealtimeAir(AirNetwork(on_air(paper, 5), 1))
    for i, x in enumerate(paper.initial_positions(1), start=1):
        air.read_position(0, i, orjson.dumps({"position": x.tolist()}))
    t0, ms = 10**12, 10**6  # [ns]
    air.add(0, "state", (1, 3), t0, t0 + 20 * ms, "a")
    air.add(0, "state", (2, 3), t0 + 2 * ms, t0 + 20 * ms, "b")
    assert air.settle(t0 + 100) == []  # nothing has arrived yet
    assert air.next_ns() is not None and air.next_ns() > t0 + 100  # type: ignore[operator]
    (first,) = air.settle(t0 + ms)  # a alone on the air: arrived before b was ready
    assert first[0] == "a" and first[1].passed and t0 < first[2] <= t0 + ms
    assert first[2] == t0 + round(first[1].arrival_ms * 1e6)
    air.add(0, "state", (4, 3), t0, t0 + 20 * ms, "c")  # came late to netem: ready from now
    rest = air.settle(t0 + 20 * ms)  # the deadline: the phase is over
    assert sorted(item for item, _, _ in rest) == ["b", "c"] and not air.open
    assert all(v.passed for _, v, _ in rest)
