"""The live view and the DataFrames: what watching and analysing cost.

1. Lockstep epochs/s (and the recorder's CPU per epoch) of the same run (paper.toml, seed 1) without ``--foxglove``, with it and
   one subscribed client that reads everything, and with that client and a second one that
   subscribes and never reads; the runs interleaved, each configuration ``REPEATS`` times,
   the median reported with its ratio to the run without a viewer. The rate is taken
   between epoch marks (start-up and the end excluded), the ``--foxglove-wait`` for the
   client too.
2. Messages/s the live server sends to the reading client (data frames, by its clock): in
   those runs (bounded by the run), and at capacity: the recorded scenes and metrics of the
   synthetic recording below offered as fast as the server takes them (``block=True``).
3. ``recorder.load_run`` on a 10,000-epoch synthetic recording (the paper scenario
   simulated and recorded as the recorder would, testkit/src/testkit/synthetic.py) against the
   same file read with the ``mcap`` library alone (every message decompressed), and with
   ``mcap`` plus decoding every payload (``orjson.loads``; the recorder's protobuf scenes,
   frames and log lines by their schema), the least any table needs.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import tempfile
import threading
import time
from pathlib import Path

import orjson
from mcap.reader import make_reader

from bench.procfs import cpu_s
from formation.scenario import Scenario
from formation.topics import DECISIONS_TOPIC, METRICS_TOPIC, SCENE_TOPIC, STATS_TOPIC, TF_TOPIC
from recorder import load_run
from recorder.live.server import LiveServer
from recorder.reading.decoder import decode
from testbed.runtime.launcher import launch
from testbed.runtime.processes import free_port
from testbed.sim.simulate import simulate
from testkit import foxglove_client as fc
from testkit.synthetic import write_synthetic

ROOT = Path(__file__).resolve().parents[1]
SEED = 1
EPOCHS = 200
REPEATS = 2
LOAD_EPOCHS = 10_000
TOPICS = [DECISIONS_TOPIC, TF_TOPIC, METRICS_TOPIC, STATS_TOPIC, SCENE_TOPIC]  # scene last


class Viewer(threading.Thread):
    """The independent client (testkit/src/testkit/foxglove_client.py) reading a live run to its end,
    with, if ``idle``, a second client that subscribes and never reads."""

    def __init__(self, port: int, idle: bool) -> None:
        super().__init__(daemon=True)
        self.url, self.idle = f"ws://127.0.0.1:{port}", idle
        self.received: list[float] = []  # receive time of each data frame but the counts [s]
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            asyncio.run(self._watch())
        except BaseException as exc:  # reported by the benchmark, not lost in the thread
            self.error = exc

    async def _watch(self) -> None:
        ws = await fc.connect(self.url, 120.0)
        got = fc.Received()
        await fc.advertised(ws, got, set(TOPICS))
        stalled = await fc.idle_subscriber(self.url, got.channels) if self.idle else None
        subs = await fc.subscribe(ws, got, TOPICS)

        def done(topic: str, payload: bytes) -> bool:
            if topic == STATS_TOPIC:
                return bool(json.loads(payload)["state"] == "done")
            self.received.append(time.monotonic())
            return False

        await fc.read_until(ws, got, subs, done, 600.0)
        await ws.close()
        if stalled is not None:
            stalled.transport.abort()

    def rate(self) -> float:
        """Data frames per second between the first and the last [1/s]."""
        t = self.received
        return (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 else 0.0


def lockstep_rate(scenario: Scenario, runs: Path, viewers: int) -> tuple[float, float, float]:
    """(epochs/s between epoch marks, messages/s to the reading client or 0, the recorder's
    CPU ms per epoch between the same marks)."""
    marks: dict[int, float] = {}
    cpu: dict[int, float] = {}
    first, last = 5, scenario.epochs - 2
    extra: tuple[str, ...] = ()
    viewer = None
    if viewers:
        port = free_port()
        extra = ("--foxglove", str(port), "--foxglove-wait")
        viewer = Viewer(port, idle=viewers > 1)
        viewer.start()

    def progress(done: int, total: int, drops: int) -> None:
        marks.setdefault(done, time.monotonic())
        if (done >= first and not cpu) or (done >= last and len(cpu) == 1):
            pids = json.loads(next(runs.glob("*/pids.json")).read_text())["pids"]
            cpu[done] = cpu_s(pids["recorder"]) or 0.0

    launch(scenario, seed=SEED, runs_dir=runs, progress=progress, recorder_args=extra)
    seen = sorted(k for k in marks if first <= k <= last)
    rate = (seen[-1] - seen[0]) / (marks[seen[-1]] - marks[seen[0]])
    (k0, c0), (k1, c1) = sorted(cpu.items())
    cpu_ms = 1e3 * (c1 - c0) / max(k1 - k0, 1)
    if viewer is None:
        return rate, 0.0, cpu_ms
    viewer.join(60.0)
    if viewer.error is not None:
        raise viewer.error
    return rate, viewer.rate(), cpu_ms


def server_capacity(path: Path, scenario: Scenario) -> tuple[float, int, int]:
    """(messages/s a reading client receives, messages it received, messages the server sent)
    when the server is offered the recorded scenes and metrics of ``path`` back to back; what
    the client did not take in time the SDK dropped for it (its backlog, the oldest first)."""
    live = LiveServer(scenario, 0, block=True).start()
    kinds = {"scene", "metrics"}
    with open(path, "rb") as f:
        items = [
            (ch.metadata["kind"], ch.topic, m.data)
            for _, ch, m in make_reader(f).iter_messages(log_time_order=True)
            if ch.metadata.get("kind") in kinds
        ]
    viewer = Viewer(live.port, idle=False)
    viewer.start()
    if not live.wait_for_topics(set(TOPICS), 60.0):
        raise RuntimeError("the client did not subscribe")
    for kind, key, data in items:
        live.offer(kind, key, data)
    live.close()
    viewer.join(60.0)
    return viewer.rate(), len(viewer.received), live.sent


def load_times(path: Path) -> tuple[float, float, float, int]:
    """(load_run s, mcap alone s, mcap + decoding s, messages) on ``path``."""
    start = time.perf_counter()
    load_run(path)
    frames = time.perf_counter() - start
    start = time.perf_counter()
    with open(path, "rb") as f:
        count = sum(len(m.data) >= 0 for _, _, m in make_reader(f).iter_messages())
    alone = time.perf_counter() - start
    start = time.perf_counter()
    with open(path, "rb") as f:
        for schema, ch, m in make_reader(f).iter_messages():
            if ch.message_encoding == "protobuf" and schema is not None:
                decode(schema.name, schema.data, m.data)
            else:
                orjson.loads(m.data)
    parsed = time.perf_counter() - start
    return frames, alone, parsed, count


def main() -> None:
    p = argparse.ArgumentParser(prog="python -m bench bench_foxglove")
    p.add_argument("--epochs", type=int, default=EPOCHS)
    p.add_argument("--repeats", type=int, default=REPEATS)
    p.add_argument("--load-epochs", type=int, default=LOAD_EPOCHS)
    args = p.parse_args()
    paper = Scenario.from_file(ROOT / "scenarios" / "paper.toml")
    scenario = paper.with_overrides(epochs=args.epochs)
    names = {0: "no viewer", 1: "--foxglove, 1 reading client", 2: "--foxglove, + 1 never reading"}
    rates: dict[int, list[float]] = {v: [] for v in names}
    cpu: dict[int, list[float]] = {v: [] for v in names}
    sent: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(args.repeats):
            for viewers in names:
                runs = Path(tmp) / f"runs-{rep}-{viewers}"
                rate, msgs, cpu_ms = lockstep_rate(scenario, runs, viewers)
                rates[viewers].append(rate)
                cpu[viewers].append(cpu_ms)
                if viewers:
                    sent.append(msgs)
        print(f"lockstep, paper.toml, {args.epochs} epochs, seed {SEED}, {args.repeats} runs each "
              f"(interleaved; median):")  # fmt: skip
        base = statistics.median(rates[0])
        for viewers, name in names.items():
            med = statistics.median(rates[viewers])
            each = ", ".join(f"{r:.1f}" for r in rates[viewers])
            print(f"  {name:32s} {med:7.1f} epochs/s  ({each})  ratio {med / base:.2f};  "
                  f"recorder {statistics.median(cpu[viewers]):.2f} CPU ms/epoch")  # fmt: skip
        print(f"  live server → reading client: {statistics.median(sent):.0f} messages/s (median; "
              f"{', '.join(f'{m:.0f}' for m in sent)})")  # fmt: skip

        path = Path(tmp) / "synthetic.mcap"
        long = paper.with_overrides(epochs=args.load_epochs)
        start = time.perf_counter()
        write_synthetic(path, simulate(long, strategy="estimate", seed=SEED))
        made = time.perf_counter() - start
        capacity, received, sent_all = server_capacity(path, long)
        print(f"live server at capacity (the recording's scenes and metrics, each metrics also "
              f"as /tf): {capacity:.0f} messages/s to one reading client; it received "
              f"{received} of {sent_all} (the SDK dropped the rest for it)")  # fmt: skip
        frames, alone, parsed, count = load_times(path)
        size = path.stat().st_size / 2**20
        print(f"load_run, synthetic paper recording, {args.load_epochs} epochs, seed {SEED}: "
              f"{count} messages, {size:.1f} MiB (written in {made:.1f} s)")  # fmt: skip
        print(f"  mcap alone (iter_messages)      {alone:7.2f} s  baseline")
        print(f"  mcap + decoding each payload    {parsed:7.2f} s  ratio {parsed / alone:.1f}")
        print(f"  recorder.load_run               {frames:7.2f} s  ratio {frames / alone:.1f}")


if __name__ == "__main__":
    main()
