"""The launcher's observer: CPU an epoch on what a pooled lockstep run sends it.

Run ``python -m bench.bench_observer [--agents N] [--pools P] [--epochs E]``.

The messages are what the run sends, built as its processes build them: each pool's states of
an epoch as one bundle (``agent.node.state_message``, positions from ``formation simulate``,
one neighbour in ten substituted), and netem's decisions of each epoch's state phase as one
batch (one drop in ten). Measured in one process, alternating:

- **baseline**: every message read as it comes, a bundle part by part (as a bundle with a
  doubtful part still is);
- **observer**: what :class:`testbed.runtime.observer.Observer` does on arrival (states kept as
  they came, drops counted from the judgement column), and apart, what reading the states
  costs once asked (``settle``, a bundle whole).
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np
import orjson
import zenoh

from agent.node import state_message
from formation import keys
from shell import session_config
from testbed.runtime.observed_states import read_parts, read_state
from testbed.runtime.observer import Observer
from testbed.sim.simulate import simulate
from testbed.sim.team_generators import henneberg_team

SEED = 1
RUN = "bench"


class _Payload:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


class _Sample:
    """What the observer takes of a Zenoh sample."""

    def __init__(self, key: str, data: bytes) -> None:
        self.key_expr, self.payload, self.attachment = key, _Payload(data), None


def messages(agents: int, pools: int, epochs: int) -> tuple[Any, list[tuple[str, _Sample]]]:
    """The scenario and, epoch by epoch, each pool's state bundle and netem's decision batch."""
    scenario = henneberg_team(agents, epochs=epochs)
    positions = simulate(scenario, seed=SEED).positions
    rng = np.random.default_rng(SEED)
    links = scenario.directed_links
    out: list[tuple[str, _Sample]] = []
    judgements = [{"verdict": "pass", "delay_epochs": 0, "delay_ms": 0.0, "model": "", "state": ""},
                  {"verdict": "drop", "delay_epochs": 0, "delay_ms": 0.0, "model": "bernoulli",
                   "state": ""}]  # fmt: skip
    for k in range(epochs + 1):
        dropped = rng.random(len(links)) < 0.1
        for ids in np.array_split(np.arange(1, agents + 1), pools):
            parts = []
            for i in ids.tolist():
                lost = links[(links[:, 1] == i) & dropped][:, 0].tolist() if k else []
                subs = [(j, positions[k - 1, j - 1].tolist(), False) for j in lost]
                head = {"run_id": RUN, "sender": f"pool/{ids[0]}", "seq": k, "epoch": k,
                        "stamp_ns": 1}  # fmt: skip
                msg = state_message(head, i, positions[k, i - 1].tolist(), subs)
                parts.append({"agent": i, "seq": k, "message": msg.decode()})
            key = keys.pool_states(RUN, int(ids[0]))
            bundle = {"run_id": RUN, "sender": f"pool/{ids[0]}", "seq": k, "epoch": k,
                      "stamp_ns": 1, "kind": "bundle", "phase": "state", "parts": parts}  # fmt: skip
            out.append(("state", _Sample(key, orjson.dumps(bundle))))
        records = {"source": links[:, 0].tolist(), "target": links[:, 1].tolist(),
                   "epoch": [k] * len(links), "seq": [k] * len(links),
                   "judgement": dropped.astype(int).tolist()}  # fmt: skip
        batch = {"run_id": RUN, "sender": "netem", "seq": k, "epoch": k, "stamp_ns": 1,
                 "kind": "decisions", "phase": "state", "judgements": judgements,
                 "records": records}  # fmt: skip
        out.append(("decisions", _Sample(keys.netem_decision(RUN), orjson.dumps(batch))))
    return scenario, out


def baseline(observer: Observer, stream: list[tuple[str, _Sample]]) -> None:
    """Every message read as it comes: a bundle part by part, a batch's columns whole."""
    kept = []
    for kind, sample in stream:
        data = sample.payload.to_bytes()
        if kind == "decisions":
            batch = orjson.loads(data)
            judged = [(str(j["verdict"]), str(j.get("model", ""))) for j in batch["judgements"]]
            records = batch["records"]
            kept.append(tuple(records[c] for c in ("source", "target", "epoch", "seq")))
            index = np.array(records["judgement"], dtype=np.int64)
            if not all(len(c) == len(index) for c in kept[-1]):
                raise SystemExit("a batch of unequal columns")
            dropped = np.array([v == "drop" for v, _ in judged], dtype=bool)
            observer.drops += int(dropped[index].sum())
            continue
        first = int(keys.parse(sample.key_expr).args[0])
        for i, message in read_parts(data, first) or []:
            state = read_state(message, str(i), observer.bounds)
            if state is not None:
                observer._keep(state, 0.0)


def measure(
    scenario: Any, stream: list[tuple[str, _Sample]], session: zenoh.Session
) -> tuple[float, float, float, int, int]:
    """CPU s of the baseline, of the observer on arrival, of its settling; the drops both saw."""
    old = Observer(session, RUN, scenario)
    start = time.process_time()
    baseline(old, stream)
    base_s = time.process_time() - start
    new = Observer(session, RUN, scenario)
    start = time.process_time()
    for kind, sample in stream:
        (new._on_states if kind == "state" else new._on_decisions)(sample)  # type: ignore[arg-type]
    arrive_s = time.process_time() - start
    start = time.process_time()
    new.settle()
    settle_s = time.process_time() - start
    same = np.array_equal(old.positions, new.positions, equal_nan=True)
    same = same and old.substitutions == new.substitutions and not new.malformed.counts
    if not same:
        raise SystemExit("the observer kept other states than reading them one by one")
    old.close()
    new.close()
    return base_s, arrive_s, settle_s, old.drops, new.drops


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--agents", type=int, default=1000)
    parser.add_argument("--pools", type=int, default=8)
    parser.add_argument("--epochs", type=int, default=40)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args(argv)
    scenario, stream = messages(args.agents, args.pools, args.epochs)
    kib = sum(len(s.payload.to_bytes()) for _, s in stream) / 1024 / (args.epochs + 1)
    print(f"seed {SEED}; henneberg_team({args.agents}) in {args.pools} pools, {args.epochs} epochs, "
          f"{kib:.0f} KiB an epoch to the observer; CPU ms an epoch, alternating, baseline: each "
          "message read as it comes, a bundle part by part")  # fmt: skip
    print(
        f"{'round':>5} {'baseline':>9} {'on arrival':>11} {'ratio':>6} {'settle':>7} {'ratio':>6}"
    )
    with zenoh.open(session_config("peer", None, None)) as session:
        for r in range(args.rounds):
            base_s, arrive_s, settle_s, drops, seen = measure(scenario, stream, session)
            if drops != seen:
                raise SystemExit(f"drops: {seen} counted, {drops} in the batches")
            per = 1e3 / (args.epochs + 1)
            print(f"{r + 1:>5} {base_s * per:9.2f} {arrive_s * per:11.2f} "
                  f"{arrive_s / base_s:6.3f} {settle_s * per:7.2f} {settle_s / base_s:6.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
