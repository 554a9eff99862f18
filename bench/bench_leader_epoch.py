"""The leader process's epoch on real messages: CPU per epoch against its math core, and old/new.

``python -m bench.bench_leader_epoch [--loss P] [--capture DIR] [--rounds R] [--base REV]
[--profile]``.

The lockstep run of 1,000 agents pooled in 8 (``henneberg_team(1000)``, seed 1, the case of
``bench/bench_runtime.py``; ``--loss``: every formation link drops that share, Bernoulli) is
recorded once into ``DIR`` (default ``runs/leader-epoch``, or ``runs/leader-epoch-loss-P``):
netem's report delivery to the leader each epoch, and the leader's two outputs. The leader
of that run is then replayed on an in-memory bus, epoch after epoch, as its process runs
it: each delivery filed by its inbox, the reports taken and estimated, the estimate and the
agents' bundle built and put. What it puts is checked against what the run's leader put
(every field but the times). Printed: the replay's CPU ms an epoch (best of ``R`` rounds)
against the baseline in the same run, the leader's math alone (``Leader.epochs`` with its
covariances, as the simulator runs it, on the same epochs' measurements): the rest is the
wire's share.

``--base REV`` replays the same messages with the leader of commit ``REV`` too (its tree
from ``git archive``), alternating with this tree round by round, and prints the ratio.
``--profile`` prints cProfile's top functions of one round of this tree.
"""

from __future__ import annotations

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # before numpy: one core, comparable numbers

import argparse
import cProfile
import gc
import json
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
SEED = 1
AGENTS, POOLS = 1000, 8
CAPTURED_EPOCHS = 14
WARM_EPOCHS = 2
REPLAYS = 3  # replays in each child of --base, the best kept  # the first epochs build caches: left out of the times
OUTPUTS = ("estimate", "estimates")  # the leader's two keys, by their last part


def _tail(topic: str) -> str:
    return topic.rsplit("/", 2)[-2] + "/" + topic.rsplit("/", 1)[-1]


def _scenario(agents: int, epochs: int, p_loss: float) -> Any:
    """The case: ``henneberg_team(agents)``, each formation link dropping ``p_loss`` (Bernoulli)."""
    from testbed.sim.team_generators import henneberg_team

    if not p_loss:
        return henneberg_team(agents, epochs=epochs)
    lossy = {"formation_default": [{"model": "bernoulli", "p_loss": p_loss}]}
    return henneberg_team(agents, epochs=epochs, network=lossy)


def capture(folder: Path, p_loss: float) -> None:
    """Run the lockstep case once, recorded, and keep what the leader took and put."""
    from mcap.reader import make_reader

    from testbed.runtime.launcher import launch

    scenario = _scenario(AGENTS, CAPTURED_EPOCHS, p_loss)
    with tempfile.TemporaryDirectory() as tmp:
        out = launch(scenario, seed=SEED, runs_dir=Path(tmp), record=True, pool=POOLS)
        wanted = {"0/report": "reports", "leader/estimate": "estimate"}
        wanted["leader/estimates"] = "estimates"
        kept: dict[str, list[bytes]] = {name: [] for name in wanted.values()}
        with (out.run_dir / "run.mcap").open("rb") as f:
            for _, channel, message in make_reader(f).iter_messages(log_time_order=True):
                name = wanted.get(_tail(channel.topic))
                if name is not None:
                    kept[name].append(message.data)
    folder.mkdir(parents=True, exist_ok=True)
    for name, payloads in kept.items():
        (folder / f"{name}.jsonl").write_bytes(b"".join(p + b"\n" for p in payloads))
    meta = {"run_id": out.run_id, "agents": AGENTS, "epochs": CAPTURED_EPOCHS, "seed": SEED}
    meta["p_loss"] = p_loss
    (folder / "meta.json").write_text(json.dumps(meta))


def _load(folder: Path) -> tuple[dict[str, Any], dict[str, list[bytes]]]:
    meta = json.loads((folder / "meta.json").read_text())
    names = ("reports", *OUTPUTS)
    return meta, {n: (folder / f"{n}.jsonl").read_bytes().splitlines() for n in names}


def _without_times(payload: bytes | str) -> Any:
    """A message's fields without ``stamp_ns``, a bundle's parts' messages likewise."""
    msg = json.loads(payload)
    msg.pop("stamp_ns", None)
    if msg.get("kind") == "bundle":
        msg["parts"] = [{**p, "message": _without_times(p["message"])} for p in msg["parts"]]
    return msg


def _measurements(scenario: Any, delivery: bytes) -> tuple[Any, Any]:
    """``known`` (L,) and ``z`` (L, d) of one report delivery, as the leader reads them."""
    import numpy as np

    links = scenario.directed_links
    row = {(a, b): r for r, (a, b) in enumerate(links.tolist())}
    known, z = np.zeros(len(links), dtype=bool), np.zeros((len(links), scenario.dimension))
    for packet in json.loads(delivery)["packets"]:
        report = json.loads(packet["message"])
        for m in report["measurements"]:
            at = row.get((m["neighbour"], report["agent"]))
            if at is not None and m["token"] == 1 and m.get("z") is not None:
                known[at], z[at] = True, m["z"]
    return known, z


def replay(folder: Path, rounds: int, profile: bool) -> dict[str, Any]:
    """The leader of this interpreter's tree on the captured messages: CPU s an epoch per
    round, the math's alone, and whether its outputs equal the run's."""
    import numpy as np

    from formation import keys
    from formation.scenario import Scenario
    from leader.node import LeaderNode
    from shell import Lockstep, MemoryBus, Service, settle_heap
    from shell.service import Incoming

    meta, captured = _load(folder)
    scenario: Scenario = _scenario(meta["agents"], meta["epochs"], meta.get("p_loss", 0.0))
    run_id = meta["run_id"]
    inbox_key = keys.inbox(run_id, keys.LEADER_ENDPOINT, "report")
    reports = captured["reports"]
    times, math_times, same = [], [], True
    stats = None
    for r in range(rounds):
        bus = MemoryBus()
        Service(bus, run_id, "netem", 0).announce()
        service = Service(bus, run_id, "leader", 0, start_timeout_s=5)
        node = LeaderNode(service, scenario)
        put: dict[str, list[bytes]] = {name: [] for name in OUTPUTS}
        for name, key in zip(
            OUTPUTS, (keys.leader_estimate_out(run_id), keys.leader_estimates(run_id)), strict=True
        ):
            bus.declare_subscriber(key, lambda s, got=put[name]: got.append(s.payload.to_bytes()))
        node.rehearse()
        inbox = Lockstep().inbox(service, [keys.LEADER_ENDPOINT], node.deadline)
        node.inbox = inbox
        loop = node._epochs(inbox)
        waiting = [next(loop)]

        def deliver(payload: bytes, loop: Any = loop, inbox: Any = inbox, w: Any = waiting) -> None:
            inbox.route(Incoming(inbox_key, payload, None))
            try:
                while w[0].complete():
                    w[0] = loop.send(False)
            except StopIteration:
                pass

        for payload in reports[:WARM_EPOCHS]:
            deliver(payload)
        settle_heap()  # as the process does once it has joined the run
        prof = cProfile.Profile() if profile and r == 0 else None
        start = time.process_time()
        if prof is not None:
            prof.enable()
        for payload in reports[WARM_EPOCHS:]:
            deliver(payload)
        if prof is not None:
            prof.disable()
            stats = prof
        times.append((time.process_time() - start) / (len(reports) - WARM_EPOCHS))
        if r == 0:
            for name in OUTPUTS:
                got, want = put[name], captured[name]
                same = same and [_without_times(p) for p in got] == [
                    _without_times(p) for p in want
                ]
        # the baseline: the leader's math alone on the same measurements
        from leader.epoch import Leader
        from leader.rigidity import HealthyRigidity

        leader = Leader(scenario, HealthyRigidity(scenario.offsets, scenario.edge_array))
        inputs = [_measurements(scenario, payload) for payload in reports]
        for k in range(WARM_EPOCHS):
            leader.epochs(inputs[k][0][None], inputs[k][1][None], node.ref_x[k])
        start = time.process_time()
        for k in range(WARM_EPOCHS, len(reports)):
            known, z = inputs[k][0][None], inputs[k][1][None]
            leader.epochs(known, z, node.ref_x[k])  # as the simulator runs it
        math_times.append((time.process_time() - start) / (len(reports) - WARM_EPOCHS))
        del node, service, bus
        gc.unfreeze()
        gc.collect()
    if stats is not None:
        pstats.Stats(stats, stream=sys.stderr).sort_stats("tottime").print_stats(25)
    _ = np  # numpy loaded before the rounds, as in the process
    return {"epoch_s": times, "math_s": math_times, "same": same}


def _in_tree(tree: Path, folder: Path, rounds: int) -> dict[str, Any]:
    """:func:`replay` in a fresh interpreter importing the product from ``tree``."""
    env = {**os.environ, "PYTHONPATH": str(tree), "PYTHONSAFEPATH": "1"}
    args = [sys.executable, str(Path(__file__).resolve()), "--replay-only", str(folder)]
    done = subprocess.run(
        [*args, "--rounds", str(rounds)], env=env, check=True, capture_output=True, text=True
    )
    result: dict[str, Any] = json.loads(done.stdout.splitlines()[-1])
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--capture", type=Path, help="default: runs/leader-epoch[-loss-P]")
    parser.add_argument("--loss", type=float, default=0.0, help="Bernoulli loss of every link")
    parser.add_argument("--rounds", type=int, default=3, help="replays of each tree")
    parser.add_argument("--base", help="a commit whose leader is replayed too, alternating")
    parser.add_argument("--profile", action="store_true", help="cProfile of one round")
    parser.add_argument("--replay-only", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.replay_only is not None:  # the child of _in_tree
        print(json.dumps(replay(args.replay_only, args.rounds, False)))
        return
    if args.capture is None:
        args.capture = ROOT / ("runs/leader-epoch" + (f"-loss-{args.loss:g}" if args.loss else ""))
    if not (args.capture / "meta.json").exists():
        print(f"recording the lockstep run into {args.capture} ...", flush=True)
        capture(args.capture, args.loss)
    meta = json.loads((args.capture / "meta.json").read_text())
    epochs = meta["epochs"] - WARM_EPOCHS
    print(
        f"seed {meta['seed']}; henneberg_team({meta['agents']}) pooled in {POOLS}, lockstep, "
        f"Bernoulli loss {meta.get('p_loss', 0.0):g}; "
        f"{epochs} epochs replayed per round, best of {args.rounds}; load {os.getloadavg()[0]:.1f}"
    )
    if args.profile:
        replay(args.capture, 1, True)
    if args.base is None:
        new = replay(args.capture, args.rounds, False)
        _report("this tree", new)
        return
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", args.base], check=True, capture_output=True
        )
        subprocess.run(["tar", "-x", "-C", tmp], input=archive.stdout, check=True)
        olds, news = [], []
        for _ in range(args.rounds):  # alternating: the load changes both alike
            olds.append(_in_tree(Path(tmp), args.capture, REPLAYS))
            news.append(_in_tree(ROOT, args.capture, REPLAYS))
    old, new = (
        {key: [min(r[key]) for r in runs] if key != "same" else all(r[key] for r in runs)
         for key in runs[0]}
        for runs in (olds, news)
    )  # fmt: skip
    _report(f"base {args.base}", old)
    _report("this tree", new)
    print(
        f"ratio this tree / base, CPU an epoch: best {min(new['epoch_s']) / min(old['epoch_s']):.3f}, "
        f"per round (each the best of {REPLAYS} replays) "
        f"{', '.join(f'{n / o:.3f}' for n, o in zip(new['epoch_s'], old['epoch_s'], strict=True))}"
    )


def _report(name: str, result: dict[str, Any]) -> None:
    best, math = min(result["epoch_s"]), min(result["math_s"])
    print(
        f"{name:>16}: leader CPU {1e3 * best:6.2f} ms an epoch (rounds "
        f"{', '.join(f'{1e3 * t:.2f}' for t in result['epoch_s'])}); its math alone "
        f"{1e3 * math:.2f} ms, ratio {best / math:.2f}; outputs equal to the run's: {result['same']}"
    )


if __name__ == "__main__":
    main()
