"""The recorder process: Zenoh in, MCAP out (``python -m recorder``).

Zenoh callbacks only append the raw sample ``(key, payload, attachment, timestamp,
receive time)`` to a list under a lock; a writer thread swaps the list out every
few milliseconds and writes the batch (:class:`recorder.recording.writer.RecordingWriter`). Nothing
is parsed on the way except the agents' states, the leader's estimates, netem's
decisions and the statuses, which feed the per-epoch metrics and the Foxglove scene when
``--scenario`` is given.
If the queue reaches ``--max-queue`` messages the sample is counted per key, never
dropped silently. The liveliness token is declared after the subscribers, so a
launcher that waits for it knows the recorder hears everything published after.

Times: log time = receive time (``time.time_ns()``); publish time = the sample's
Zenoh timestamp (the sender's clock, present when the sender's session has
timestamping enabled), else the receive time, since the sender's ``stamp_ns`` is
monotonic and inside the payload. The MCAP ``sequence`` is the ``seq`` of the codec
attachment. ``keys.flush`` is a queryable answering the counts per key of everything
received before the query (a flush barrier for the launcher).

Stopping: the first SIGINT/SIGTERM stops intake, drains the queue and finishes the
file (summary, indexes); a second one exits at once, leaving every complete chunk
readable (``formation recover``).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
import time
from collections import Counter
from functools import partial
from pathlib import Path
from time import time_ns

import zenoh

from formation import keys
from formation.errors import TestbedError
from formation.scenario import Scenario
from recorder.live.epoch_assembly import TAPS, EpochAssembler
from recorder.live.server import LiveServer
from recorder.reading.trust import Gate
from recorder.recording.display import Display
from recorder.recording.schemas import LivelinessEvent, classify
from recorder.recording.stored_scenario import SCENARIO, scenario_metadata
from recorder.recording.writer import COMPRESSIONS, Raw, RecordingWriter
from shell import Bus, Query, Sample, Service, add_arguments, open_service, serve

log = logging.getLogger("recorder")
POLL_S = 0.005  # the writer thread's wait between batches [s]
SNAPSHOT_NS = 500_000_000  # how often the writer thread refreshes the per-key counts [ns]
COUNTS_WAIT_S = 2.0  # longest a flush query waits for fresh counts [s]
VIEWER_WAIT_S = 50.0  # --foxglove-wait: longest wait for a viewer (the launcher waits 60 s) [s]


class Intake:
    """Where Zenoh callbacks put samples: a list swapped out under a lock by the writer."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.dropped: Counter[str] = Counter()
        self.peak = 0
        self._lock = threading.Lock()
        self._items: list[Raw] = []

    def on_sample(self, sample: Sample) -> None:
        att = sample.attachment
        item = (
            str(sample.key_expr),
            sample.payload.to_bytes(),
            None if att is None else att.to_bytes(),
            sample.timestamp,
            time_ns(),
        )
        with self._lock:
            if len(self._items) < self.limit:
                self._items.append(item)
            else:
                self.dropped[item[0]] += 1

    def push(self, item: Raw) -> None:
        with self._lock:
            self._items.append(item)

    def drain(self) -> list[Raw]:
        with self._lock:
            items, self._items = self._items, []
        self.peak = max(self.peak, len(items))
        return items

    def backlog(self) -> int:
        return len(self._items)


class Recorder:
    """One recording: session, subscribers, token, writer thread."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args, self.run_id = args, args.run_id
        self.scenario = Scenario.from_file(args.scenario) if args.scenario else None
        compression = args.compression or (
            self.scenario.recording.compression if self.scenario else "zstd"
        )
        self.out_dir = Path(args.out or Path("runs") / self.run_id)
        self.filters = _filters(args.keys, self.run_id)
        metadata = {"recorder": {"run_id": self.run_id, "keys": json.dumps(self.filters)}}
        if self.scenario is not None:
            metadata[SCENARIO] = scenario_metadata(self.scenario, str(args.scenario))
            toml = metadata[SCENARIO]["toml"]
            self.out_dir.mkdir(parents=True, exist_ok=True)
            resolved = self.out_dir / "scenario.toml"
            if not resolved.exists():
                resolved.write_text(toml, encoding="utf-8")
        # Opened once the session is: a recorder that cannot connect (a router down, a
        # credential it cannot read) leaves a recording already in out_dir as it was.
        self._open_recording = partial(
            RecordingWriter,
            self.out_dir / args.file,
            compression=compression,
            chunk_size=args.chunk_size,
            chunk_interval_s=args.chunk_interval,
            split_size=args.split_size,
            split_duration_s=args.split_duration,
            fsync_interval_s=args.fsync_interval,
            metadata=metadata,
            taps=TAPS if self.scenario else (),
        )
        self._recording: RecordingWriter | None = None
        self.assembler = EpochAssembler(self.scenario, self.run_id) if self.scenario else None
        self.live: LiveServer | None = None
        if args.foxglove is not None:
            if self.scenario is None:
                raise TestbedError("--foxglove needs --scenario (the live view draws the scene)")
            gate = Gate(self.scenario, conflicts=False)
            self.live = LiveServer(self.scenario, args.foxglove, gate).start()
        self.intake = Intake(args.max_queue)
        self.service: Service | None = None  # from run: its stopping is the recording's stop
        self._writer_done = threading.Event()
        self.error: BaseException | None = None
        self.written = 0
        self.first_recv_ns: int | None = None  # receive time of the first sample [ns]
        self.last_write_ns = 0  # when the last batch had been written [ns]
        self.counts: dict[str, int] = {}  # per key, refreshed by the writer thread
        self._want_counts = threading.Event()
        self._fresh_counts = threading.Event()

    @property
    def recording(self) -> RecordingWriter:
        if self._recording is None:
            raise RuntimeError("the recording opens in run(), once the bus is open")
        return self._recording

    @property
    def stop(self) -> threading.Event:
        """Set to stop the recording (a signal, through :func:`shell.serve`; a writer's error)."""
        if self.service is None:
            raise RuntimeError("the recording stops once it runs (run or record first)")
        return self.service.stopping

    # -- writer thread ------------------------------------------------------------------------
    def _writer(self) -> None:
        snapshot_ns = 0
        try:
            while True:
                draining = self._writer_done.is_set()
                wanted = (
                    self._want_counts.is_set()
                )  # seen before the drain: the drain follows the query
                batch = self.intake.drain()
                if batch:
                    self._write(batch)
                now = time.monotonic_ns()
                self.recording.tick(now)
                if wanted or now - snapshot_ns > SNAPSHOT_NS:
                    if wanted:
                        self._want_counts.clear()
                    self.counts, snapshot_ns = self.recording.counts(), now
                    if wanted:
                        self._fresh_counts.set()
                if not batch:
                    if draining:
                        return
                    self._writer_done.wait(POLL_S)
        except BaseException as exc:
            self.error = exc
            self.stop.set()

    def _write(self, batch: list[Raw]) -> None:
        if self.first_recv_ns is None:
            self.first_recv_ns = batch[0][4]
        tapped = self.recording.write_batch(batch)
        self.written += len(batch)
        self.last_write_ns = time_ns()
        asm = self.assembler
        if asm is None:
            return
        live = self.live
        for kind, key, data, recv in tapped:
            if live is not None:
                live.offer(kind, key, data)  # netem's decisions; the live view ignores the rest
            for out_key, payload in asm.on(kind, key, data, recv):
                self.recording.write(out_key, payload, time_ns())
                if live is not None:
                    live.offer(classify(out_key), out_key, payload)

    # -- liveliness -------------------------------------------------------------------------
    def on_alive(self, key: str, alive: bool) -> None:
        """A liveliness token came or went: recorded as a :class:`LivelinessEvent`."""
        role, ident = keys.parse(key).args
        event = LivelinessEvent(key=key, role=role, ident=ident, alive=alive)
        self.intake.push((key, event.model_dump_json().encode(), None, None, time_ns()))

    def on_counts(self, query: Query) -> None:
        """The flush barrier (``keys.flush``): counts per key of everything received before the query."""
        self._fresh_counts.clear()
        self._want_counts.set()
        self._fresh_counts.wait(COUNTS_WAIT_S)
        query.reply(query.key_expr, json.dumps(self.counts).encode())

    # -- the run ------------------------------------------------------------------------------
    def run(self, bus: Bus) -> int:
        """Record on ``bus`` until :attr:`stop` is set; returns an exit code."""
        service = Service(bus, self.run_id, "recorder", 0)
        try:
            return self.record(service)
        finally:
            service.close()

    def record(self, service: Service) -> int:
        """Record on ``service`` until it is stopping (``shell.serve``'s body)."""
        self.service = service
        try:
            self._recording = self._open_recording()
            return self._record(service)
        finally:
            self.close_live()

    def close_live(self) -> None:
        """Stop the live view at once (after an error; a stopped server again is harmless)."""
        if self.live is not None:
            self.live.close(linger_s=0.0)

    def _record(self, service: Service) -> int:
        bus = service.bus
        subs = [bus.declare_subscriber(f, self.intake.on_sample) for f in self.filters]
        subs.append(bus.declare_liveliness_subscriber(keys.alive_all(self.run_id), self.on_alive))
        subs.append(bus.declare_queryable(keys.flush(self.run_id), self.on_counts))
        service.declare_publishers([keys.status(self.run_id, "recorder", 0)])
        writer = threading.Thread(target=self._writer, name="recorder-writer", daemon=True)
        writer.start()
        self._wait_for_viewer()
        token = bus.declare_token(keys.alive(self.run_id, "recorder", 0))
        service.status("ready")
        log.info("recording %s into %s", ", ".join(self.filters), self.recording.files[0])
        if self.live is not None:
            log.info("live view for Foxglove on %s", self.live.url)
        display = Display(self, self.args.live, self.args.log_interval)
        with display:
            while not self.stop.wait(display.period_s):
                display.update()
        for sub in subs:
            sub.undeclare()
        self._writer_done.set()
        while writer.is_alive():
            writer.join(0.1)
        if self.error is None:
            self._finish()
        detail = self.summary()
        service.status("error" if self.error else "done", 0, detail)
        token.undeclare()
        print(f"recorder {self.run_id}: {detail}", file=sys.stderr)
        if self.error is not None:
            print(f"recorder {self.run_id}: error: {self.error!r}", file=sys.stderr)
            return 1
        return 0

    def _wait_for_viewer(self) -> None:
        """``--foxglove-wait``: hold the run (its liveliness token) until a viewer watches."""
        if self.live is None or not self.args.foxglove_wait:
            return
        log.info("waiting for a Foxglove viewer on %s (at most %g s)", self.live.url, VIEWER_WAIT_S)
        if not self.live.wait_for_viewer(VIEWER_WAIT_S):
            log.warning("no viewer after %g s; the run starts without one", VIEWER_WAIT_S)

    def _finish(self) -> None:
        if self.assembler is not None:
            for key, payload in self.assembler.finish(time_ns()):
                self.recording.write(key, payload, time_ns())
                if self.live is not None:
                    self.live.offer(classify(key), key, payload)
        if self.live is not None:
            self.live.finish()  # its counts are final; the viewers get the end after the file
        stats = {
            "written": str(self.written),
            "dropped": str(sum(self.intake.dropped.values())),
            "dropped_by_key": json.dumps(dict(self.intake.dropped)),
            "peak_backlog": str(self.intake.peak),
            "first_recv_ns": str(self.first_recv_ns or 0),
            "last_write_ns": str(self.last_write_ns),
        }
        if self.assembler is not None:
            stats["derived_malformed"] = json.dumps(self.assembler.gate.skipped.by_channel())
            stats["epochs_incomplete"] = str(self.assembler.incomplete)
            stats["states_late"] = str(self.assembler.late)
            stats["scenes_drawn_early"] = str(self.assembler.drawn_early)
        if self.live is not None:
            stats["live"] = json.dumps(self.live.stats("done"))
        self.recording.add_metadata("recorder_stats", stats)
        self.recording.close()
        if self.live is not None:
            self.live.close()

    def summary(self) -> str:
        dropped = sum(self.intake.dropped.values())
        files = ", ".join(str(f) for f in self.recording.files)
        text = f"{self.written} messages written to {files}; peak backlog {self.intake.peak}"
        text += f"; {dropped} could not be kept (queue full)" if dropped else "; nothing dropped"
        if self.live is not None:
            live = self.live
            text += f"; live view: {live.offered} offered, {live.dropped} dropped, {live.sent} sent"
        return text


def _filters(given: list[str] | None, run_id: str) -> list[str]:
    """Key filters from ``--keys`` (repeatable, comma-separated); overlapping filters are refused."""
    filters = [f.strip() for g in (given or []) for f in g.split(",") if f.strip()]
    filters = filters or [keys.everything(run_id)]
    for a_index, a in enumerate(filters):
        for b in filters[a_index + 1 :]:
            if zenoh.KeyExpr(a).intersects(zenoh.KeyExpr(b)):
                raise TestbedError(
                    f"--keys {a} and {b} overlap: a message on both would be recorded twice"
                )
    return filters


def _size(text: str) -> int:
    """``"100M"`` → 104857600; plain integers are bytes."""
    units = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}
    text = text.strip().upper().removesuffix("B")
    if text and text[-1] in units:
        return int(float(text[:-1]) * units[text[-1]])
    return int(text)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m recorder", description=__doc__.split("\n")[0])
    p.add_argument("--run-id", required=True, help="run id: records formation/<run_id>/**")
    p.add_argument("--out", help="output directory (default runs/<run_id>)")
    p.add_argument(
        "--file", default="run.mcap", help="file name; rotated files get -001, -002, ..."
    )
    p.add_argument(
        "--scenario", help="scenario TOML: stored as metadata, enables metrics and scene"
    )
    p.add_argument("--keys", action="append", help="key filter(s), comma-separated or repeated")
    p.add_argument("--compression", choices=COMPRESSIONS, help="default: the scenario's, else zstd")
    p.add_argument("--chunk-size", type=_size, default=1 << 20, help="bytes per chunk (default 1M)")
    p.add_argument("--chunk-interval", type=float, default=0.5, help="close a chunk after s (0.5)")
    p.add_argument("--split-size", type=_size, help="start a new file after this many bytes")
    p.add_argument("--split-duration", type=float, help="start a new file after this many seconds")
    p.add_argument("--fsync-interval", type=float, default=1.0, help="fsync at most every s (1.0)")
    p.add_argument(
        "--max-queue", type=int, default=2_000_000, help="messages queued before counting drops"
    )
    p.add_argument(
        "--live", action=argparse.BooleanOptionalAction, help="live table (default: on a TTY)"
    )
    p.add_argument("--log-interval", type=float, default=10.0, help="progress log line every s")
    p.add_argument(
        "--foxglove",
        type=int,
        metavar="PORT",
        help="serve the run live to Foxglove on ws://127.0.0.1:PORT (0: any free port)",
    )
    p.add_argument(
        "--foxglove-wait",
        action="store_true",
        help=f"start the run once a viewer watches the scene (at most {VIEWER_WAIT_S:g} s)",
    )
    add_arguments(p)
    return p


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    args = build_parser().parse_args(argv)
    try:
        recorder = Recorder(args)
    except TestbedError as exc:
        print(f"recorder: error: {exc}", file=sys.stderr)
        return 1
    try:  # a second signal ends at once: every chunk flushed stays readable (formation recover)
        code: int = serve(
            "recorder", partial(open_service, args, "recorder", 0), recorder.record, True
        )
        return code
    except zenoh.ZError as exc:
        print(f"recorder: error: cannot open the Zenoh session: {exc}", file=sys.stderr)
        return 1
    finally:
        recorder.close_live()  # also when the session did not open


__all__ = ["Intake", "Recorder", "build_parser", "main"]
