"""netem's lockstep with distance models: positions read from the states, packets held until known.

Every formation link has a ``logistic`` model and the control links a ``range`` to an
access point; packets arrive in adversarial orders (a sender's state before its
receivers'), and every decision must be the link model's at the true distance.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import zenoh

from formation.scenario import Scenario
from netem.links.models import LinkModel, link_lengths
from netem.proxy.lockstep import LockstepCore
from netem.proxy.progress import Progress
from netem.proxy.records import Ledger
from netem.proxy.routes import Links, Route
from testkit.lockstep_wire import Wire, receivers

ROOT = Path(__file__).resolve().parents[3]
NETWORK = {
    "formation_default": [{"model": "logistic", "d50_m": 1.2, "width_m": 0.1}],
    "control_default": [{"model": "range", "max_range_m": 1.0}],
    "access_point": [0.0, 0.2],
}


def wireless(paper: Scenario) -> Scenario:
    return paper.with_overrides(network=NETWORK, epochs=6)


def core(scenario: Scenario, seed: int) -> tuple[LockstepCore, Wire]:
    links, wire = Links(scenario, seed), Wire(receivers(scenario))
    lock = LockstepCore(links, scenario.epochs, Progress(links.agents, scenario.epochs, lambda: None),
                    Ledger(), wire)  # fmt: skip
    return lock, wire


def state(i: int, k: int, x: np.ndarray) -> tuple[Route, int, int, bytes]:
    msg = {"agent": i, "epoch": k, "position": x[i - 1].tolist()}
    return ("state", i, 0), k, k, json.dumps(msg).encode()


def positions(seed: int, k: int, n: int) -> np.ndarray:
    return np.random.default_rng(seed * 100 + k).uniform(-1.0, 1.0, size=(n, 2))


@pytest.mark.parametrize("order", ["ascending", "descending"])
def test_decisions_are_the_models_at_the_true_distances(
    paper: Scenario, seed: int, order: str
) -> None:
    scenario = wireless(paper)
    lock, wire = core(scenario, seed)
    n, ap = scenario.n, np.array([0.0, 0.2])
    agents = list(range(1, n + 1)) if order == "ascending" else list(range(n, 0, -1))
    xs = {}
    for k in range(scenario.epochs):
        xs[k] = x = positions(seed, k, n)
        for i in agents:
            lock.packet(*state(i, k, x))
        for i in agents:
            lock.packet(("report", i, 0), k, k, b"{}")
        for i in agents:
            lock.packet(("estimate", 0, i), k, k, b"{}")
    assert lock.positions.held == {} or all(not v for v in lock.positions.held.values())
    lock.flush()
    decided = {(d.link_class, d.source, d.target, d.epoch): d for d in wire.decisions}
    assert len(decided) == scenario.epochs * (len(scenario.directed_links) + 2 * n)
    for (cls, src, dst, k), d in decided.items():
        x = xs[k]
        a = ap if src == 0 else x[src - 1]
        b = ap if dst == 0 else x[dst - 1]
        length = float(link_lengths(a[None], b[None])[0])
        specs = (
            scenario.formation_link_models(src, dst)
            if cls == "formation"
            else (
                scenario.control_link_models(
                    dst if src == 0 else src, "estimate" if src == 0 else "report"
                )
            )
        )
        want = LinkModel(specs, seed, src, dst).decide(k, distance_m=length)
        assert (d.verdict, d.model) == (want.verdict, want.model), (cls, src, dst, k)
    verdicts = {d.verdict for d in decided.values()}
    assert verdicts == {"pass", "drop"}  # the distances straddle d50 and the range
    # every receiver closed each epoch once
    assert all(c == len(wire.receivers[p]) for (p, _), c in wire.closed.items())


def test_a_packet_waits_for_its_receivers_position(paper: Scenario, seed: int) -> None:
    scenario = wireless(paper)
    lock, wire = core(scenario, seed)
    x = positions(seed, 0, scenario.n)
    lock.packet(*state(1, 0, x))  # 1 → 2, 1 → 3, 1 → 4: their receivers' positions unknown
    assert not any(d.epoch == 0 and d.source == 1 for d in wire.decisions) and not wire.deliveries
    assert sum(len(v) for v in lock.positions.held.values()) == 1
    for i in (2, 3, 4, 5):
        lock.packet(*state(i, 0, x))
    assert not any(v for v in lock.positions.held.values())
    assert {d.receiver for d in wire.deliveries if d.phase == "state"} == {1, 2, 3, 4, 5}


def test_a_dead_receiver_releases_what_waited_for_it(paper: Scenario, seed: int) -> None:
    scenario = wireless(paper)
    lock, wire = core(scenario, seed)
    x = positions(seed, 0, scenario.n)
    for i in (1, 2, 3, 5):
        lock.packet(*state(i, 0, x))  # 4 never sends: 1, 2 and 5 wait on it
    assert any(v for v in lock.positions.held.values())
    lock.sender_died(4)
    assert not any(v for v in lock.positions.held.values())
    got = {d.receiver for d in wire.deliveries if d.phase == "state" and d.epoch == 0}
    assert got == {1, 2, 3, 5}


def test_an_unreadable_position_is_counted_and_out_of_range(paper: Scenario, seed: int) -> None:
    scenario = wireless(paper)
    lock, wire = core(scenario, seed)
    x = positions(seed, 0, scenario.n)
    lock.packet(("state", 2, 0), 0, 0, b"not json")
    lock.packet(("state", 1, 0), 0, 0, b'{"position": ["a"]}')
    for i in (3, 4, 5):
        lock.packet(*state(i, 0, x))
    assert lock.positions.malformed == 2
    lock.flush()
    from_bad = [d for d in wire.decisions if d.source in (1, 2) and d.link_class == "formation"]
    assert from_bad and all(d.verdict == "drop" and d.model == "logistic" for d in from_bad)


def test_without_distance_models_no_state_is_read(paper: Scenario, seed: int) -> None:
    lock, _ = core(paper, seed)
    assert not lock.positions.needed
    lock.packet(("state", 1, 0), 0, 0, b"not json")
    assert lock.positions.malformed == 0 and not lock.positions.at


def true_decisions(scenario: Scenario, seed: int, wire: Wire, xs: dict[int, np.ndarray],
                   epochs: range) -> None:  # fmt: skip
    """Every formation decision of ``epochs`` is the link model's at the true distance."""
    seen = 0
    for d in wire.decisions:
        if d.link_class != "formation" or d.epoch not in epochs:
            continue
        x = xs[d.epoch]
        length = float(link_lengths(x[d.source - 1][None], x[d.target - 1][None])[0])
        model = LinkModel(scenario.formation_link_models(d.source, d.target), seed, d.source,
                          d.target)  # fmt: skip
        want = model.decide(d.epoch, distance_m=length)
        assert (d.verdict, d.model) == (want.verdict, want.model), d
        seen += 1
    assert seen


def test_an_agent_back_is_waited_for_with_its_position(paper: Scenario, seed: int) -> None:
    """After a death and a rejoin the agent's receivers wait for its real position again (they
    were once released at the next packet, the agent counted as out of range)."""
    scenario = paper.with_overrides(network=NETWORK, epochs=9)
    lock, wire = core(scenario, seed)
    xs = {k: offsets(scenario) for k in range(scenario.epochs)}
    for k in range(2):
        for i in (1, 2, 3, 4, 5):
            lock.packet(*state(i, k, xs[k]))
    lock.sender_died(3)
    for k in range(2, 4):
        for i in (1, 2, 4, 5):
            lock.packet(*state(i, k, xs[k]))
    back = lock.rejoin(3)
    for k in range(back, scenario.epochs):
        for i in (1, 2, 5, 4, 3):  # 4 goes at once (no link to 3), the rest wait for 3
            lock.packet(*state(i, k, xs[k]))
    assert not lock.positions.held
    lock.flush()
    true_decisions(scenario, seed, wire, xs, range(back, scenario.epochs))
    into_3 = [d for d in wire.decisions if d.target == 3 and d.epoch >= back]
    assert into_3 and all(d.verdict == "pass" for d in into_3)  # a small pentagon: all in range


def test_a_packet_is_not_held_for_an_agent_out_by_the_scenario(paper: Scenario, seed: int) -> None:
    """An agent that left (a scenario event) sends no position: nothing waits for it."""
    events = [{"epoch": 2, "agent": 4, "action": "leave"}]
    scenario = paper.with_overrides(network=NETWORK, epochs=5, events=events)
    lock, wire = core(scenario, seed)
    xs = {k: offsets(scenario) for k in range(scenario.epochs)}
    for k in range(scenario.epochs):
        for i in (1, 2, 3, 5) if k >= 2 else (1, 2, 3, 4, 5):
            lock.packet(*state(i, k, xs[k]))
    assert not lock.positions.held
    got = {(d.receiver, d.epoch) for d in wire.deliveries if d.phase == "state"}
    assert got >= {(j, k) for j in (1, 2, 3, 5) for k in range(scenario.epochs)}
    lock.flush()
    true_decisions(scenario, seed, wire, xs, range(scenario.epochs))


def offsets(scenario: Scenario) -> np.ndarray:
    """A small pentagon: every link well within the logistic's d50 (1.2 m)."""
    return np.asarray(scenario.offsets[:, :2], dtype=np.float64) * 0.3


@pytest.mark.parametrize(
    ("payload", "read"),
    [
        (b'{"position": [0, 1]}', [0.0, 1.0]),  # integers are numbers
        (b'{"position": [0.0, true]}', [0.0, 1.0]),  # as before: JSON true counted as 1
        (b'{"position": [0.0, 0.3], "x": }', None),  # broken after the position
        (b'{"position": [[0.0], 0.3]}', None),
        (b'{"position": {"x": 0.0}}', None),
        (b'{"position": []}', None),
        (b"[0.0, 0.3]", None),
        (b'{"position": [0.0, "0.3"]}', None),
    ],
)
def test_a_forged_position_in_a_gated_epoch(paper: Scenario, seed: int, payload: bytes,
                                            read: list[float] | None) -> None:  # fmt: skip
    """Read as the whole state's JSON says (also from Zenoh's bytes): an unreadable one is
    counted and puts its sender out of range."""
    scenario = wireless(paper)
    lock, wire = core(scenario, seed)
    x = offsets(scenario)
    lock.packet(("state", 1, 0), 0, 0, zenoh.ZBytes(payload))
    for i in (2, 3, 4, 5):
        lock.packet(*state(i, 0, x))
    assert lock.positions.at[0][1] == read
    assert lock.positions.malformed == (read is None)
    lock.flush()
    from_1 = [d for d in wire.decisions if d.source == 1 and d.link_class == "formation"]
    if read is None:
        assert from_1 and all(d.verdict == "drop" and d.model == "logistic" for d in from_1)
    assert {d.receiver for d in wire.deliveries if d.phase == "state"} == {1, 2, 3, 4, 5}


@pytest.mark.parametrize("unreadable", [(), (2,), (1, 4)])
@pytest.mark.parametrize("name", ["paper", "grid20"])
def test_lengths_one_by_one_equal_the_vectorised(name: str, unreadable: tuple[int, ...],
                                                monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """An epoch's lengths, one link at a time (a few links) or vectorised (many), to the last
    bit; an unreadable position, or one of another dimension, makes its links infinitely long."""
    import netem.proxy.positions

    scenario = Scenario.from_file(ROOT / f"scenarios/{name}.toml").with_overrides(network=NETWORK)
    pos = Links(scenario, 1)
    positions = netem.proxy.positions.Positions(pos)
    rng = np.random.default_rng(len(unreadable))
    x = rng.normal(scale=rng.choice([1e-3, 1.0, 1e3], size=(scenario.n, 1)), size=(scenario.n, 2))
    positions.at[0] = {i: x[i - 1].tolist() for i in pos.agents}
    positions.at[1] = {**positions.at[0], 3: [0.0, 0.0, 1.0]}  # one of three coordinates
    for i in unreadable:
        positions.at[0][i] = positions.at[1][i] = None
    links = tuple(link for link in pos.models if link[0] == "formation")
    got = {}
    for threshold in (0, 10**9):
        monkeypatch.setattr(netem.proxy.positions, "VECTOR_LINKS", threshold)
        got[threshold] = [positions.lengths(links, k) for k in (0, 1)]
    assert got[0] == got[10**9]
    for k in (0, 1):
        assert got[0][k] == [positions.length(link, k) for link in links]
        out = {positions.at[k][i] is None or len(positions.at[k][i]) != 2 for i in pos.agents}
        assert (math.inf in got[0][k]) == (True in out)
