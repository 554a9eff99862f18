"""A bundle handled at once (netem.proxy.bundle_pass), its messages as the escaped JSON strings
they came in, puts out what its parts one by one do: the same deliveries in the same order,
the same records, counts and last states, on clean and lossy links,
with pools of any size sending in any order, a sender dying or a state coming twice."""

from __future__ import annotations

from functools import cache
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from formation.keys import LEADER_ENDPOINT
from formation.scenario import Scenario
from netem.proxy.bundle_pass import BundlePass
from netem.proxy.lockstep import LockstepCore
from netem.proxy.progress import Progress
from netem.proxy.records import Escaped, Ledger, message_json
from netem.proxy.routes import Links, Phase, Route
from testbed.sim.team_generators import henneberg_team
from testkit.lockstep_wire import Wire, receivers

EPOCHS = 4
NETWORKS: list[dict[str, Any]] = [
    {},
    {"formation_default": [{"model": "bernoulli", "p_loss": 0.3}]},
    {"formation_default": [{"model": "delay", "jitter_epochs": 1}]},
]


@cache
def _team(n: int, network: int) -> Scenario:
    return henneberg_team(n, epochs=EPOCHS, network=NETWORKS[network])


def _core(scenario: Scenario, seed: int) -> tuple[LockstepCore, Wire]:
    links, wire = Links(scenario, seed), Wire(receivers(scenario))
    progress = Progress(links.agents, scenario.epochs, lambda: None)
    return LockstepCore(links, scenario.epochs, progress, Ledger(), wire), wire


def _payload(phase: Phase, agent: int, epoch: int) -> bytes:
    return b'{"phase":"%s","agent":%d,"epoch":%d}' % (phase.encode(), agent, epoch)


def _bundles(
    pools: list[list[int]], n: int, order: list[int]
) -> list[tuple[Phase, int, list[int]]]:
    """Every bundle of the run, an epoch's states, reports and estimates in turn, the
    pools in ``order``; the final states last."""
    out: list[tuple[Phase, int, list[int]]] = []
    for k in range(EPOCHS):
        out += [("state", k, pools[p]) for p in order]
        out += [("report", k, pools[p]) for p in order]
        out.append(("estimate", k, list(range(1, n + 1))))
    return out + [("state", EPOCHS, pools[p]) for p in order]


def _run(scenario: Scenario, seed: int, bundles: list[tuple[Phase, int, list[int]]],
         at_once: bool, dies: tuple[int, int] | None, twice: int | None,
         estimates_at_once: int = 32) -> tuple[Any, ...]:  # fmt: skip
    core, wire = _core(scenario, seed)
    bundle = BundlePass(core, estimates_at_once).bundle
    for b, (phase, epoch, agents) in enumerate(bundles):
        if dies is not None and dies[0] == b:
            core.sender_died(dies[1])
        sent = agents if twice != b else [*agents, agents[0]]
        seqs = [epoch] * len(sent)
        payloads = [_payload(phase, a, epoch) for a in sent]
        if at_once:  # as the node reads a bundle: each message as the JSON string it came in
            bundle(phase, epoch, sent, seqs, [Escaped(message_json(p)) for p in payloads])
            continue
        for a, seq, payload in zip(sent, seqs, payloads, strict=True):
            route: Route = (phase, LEADER_ENDPOINT, a) if phase == "estimate" else (phase, a, 0)
            core.packet(route, epoch, seq, payload)
    core.flush()
    deliveries = [d.model_dump() for d in wire.deliveries]
    decisions = [d.model_dump() for d in wire.decisions]
    last = {
        a: (k, p if type(p) is bytes else p.to_bytes()) for a, (k, p) in core.last_state.items()
    }
    done = core.progress.estimates_done
    return deliveries, decisions, core.forwarded(), done, core.finished(), last


@settings(max_examples=20, deadline=None)
@given(
    n=st.integers(3, 9),
    pools=st.integers(1, 4),
    network=st.sampled_from(range(len(NETWORKS))),
    seed=st.integers(0, 2**16),
    order=st.randoms(use_true_random=False),
    dies=st.none() | st.tuples(st.integers(0, 20), st.integers(1, 3)),
    twice=st.none() | st.integers(0, 20),
    estimates_at_once=st.integers(1, 10),
)
def test_a_bundle_at_once_equals_its_parts_one_by_one(
    n: int,
    pools: int,
    network: int,
    seed: int,
    order: Any,
    dies: Any,
    twice: int | None,
    estimates_at_once: int,
) -> None:
    scenario = _team(n, network)
    ids = list(range(1, n + 1))
    split = [ids[p::pools] for p in range(min(pools, n))]
    turn = list(range(len(split)))
    order.shuffle(turn)
    bundles = _bundles(split, n, turn)
    one_by_one = _run(scenario, seed, bundles, False, dies, twice)
    at_once = _run(scenario, seed, bundles, True, dies, twice, estimates_at_once)
    assert at_once == one_by_one


def test_a_clean_run_takes_every_bundle_at_once_and_a_duplicate_goes_one_by_one() -> None:
    scenario = henneberg_team(6, epochs=EPOCHS)
    core, wire = _core(scenario, 1)
    bundles = BundlePass(core)
    pools = [[1, 2, 3], [4, 5, 6]]
    for phase in ("state", "report"):
        for agents in pools:
            payloads = [_payload(phase, a, 0) for a in agents]
            assert bundles.take(phase, 0, agents, [0] * 3, payloads)
    assert not bundles.take("state", 0, [1], [0], [_payload("state", 1, 0)])  # came before
    agents = list(range(1, 7))
    payloads = [_payload("estimate", a, 0) for a in agents]
    assert not bundles.take("estimate", 0, [1, 1], [0, 0], payloads[:2])  # twice in one bundle
    assert bundles.take("estimate", 0, agents, [0] * 6, payloads)
    assert core.progress.estimates_done == 1
    assert len(wire.deliveries) == 6 + 1 + 6  # every receiver of every phase closed
