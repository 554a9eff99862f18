"""The launcher's observer reads netem's decision batches as columns: their drops at once,
their rows when the run is over; a batch whose columns do not fit is counted as malformed."""

from __future__ import annotations

import json
import socket
import time

import pytest
import zenoh

from formation import keys
from formation.messages import Decision, DecisionBatch
from formation.scenario import Scenario
from shell.zenoh_config import session_config
from testbed.runtime.observer import Observer, Verdict

pytestmark = pytest.mark.integration
HOST = "127.0.0.1"


def _batch(run_id: str, seq: int) -> DecisionBatch:
    rows = [
        Decision(source=1, target=2, link_class="formation", epoch=seq, seq=seq, verdict="pass"),
        Decision(source=2, target=1, link_class="formation", epoch=seq, seq=seq, verdict="drop",
                 model="bernoulli"),
    ]  # fmt: skip
    head = {"run_id": run_id, "sender": "netem", "seq": seq, "epoch": seq, "stamp_ns": 1}
    return DecisionBatch.of_rows(phase="state", decisions=rows, **head)


def _until(done: object, timeout_s: float = 10.0) -> None:
    """Wait for ``done()`` (the observer's callbacks run on Zenoh's threads)."""
    deadline = time.monotonic() + timeout_s
    while not done():  # type: ignore[operator]
        assert time.monotonic() < deadline, "the observer never got the batches"
        time.sleep(0.01)


def test_the_observer_reads_columns_and_counts_a_batch_that_does_not_fit(paper: Scenario) -> None:
    with socket.socket() as s:
        s.bind((HOST, 0))
        port = s.getsockname()[1]
    session = zenoh.open(session_config("peer", None, f"tcp/{HOST}:{port}"))
    try:
        observer = Observer(session, "obs", paper)
        key = keys.netem_decision("obs")
        session.put(key, _batch("obs", 0).model_dump_json().encode())
        unequal = _batch("obs", 1).model_dump()
        unequal["records"]["seq"].pop()
        session.put(key, json.dumps(unequal).encode())
        past = _batch("obs", 2).model_dump()
        past["records"]["judgement"][0] = 2  # the batch has two judgements
        session.put(key, json.dumps(past).encode())
        _until(lambda: observer.malformed.counts[key] == 2)
        with observer.lock:
            assert observer.drops == 1
            assert observer.decisions == [
                Verdict(1, 2, "formation", 0, 0, "pass", ""),
                Verdict(2, 1, "formation", 0, 0, "drop", "bernoulli"),
            ]
        observer.close()
    finally:
        session.close()
