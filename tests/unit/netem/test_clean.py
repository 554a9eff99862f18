"""netem's clean epochs: the vectorised verdicts and spliced records equal the per-packet ones."""

from __future__ import annotations

from formation.linkmodels import Bernoulli, Delay, GilbertElliott, Outage
from formation.messages import DecisionBatch
from netem.links.models import LinkModel
from netem.proxy.clean_epochs import CleanEpochs, CleanStream
from netem.proxy.records import decision_batch, decision_batch_of

HEADER = {"run_id": "r", "sender": "netem", "seq": 0, "epoch": 0, "stamp_ns": 1}


def streams() -> dict[int, CleanStream]:
    stacks = {
        (1, 2): [Bernoulli(p_loss=0.05)],
        (1, 3): [GilbertElliott(p=0.01, r=0.5)],  # a state in every record, loss rare
        (2, 1): [Outage(start=300, end=320)],
        (3, 1): [Delay(epochs=0, jitter_epochs=1)],
    }
    out: dict[int, CleanStream] = {}
    for src in (1, 2, 3):
        links = [("formation", s, d) for s, d in stacks if s == src]
        models = [LinkModel(stacks[(s, d)], 7, s, d) for _, s, d in links]
        out[src] = CleanStream(tuple(links), (), tuple(models))
    return out


def test_clean_epochs_are_those_where_every_link_passes() -> None:
    ce = CleanEpochs(streams(), {}, block=64)
    models = [m for s in ce.streams.values() for m in s.models]
    flags = [ce.clean(k) for k in range(700)]
    assert flags == [all(m.decide(k).verdict == "pass" for m in models) for k in range(700)]
    assert 0 < sum(flags) < 700 and not any(flags[300:320])


def test_finished_epochs_encode_exactly_their_records() -> None:
    ce = CleanEpochs(streams(), {}, block=64)
    clean = [k for k in range(400) if ce.clean(k)]
    expected = []
    for k in clean:
        got = {1: 10 * k, 3: 10 * k + 3, 2: 10 * k + 2}  # arrival order, any seq
        ce.finish(k, got)
        expected.extend(record for record, _ in ce.records(k, got))
    assert ce.done == set(clean) and ce.last_done == clean[-1]
    batch = decision_batch_of(HEADER, "state", ce.chunks)
    assert batch == decision_batch(HEADER, "state", expected)
    parsed = DecisionBatch.model_validate_json(batch)
    assert {d.state for d in parsed.decisions} >= {"good"}
    assert {d.verdict for d in parsed.decisions} == {"pass"}


def test_a_changed_model_is_seen_after_invalidate() -> None:
    ss = streams()
    ce = CleanEpochs(ss, {}, block=64)
    assert ce.clean(100) or ce.clean(101)
    for s in ss.values():
        for m in s.models:
            m.replace([Bernoulli(p_loss=1.0)], 90)
    ce.invalidate()
    assert not any(ce.clean(k) for k in range(90, 200))


def test_an_epoch_marked_slow_stays_unclean_after_its_block_is_computed_again() -> None:
    ce = CleanEpochs(streams(), {}, block=64)
    k = next(k for k in range(64) if ce.clean(k))
    ce.mark_slow(k)
    assert not ce.clean(k)
    for far in (64, 128, 192):  # evicts the first block
        ce.clean(far)
    assert k not in ce.flags and not ce.clean(k)


def test_a_receiver_gets_its_delivery_once_all_its_senders_packets_are_in() -> None:
    links = {1: [("formation", 1, 2), ("formation", 1, 3)], 2: [("formation", 2, 3)]}
    ss = {
        s: CleanStream(tuple(ls), tuple(d for _, _, d in ls), tuple(LinkModel([], 7, s, d) for _, s, d in ls))
        for s, ls in links.items()
    }  # fmt: skip
    ce = CleanEpochs(ss, {2: 1, 3: 2}, block=64)
    got: list[tuple[int, int, int]] = []

    def deliver(receiver: int, epoch: int, packets: list[bytes]) -> None:
        got.append((receiver, epoch, len(packets)))

    assert ce.clean(5) and not ce.take(1, 5, 50, b"{}", deliver)
    assert got == [(2, 5, 1)] and ce.gathering[5].delivered == {2}
    assert not ce.take(1, 5, 51, b"{}", deliver)  # a second packet of stream 1: ignored
    assert ce.take(2, 5, 52, b"{}", deliver)  # the epoch's last packet
    assert got == [(2, 5, 1), (3, 5, 2)] and 5 not in ce.gathering and ce.done == {5}
    assert ce.chunks and ce.go_slow(5) is None  # finished: nothing left to hand back
    ce.take(1, 6, 60, b"{}", deliver)
    g = ce.go_slow(6)
    assert g is not None and g.seqs == {1: 60} and g.delivered == {2} and g.waiting.keys() == {3}
    assert not ce.clean(6)
