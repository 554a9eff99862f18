"""How the launcher settles a lost agent from what was recorded (issue 20), without processes.

The launcher notices a dead process between epochs, possibly before the process's last
state has reached it; the recorded states and netem's word on the epoch a restarted agent
takes part from decide the loss epoch and the first epoch back.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import orjson

from testbed.runtime.faults import Loss, Supervisor
from testbed.runtime.processes import ProcessGroup


def supervisor_with(loss: Loss) -> Supervisor:
    sup = Supervisor(ProcessGroup(Path("unused")), "on-failure", started=100.0)
    sup.losses.append(loss)
    return sup


def seen_of(n_epochs: int, agent_epochs: list[int]) -> np.ndarray:
    seen = np.ones((n_epochs + 1, 3), dtype=bool)
    seen[:, 2] = False
    seen[agent_epochs, 2] = True
    return seen


def test_a_last_state_that_came_after_the_loss_was_seen_moves_the_loss_epoch() -> None:
    loss = Loss("agent-3", pid=1, code=-9, epoch=7, after_start_s=1.0)  # seen gone at 7
    sup = supervisor_with(loss)
    sup.note_returns(seen_of(20, list(range(8))), {})  # yet its state of 7 came in later
    assert loss.epoch == 8 and loss.back_from_epoch is None


def test_the_first_epoch_back_is_the_one_netem_gave_not_a_late_state_before_it() -> None:
    loss = Loss("agent-3", pid=1, code=-9, epoch=7, after_start_s=1.0, restarted_pid=2)
    sup = supervisor_with(loss)
    seen = seen_of(20, [*range(8), *range(10, 21)])  # state 7 came late; back from 10
    events = [
        (99.0, orjson.dumps({"event": "back agent 3", "back": {"3": 4}}).decode()),  # earlier
        (101.5, "not JSON"),
        (101.6, orjson.dumps({"event": "back agent 3", "back": {"3": 10}}).decode()),
    ]
    sup.note_returns(seen, {3: (10, 102.0)}, events)
    assert (loss.epoch, loss.back_from_epoch) == (8, 10)
    assert loss.back_after_s == 1.0


def test_back_with_no_gap_when_netem_gave_the_next_epoch() -> None:
    loss = Loss("agent-3", pid=1, code=-9, epoch=7, after_start_s=1.0, restarted_pid=2)
    sup = supervisor_with(loss)
    events = [(101.2, orjson.dumps({"event": "back agent 3", "back": {"3": 8}}).decode())]
    # The observer marks the new process's first state (seq 0), gap or not.
    sup.note_returns(seen_of(20, list(range(21))), {3: (8, 101.5)}, events)
    assert (loss.epoch, loss.back_from_epoch) == (8, 8)
    assert loss.back_after_s == 0.5, "bench_faults printed 'rejoin time None' without it"


def test_a_loss_while_starting_up_is_timed_before_the_start_and_back_from_epoch_0() -> None:
    sup = Supervisor(ProcessGroup(Path("unused")), "on-failure", started=90.0)
    loss = Loss("agent-3", pid=1, code=-9, epoch=0, after_start_s=8.0, restarted_pid=2)
    sup.losses.append(loss)  # seen dead at 98.0, before the run's start at 100.0
    sup.begin(100.0)
    assert loss.after_start_s == -2.0
    sup.note_returns(seen_of(20, list(range(21))), {3: (0, 101.0)})  # no netem word: no rejoin
    assert (loss.epoch, loss.back_from_epoch, loss.back_after_s) == (0, 0, 3.0)


def test_without_netem_s_word_the_first_state_after_the_gap_is_back() -> None:
    loss = Loss("agent-3", pid=1, code=-9, epoch=7, after_start_s=1.0, restarted_pid=2)
    sup = supervisor_with(loss)
    sup.note_returns(seen_of(20, [*range(8), *range(12, 21)]), {})
    assert (loss.epoch, loss.back_from_epoch) == (8, 12)
