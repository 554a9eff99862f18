"""The launcher's observer keeps the states as they came and reads them when asked: a pool's
bundle whole, one with a bad part part by part (the bad part counted, the others kept), one that
is no bundle counted; in lockstep the whole estimate's attachment says an epoch is done."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import orjson
import pytest
import zenoh

import testbed.runtime.observer as observer_module
from formation import keys
from formation.codec import attachment
from formation.scenario import Scenario
from shell.zenoh_config import session_config
from testbed.runtime.observer import Observer

pytestmark = pytest.mark.integration
HOST = "127.0.0.1"
RUN = "obs"


def _until(done: Callable[[], bool], timeout_s: float = 10.0) -> None:
    """Wait for ``done()`` (the observer's callbacks run on Zenoh's threads)."""
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, "the observer never got the messages"
        time.sleep(0.01)


def _state(agent: int, epoch: int, **changed: Any) -> str:
    msg = {"run_id": RUN, "sender": "pool/1", "seq": epoch, "epoch": epoch, "stamp_ns": 1,
           "kind": "state", "agent": agent, "position": [float(agent), float(epoch)],
           "velocity": None, "substituted": []}  # fmt: skip
    return orjson.dumps({**msg, **changed}).decode()


def _bundle(messages: dict[int, str]) -> bytes:
    parts = [{"agent": i, "seq": 0, "message": m} for i, m in messages.items()]
    head = {"run_id": RUN, "sender": "pool/1", "seq": 0, "epoch": 0, "stamp_ns": 1}
    return orjson.dumps({**head, "kind": "bundle", "phase": "state", "parts": parts})


def test_states_are_read_when_asked_bad_parts_counted(paper: Scenario) -> None:
    with socket.socket() as s:
        s.bind((HOST, 0))
        port = s.getsockname()[1]
    session = zenoh.open(session_config("peer", None, f"tcp/{HOST}:{port}"))
    try:
        observer = Observer(session, RUN, paper)
        pool = keys.pool_states(RUN, 1)
        subs = [{"neighbour": 2, "value": [0.5, 0.5], "fallback": True}]
        session.put(pool, _bundle({1: _state(1, 0), 2: _state(2, 0), 3: _state(3, 0)}))
        bad = _state(2, 1, position=[1.0])  # of the wrong dimension
        session.put(pool, _bundle({1: _state(1, 1, substituted=subs), 2: bad, 3: _state(3, 1)}))
        session.put(pool, b"not a bundle")
        session.put(keys.agent_state(RUN, 4), _state(4, 1).encode())
        whole = keys.leader_estimate_out(RUN)
        session.put(whole, b"{}", attachment=attachment(0, 0, 0))
        _until(lambda: observer.estimated == {0} and np.isfinite(observer.positions[1, 3, 0]))
        with observer.lock:
            assert observer.malformed.counts[pool] == 2
            seen = np.isfinite(observer.positions[:2, :4, 0])
            assert seen.tolist() == [[True, True, True, False], [True, False, True, True]]
            assert observer.positions[1, 0].tolist() == [1.0, 1.0]
            assert observer.substitutions == [(0, 1, 2, [0.5, 0.5])]
            assert observer.fallbacks == 1 and observer.fallback_epochs == {0: 1}
            assert {i: k for i, (k, _) in observer.returns.items()} == {1: 0, 2: 0, 3: 0, 4: 1}
        observer.close()
    finally:
        session.close()


def test_states_past_the_bound_are_read_as_they_come(
    paper: Scenario, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What is kept unread stays bounded: past ``PENDING_BYTES`` the states are read at once."""
    monkeypatch.setattr(observer_module, "PENDING_BYTES", 1)
    session = zenoh.open(session_config("peer", None, None))
    try:
        observer = Observer(session, RUN, paper)
        session.put(keys.pool_states(RUN, 1), _bundle({1: _state(1, 0), 2: _state(2, 0)}))
        _until(lambda: np.isfinite(observer._positions[0, 1, 0]))  # nobody asked
        assert not observer._pending
        observer.close()
    finally:
        session.close()
