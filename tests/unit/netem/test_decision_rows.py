"""A phase's rows of decisions, taken a block at a time, are each link's ``decide``; the
columns built from a row's template are the records encoded one by one."""

from __future__ import annotations

from formation.linkmodels import Bernoulli, Delay, Duplicate, GilbertElliott, Range
from formation.messages import DecisionBatch, decision_rows
from netem.links.models import LinkModel
from netem.proxy.decision_rows import DecisionRows, Stream
from netem.proxy.records import RecordTemplates, batch_body, decision_batch_of, records_body


def streams(seed: int = 7) -> dict[int, Stream]:
    stacks = {
        2: [Bernoulli(p_loss=0.2)],
        3: [GilbertElliott(p=0.05, r=0.3), Duplicate(p=0.1)],
        4: [Delay(epochs=0, jitter_epochs=1)],
    }
    links = tuple(("formation", 1, d) for d in stacks)
    models = tuple(LinkModel(stacks[d], seed, 1, d, block_epochs=50) for d in stacks)
    return {1: Stream(links, tuple(stacks), models)}


def test_each_epochs_row_is_every_links_decision() -> None:
    s = streams()
    rows = DecisionRows(s, block=64)
    for k in range(300):
        row, reach = rows.row(1, k)
        assert reach is None
        assert row.decisions == tuple(m.decide(k) for m in s[1].models), k


def test_a_changed_model_is_decided_again_once_invalidated() -> None:
    s = streams()
    rows = DecisionRows(s, block=64)
    rows.row(1, 10)
    s[1].models[0].replace([Bernoulli(p_loss=1.0)], from_epoch=20)
    rows.invalidate()
    for k in range(64):
        row, _ = rows.row(1, k)
        assert row.decisions[0] == s[1].models[0].decide(k)
        assert row.decisions[0].verdict == ("drop" if k >= 20 else row.decisions[0].verdict)


def test_a_distance_models_row_is_before_its_layer_with_each_links_reach() -> None:
    model = LinkModel([Bernoulli(p_loss=0.3), Range(max_range_m=5.0)], 7, 1, 2)
    rows = DecisionRows({1: Stream((("formation", 1, 2),), (2,), (model,))}, block=64)
    assert rows.ranged[1]
    for k in range(100):
        row, reach = rows.row(1, k)
        assert reach == [5.0]
        assert row.decisions[0] == model.decide(k, distance_m=1.0)  # within reach


def test_records_by_template_are_those_encoded_one_by_one() -> None:
    s = streams()
    rows = DecisionRows(s, block=64)
    templates = RecordTemplates({1: s[1].links})
    by_template, one_by_one = [], []
    for k in range(200):
        row, _ = rows.row(1, k)
        decisions = [d for d in row.decisions if d is not None]
        skipped = k % 3  # a link not recorded with the others (its receiver out)
        ids = tuple(
            -1 if i == skipped else templates.judgement_id(d) for i, d in enumerate(decisions)
        )
        by_template.append((k, [(templates.template(1, ids), 50 + k)]))
        one_by_one += [
            (src, dst, cls, k, 50 + k, d)
            for i, ((cls, src, dst), d) in enumerate(zip(s[1].links, decisions, strict=True))
            if i != skipped
        ]
    header = {"run_id": "r", "sender": "netem", "seq": 0, "epoch": 199, "stamp_ns": 1}
    got = DecisionBatch.model_validate_json(
        decision_batch_of(header, batch_body("state", templates.judgements, by_template))
    )
    want = DecisionBatch.model_validate_json(
        decision_batch_of(header, records_body("state", one_by_one))
    )
    assert decision_rows(got) == decision_rows(want)
    assert len(got.judgements) == len(set(got.judgements))  # each judgement once
