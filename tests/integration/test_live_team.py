"""The live view and the recording's derived channels follow the team (issue 26).

An events run (``scenarios/events.toml``) and a run whose agent 3 is killed mid-run (and
restarted, or not) have,
in their MCAP, exactly one scene, one frames and one metrics message for every epoch, the
agents out listed in the metrics and drawn as out in the scene; ``formation replay
--foxglove`` offers them all again and ``recorder.load_run(...).metrics`` has every epoch.
Every process is ended by PID (the ``runs_dir`` fixture fails the test if one is left).
"""

from __future__ import annotations

import json
import threading
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from formation.scenario import Scenario
from recorder import load_run
from recorder.playback.player import LIVE_KEYS, Replayer
from recorder.reading.decoder import as_dict, decode_kind
from recorder.recording.schemas import classify
from testbed.runtime.launcher import launch
from testbed.runtime.outcome import RunOutcome
from testkit.run_watch import KillAtEpoch

pytestmark = pytest.mark.integration
SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"
EPOCHS, KILL_AT = 60, 20  # the killed run: agent 3 killed at agent 1's state of KILL_AT


def derived(path: Path) -> dict[str, list[Any]]:
    """The recorder's scenes, frames and metrics in the file, in log-time order, decoded."""
    out: dict[str, list[Any]] = {"scene": [], "tf": [], "metrics": []}
    with open(path, "rb") as f:
        for _, ch, msg in make_reader(f).iter_messages(log_time_order=True):
            kind = ch.metadata.get("kind") or classify(ch.topic)
            if kind in ("scene", "tf"):
                out[kind].append(as_dict(decode_kind(kind, msg.data)))
            elif kind == "metrics":
                out[kind].append(json.loads(msg.data))
    return out


def scene_meta(scene: dict[str, Any]) -> dict[str, str]:
    (entity,) = scene["entities"]
    return {m["key"]: m["value"] for m in entity["metadata"]}


def assert_every_epoch_once(outcome: RunOutcome, out_at: list[list[int]]) -> dict[str, list[Any]]:
    """One of each per epoch 0..E in the file, ``out_at[k]`` the agents out at ``k``."""
    s, every = outcome.scenario, list(range(outcome.scenario.epochs + 1))
    got = derived(outcome.run_dir / "run.mcap")
    assert [m["epoch"] for m in got["metrics"]] == every, "one metrics per epoch, in order"
    assert sorted(int(scene_meta(sc)["epoch"]) for sc in got["scene"]) == every
    assert len(got["tf"]) == len(every)
    for m, tf in zip(got["metrics"], got["tf"], strict=True):  # written together
        moved = [[t["translation"]["x"], t["translation"]["y"]] for t in tf["transforms"]]
        assert moved == m["positions"] and len(moved) == s.n
    assert [m.get("out", []) for m in got["metrics"]] == out_at
    for sc in got["scene"]:
        meta = scene_meta(sc)
        out = out_at[int(meta["epoch"])]
        assert meta.get("out", "") == ",".join(map(str, out))
        (entity,) = sc["entities"]
        texts = [t["text"] for t in entity["texts"]]
        assert [t for t in texts if t.endswith(" out")] == [f"{i} out" for i in out]
    # the positions of the agents in, the true states; the errors over the team's edges
    x = outcome.positions
    for k, m in enumerate(got["metrics"]):
        inside = [i for i in range(s.n) if i + 1 not in out_at[k]]
        assert np.array_equal(np.array(m["positions"])[inside], x[k, inside])
    table = load_run(outcome.run_dir / "run.mcap").metrics
    assert table["epoch"].tolist() == every, "load_run: every epoch"
    assert table["agents"].tolist() == [s.n - len(o) for o in out_at]
    np.testing.assert_array_equal(
        table["formation_error_m"], table["recorded_formation_error_m"]
    )  # recomputed from the states = the recorder's live value, to the bit
    return got


def assert_replay_offers_every_epoch(outcome: RunOutcome, got: dict[str, list[Any]]) -> None:
    """``formation replay --foxglove``'s messages (what it hands its LiveServer) cover every epoch."""
    offered: Counter[str] = Counter()
    epochs: list[int] = []

    def offer(key: str, data: bytes, _: Any) -> None:
        kind = classify(key)
        offered[kind] += 1
        if kind == "metrics":
            epochs.append(json.loads(data)["epoch"])

    replayer = Replayer(outcome.run_dir / "run.mcap", rate=1e6, topics=list(LIVE_KEYS))
    state = replayer.run(offer, threading.Event())
    assert state.done and state.skipped == 0
    assert epochs == list(range(outcome.scenario.epochs + 1))  # the live /tf comes from each
    assert offered["scene"] == len(got["scene"])


def test_an_events_run_has_every_epoch_with_who_is_out(runs_dir: Path) -> None:
    scenario = Scenario.from_file(SCENARIOS / "events.toml")
    outcome = launch(scenario, runs_dir=runs_dir)
    published = scenario.membership.published
    out_at = [[int(i) + 1 for i in np.flatnonzero(~row)] for row in published]
    assert out_at[10] == [6] and out_at[30] == [3] and out_at[70] == [5] and out_at[50] == []
    got = assert_every_epoch_once(outcome, out_at)
    assert_replay_offers_every_epoch(outcome, got)


@pytest.mark.parametrize("restart", ["no", "on-failure"])
def test_a_run_with_a_killed_agent_has_every_epoch_with_it_out(
    paper: Scenario, runs_dir: Path, restart: str
) -> None:
    kill = KillAtEpoch(["agent-3"], KILL_AT)
    try:
        outcome = launch(paper.with_overrides(epochs=EPOCHS), runs_dir=runs_dir,
                         on_started=kill.hook(runs_dir), restart=restart)  # type: ignore[arg-type]  # fmt: skip
    finally:
        kill.close()
    assert kill.killed, "the run ended before the kill"
    (loss,) = outcome.summary()["losses"]
    lost, back = loss["epoch"], loss.get("back_from_epoch") or EPOCHS + 1
    # restarted fast enough, it is back from the very epoch it was lost at: never out
    assert KILL_AT - 5 <= lost <= KILL_AT + 5 and lost <= back
    assert (back <= EPOCHS) == (restart == "on-failure")
    out_at = [[3] if lost <= k < back else [] for k in range(EPOCHS + 1)]
    got = assert_every_epoch_once(outcome, out_at)
    body = got["metrics"][lost - 1]["positions"][2]
    assert all(m["positions"][2] == body for m in got["metrics"][lost:back]), "where last seen"
    assert_replay_offers_every_epoch(outcome, got)
