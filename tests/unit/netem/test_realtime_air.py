"""Realtime on the air: a phase decided once for every packet that came since the last
settle, its delivered packets settled in order of the model's arrival."""

from __future__ import annotations

import orjson

from formation.scenario import Scenario
from netem.links.air_network import AirNetwork
from netem.proxy.realtime_air import RealtimeAir


class Counting(AirNetwork):
    """The air network, counting its phase decisions."""

    decisions = 0

    def phase(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        self.decisions += 1
        return super().phase(*args, **kwargs)


def test_packets_settle_in_order_of_arrival_after_one_decision_per_settle(
    paper: Scenario,
) -> None:
    network = paper.network.model_dump(by_alias=True)
    network["access_point"] = [0.0, 0.0]
    network["air"] = {"links": "all"}
    net = Counting(paper.with_overrides(epochs=5, network=network), 1)
    air = RealtimeAir(net)
    for i, x in enumerate(paper.initial_positions(1), start=1):
        air.read_position(0, i, orjson.dumps({"position": x.tolist()}))
    t0, ms = 10**12, 10**6  # [ns]
    for link in [(5, 1), (4, 1), (3, 1), (2, 1)]:  # together: their backoffs order them
        air.add(0, "report", link, t0, t0 + 20 * ms, link[0])
    assert air.next_ns() == 0  # to decide
    assert air.settle(t0) == [] and net.decisions == 1
    first = air.next_ns()
    assert first is not None and t0 < first < t0 + 20 * ms
    got = air.settle(t0 + 10 * ms) + air.settle(t0 + 20 * ms)
    assert net.decisions == 1  # nothing came: not decided again
    times = [at for _, _, at in got]
    assert times == sorted(times) and times[0] == first  # by arrival ...
    assert [item for item, _, _ in got] == [4, 5, 2, 3]  # ... not as they came
    assert not air.open
