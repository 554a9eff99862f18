"""Benchmark of the recorder: messages/s kept with nothing lost, against the mcap library.

Run ``python bench/bench_recorder.py [--seed S] [--messages N] [--keys K] [--quick]``.

1. **End to end**: the recorder (``python -m recorder``, zstd, default chunks) and a
   publisher in two processes on 127.0.0.1. The publisher sends ``N`` coordination
   packets (seeded random positions, about 190 bytes of JSON each, codec attachment)
   round-robin on ``K`` keys as fast as it can with congestion control *block*, then
   polls the recorder's flush barrier (``keys.flush``) until every message is counted.
   Throughput = N / (first put → all N written); the file is then read with the
   ``mcap`` library and every key's count must equal what was sent.
2. **Baseline, same run**: the ``mcap`` library's ``Writer`` writing the same messages
   (same channels, zstd, 1 MiB chunks) in a tight loop; and the recorder's own writer
   in the same loop, for the cost of writing alone.
3. **Bytes per message** of the recorder's writer with zstd, lz4 and no compression.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from formation import keys
from formation.codec import attachment
from shell import session_config

SEED = 20240611
RUN = "bench"
TIMEOUT_S = 300.0
REPEATS = 3  # tight-loop measurements: best of


def payloads(seed: int, count: int, n_keys: int) -> list[tuple[str, bytes, bytes]]:
    """``count`` (key, CoordinationState JSON, attachment) with seeded positions, round-robin on keys."""
    rng = np.random.default_rng(seed)
    pos = rng.normal(0.0, 1.0, size=(count, 2))
    stamp = 10**12 + np.cumsum(rng.integers(1_000, 10_000, size=count))
    out = []
    for k in range(count):
        i = 1 + k % n_keys
        body = (
            f'{{"run_id":"{RUN}","sender":"agent/{i}","seq":{k // n_keys},"epoch":{k // n_keys},'
            f'"stamp_ns":{int(stamp[k])},"kind":"state","agent":{i},'
            f'"position":[{pos[k, 0]!r},{pos[k, 1]!r}],"velocity":null}}'
        )
        out.append(
            (keys.agent_state(RUN, i), body.encode(), attachment(k // n_keys, k // n_keys, i))
        )
    return out


# --------------------------------------------------------------------------- writing only


def mcap_library(
    msgs: list[tuple[str, bytes, bytes]], compression: str = "zstd"
) -> tuple[float, int]:
    """The baseline: mcap's Writer, channels registered up front; returns (msg/s, bytes)."""
    from mcap.writer import CompressionType, Writer

    from recorder.recording.schemas import schema_for_key

    buf = io.BytesIO()
    writer: Any = Writer(buf, chunk_size=1 << 20, compression=CompressionType[compression.upper()])
    writer.start()
    spec = schema_for_key(msgs[0][0])
    schema_id = writer.register_schema(spec.name, spec.encoding, spec.data)
    ids = {
        key: writer.register_channel(key, "json", schema_id)
        for key in dict.fromkeys(k for k, _, _ in msgs)
    }
    t0 = time.perf_counter()
    for n, (key, data, _) in enumerate(msgs):
        now = 10**18 + n
        writer.add_message(ids[key], log_time=now, data=data, publish_time=now)
    writer.finish()
    return len(msgs) / (time.perf_counter() - t0), buf.tell()


def recorder_writer(
    msgs: list[tuple[str, bytes, bytes]], compression: str = "zstd"
) -> tuple[float, int]:
    """The recorder's writer fed batches of 1,000 samples; returns (msg/s, bytes)."""
    from recorder.recording.writer import RecordingWriter

    buf = io.BytesIO()
    rec = RecordingWriter(buf, compression=compression, fsync_interval_s=None)
    raw = [(key, data, att, None, 10**18 + n) for n, (key, data, att) in enumerate(msgs)]
    t0 = time.perf_counter()
    for start in range(0, len(raw), 1000):
        rec.write_batch(raw[start : start + 1000])
    rec.close()
    return len(msgs) / (time.perf_counter() - t0), buf.tell()


# --------------------------------------------------------------------------- end to end


def publisher(endpoint: str, seed: int, count: int, n_keys: int) -> int:
    """The publishing process: wait for the recorder, send, wait for the flush barrier; JSON to stdout."""
    import zenoh

    msgs = payloads(seed, count, n_keys)
    session = zenoh.open(session_config("peer", endpoint, None))
    deadline = time.monotonic() + 30
    while not any(
        r.ok is not None
        for r in session.liveliness().get(keys.alive(RUN, "recorder", 0), timeout=1.0)
    ):
        if time.monotonic() > deadline:
            print(json.dumps({"error": "recorder not alive"}))
            return 1
    pubs = {
        k: session.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
        for k, _, _ in msgs[:n_keys]
    }
    t0 = time.monotonic()
    for key, data, att in msgs:
        pubs[key].put(data, attachment=att)
    t_sent = time.monotonic()
    counted = 0
    while counted < count and time.monotonic() - t0 < TIMEOUT_S:
        for reply in session.get(keys.flush(RUN), timeout=5.0):
            if reply.ok is not None:
                counts = json.loads(reply.ok.payload.to_bytes())
                counted = sum(v for k, v in counts.items() if k in pubs)
    t_done = time.monotonic()
    print(
        json.dumps(
            {
                "sent": count,
                "counted": counted,
                "publish_s": t_sent - t0,
                "all_written_s": t_done - t0,
            }
        )
    )
    session.close()
    return 0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def end_to_end(seed: int, count: int, n_keys: int, out: Path) -> dict[str, Any]:
    from mcap.reader import make_reader

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ)
    rec_args = [
        "-m",
        "recorder",
        "--run-id",
        RUN,
        "--out",
        str(out),
        "--mode",
        "peer",
        "--listen",
        endpoint,
        "--no-live",
    ]
    recorder = subprocess.Popen([sys.executable, *rec_args], env=env, stderr=subprocess.PIPE)
    pub = None
    try:
        pub_args = [
            __file__,
            "--publish",
            endpoint,
            "--seed",
            str(seed),
            "--messages",
            str(count),
            "--keys",
            str(n_keys),
        ]
        pub = subprocess.run(
            [sys.executable, *pub_args], env=env, capture_output=True, timeout=TIMEOUT_S, check=True
        )
        result: dict[str, Any] = json.loads(pub.stdout.decode().strip().splitlines()[-1])
        os.kill(recorder.pid, signal.SIGTERM)
        recorder.wait(timeout=60)
    finally:
        if recorder.poll() is None:
            os.kill(recorder.pid, signal.SIGKILL)
            recorder.wait()
    with open(out / "run.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        stats = {m.name: m.metadata for m in reader.iter_metadata()}["recorder_stats"]
        assert summary is not None and summary.statistics is not None
        by_topic = {
            summary.channels[c].topic: n
            for c, n in summary.statistics.channel_message_counts.items()
        }
        times = [
            m.log_time
            for _, ch, m in reader.iter_messages(log_time_order=False)
            if ch.topic.endswith("/state")
        ]
    recorded = sum(n for t, n in by_topic.items() if t.endswith("/state"))
    result.update(
        recorded=recorded,
        per_key_equal=all(
            by_topic.get(k) == count // n_keys + (i < count % n_keys)
            for i, k in enumerate(keys.agent_state(RUN, j) for j in range(1, n_keys + 1))
        ),
        intake_per_s=recorded / max((max(times) - min(times)) / 1e9, 1e-9),
        peak_backlog=int(stats["peak_backlog"]),
        dropped=int(stats["dropped"]),
        file_bytes=(out / "run.mcap").stat().st_size,
        returncode=recorder.returncode,
    )
    return result


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the results; returns 0 (``argv`` default: no options)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--messages", type=int, default=600_000)
    parser.add_argument("--keys", type=int, default=16, help="distinct keys (channels)")
    parser.add_argument("--quick", action="store_true", help="100,000 messages")
    parser.add_argument("--publish", help=argparse.SUPPRESS)  # the publisher process's mode
    args = parser.parse_args([] if argv is None else argv)  # a runner's argv is not ours
    count = 100_000 if args.quick else args.messages
    if args.publish:
        return publisher(args.publish, args.seed, count, args.keys)
    load = os.getloadavg()
    print(
        f"bench_recorder  seed={args.seed}  messages={count}  keys={args.keys}  cpus={os.cpu_count()}  load={load[0]:.1f},{load[1]:.1f},{load[2]:.1f}"
    )
    msgs = payloads(args.seed, count, args.keys)
    size = np.mean([len(d) for _, d, _ in msgs])
    print(f"payload: CoordinationState JSON, mean {size:.0f} bytes, 24-byte attachment")

    with tempfile.TemporaryDirectory() as tmp:
        e2e = end_to_end(args.seed, count, args.keys, Path(tmp))
    base = [mcap_library(msgs) for _ in range(REPEATS)]
    own = [recorder_writer(msgs) for _ in range(REPEATS)]
    base_rate, base_bytes = max(r for r, _ in base), base[0][1]
    own_rate = max(r for r, _ in own)
    lost = e2e["sent"] - e2e["recorded"]
    rate = e2e["sent"] / e2e["all_written_s"]
    print("\nend to end (publisher process → recorder process, loopback, zstd)")
    print(
        f"  publisher sent          {e2e['sent']:>10}   in {e2e['publish_s']:.2f} s  ({e2e['sent'] / e2e['publish_s']:,.0f} msg/s offered)"
    )
    print(
        f"  recorder recorded       {e2e['recorded']:>10}   lost {lost}, dropped (queue full) {e2e['dropped']}, per key equal: {e2e['per_key_equal']}"
    )
    print(
        f"  all written after       {e2e['all_written_s']:>10.2f} s  → {rate:,.0f} msg/s sustained, nothing lost"
        if lost == 0
        else "  MESSAGES LOST"
    )
    print(
        f"  intake (receive times)  {e2e['intake_per_s']:>10,.0f} msg/s   peak backlog {e2e['peak_backlog']} messages"
    )
    print(f"  recorder exit code      {e2e['returncode']:>10}")
    print(f"\nwriting only, same messages, same run (best of {REPEATS})")
    print(f"  mcap library Writer     {base_rate:>10,.0f} msg/s   (baseline)")
    print(
        f"  recorder writer         {own_rate:>10,.0f} msg/s   ×{own_rate / base_rate:.2f} baseline"
    )
    print(f"  end to end / baseline   ×{rate / base_rate:.2f}")
    print("\nbytes per message (recorder writer, chunks 1 MiB)")
    for compression in ("zstd", "lz4", "none"):
        _, nbytes = recorder_writer(msgs, compression)
        print(f"  {compression:<5} {nbytes / count:>8.1f} B/msg")
    print(
        f"  mcap library zstd {base_bytes / count:>6.1f} B/msg;  recorder file (e2e, zstd) {e2e['file_bytes'] / count:.1f} B/msg"
    )
    load = os.getloadavg()
    print(
        f"\nload at the end {load[0]:.1f},{load[1]:.1f},{load[2]:.1f} (other processes share the cores)"
    )
    target = 120_000
    print(
        f"\ntarget ≥ {target:,} msg/s with nothing lost: {'met' if lost == 0 and rate >= target else 'NOT met'} ({rate:,.0f})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
