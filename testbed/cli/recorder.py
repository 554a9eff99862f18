"""``formation report | info | recover | export``: the recorder's subcommands on files.

:func:`register` adds them to the ``formation`` parser (:mod:`testbed.cli`).
Every bad file (missing, empty, not MCAP, truncated) is a ``RecordingError`` naming
it, which the CLI prints before exiting with 1.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from formation import keys
from testbed.cli.progress import Stages
from testbed.cli.tables import LABELS, header, print_table

INFO_COLUMNS = ("topic", "schema", "messages [msgs]")
LINK_COLUMNS = ("link", "packets [pkts]", "dropped [pkts]")


def cmd_report(args: argparse.Namespace) -> int:
    from recorder import write_reports  # each command loads the recorder: its --help does not

    with Stages("formation report", 1).stage(f"{len(args.recordings)} recording(s)"):
        path = write_reports(args.recordings, args.out)
    print(f"report: {path}")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    from recorder import describe, validate

    info = describe(args.recording)
    console = Console()
    s = info.scenario
    console.print(
        f"[bold]{info.path}[/]: {info.size_bytes} bytes, {info.messages} messages in {info.chunks} chunks ({info.compression})"
    )
    console.print(f"duration {info.duration_s:.3f} s (log time {info.start_ns} … {info.end_ns} ns)")
    if s is None:
        console.print("scenario: none stored")
    else:
        console.print(
            f"scenario: {s.name} (seed {s.seed}, {s.n} agents, d = {s.dimension}, {s.epochs} epochs, "
            f"strategy {s.strategy.name}, {s.runtime.mode})"
        )
    stats = info.metadata.get("recorder_stats")
    if stats:
        received = int(stats.get("written", 0))
        console.print(
            f"recorder: {received} received and written, {stats.get('dropped')} could not be kept; "
            f"{info.messages - received} derived (metrics, frames, scene, log)"
        )
    run_id = info.metadata.get("recorder", {}).get("run_id")
    prefix = f"{keys.prefix(run_id)}/" if run_id else ""
    table = Table(title=f"channels under {prefix}" if prefix else "channels")
    for col in INFO_COLUMNS:
        table.add_column(header(col), justify="left" if col in LABELS else "right", overflow="fold")
    for ch in info.channels:
        topic = ch.topic.removeprefix(prefix) if prefix else ch.topic
        table.add_row(topic, ch.schema, str(ch.messages))
    print_table(table, console)
    if info.sent:
        links = Table(title="netem decisions per link")
        for col in LINK_COLUMNS:
            links.add_column(header(col), justify="left" if col in LABELS else "right")
        for link in sorted(info.sent):
            links.add_row(link, str(info.sent[link]), str(info.drops.get(link, 0)))
        console.print(links)
    else:
        console.print("no netem decisions recorded")
    console.print(f"checked every message (model, owner, scenario): {info.skipped.describe()}")
    for topic, count in info.skipped.by_channel().items():
        console.print(f"  skipped on {topic.removeprefix(prefix)}: {count}")
    if args.validate:
        check = validate(args.recording)
        console.print(
            f"validated {check.checked} messages against their schemas: {check.failures} invalid"
        )
        for topic, log_ns, problem in check.examples:
            console.print(f"  {topic} @ {log_ns}: {problem}")
        return 1 if check.failures else 0
    if args.json:
        print(
            json.dumps(
                {
                    "channels": {c.topic: c.messages for c in info.channels},
                    "drops": dict(info.drops),
                    "skipped": info.skipped.as_json(),
                }
            )
        )
    return 0


def cmd_recover(args: argparse.Namespace) -> int:
    from recorder import recover

    result = recover(args.recording, args.output, args.compression)
    print(result.describe())
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from recorder import export, load_run  # here: pandas loads only for this command

    with Stages("formation export", 1).stage(f"{args.recording} as {args.format}"):
        run = load_run(args.recording)
        files = export(run, args.out_dir, args.format)
    sizes = ", ".join(f"{name} {len(frame)}" for name, frame in run.tables().items())
    print(f"exported {args.recording} to {args.out_dir} ({args.format}): rows {sizes}")
    print(f"checked every message: {run.skipped.describe() if run.skipped else '-'}")
    for f in files:
        print(f"  {f}")
    return 0


def register(sub: Any) -> None:
    """Add ``report``, ``info``, ``recover`` and ``export`` to the ``formation`` subparsers."""
    p = sub.add_parser("report", help="report.md and PNG plots from one or more recordings")
    p.add_argument(
        "recordings", nargs="+", type=Path, help="run.mcap file(s); several are compared"
    )
    p.add_argument(
        "-o", "--out", type=Path, help="output directory (default: beside the first file)"
    )
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("info", help="scenario, duration, channels, message counts, drops per link")
    p.add_argument("recording", type=Path, help="a run.mcap file")
    p.add_argument(
        "--validate", action="store_true", help="check every message against its JSON Schema"
    )
    p.add_argument("--json", action="store_true", help="also print counts and drops as JSON")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("recover", help="a clean MCAP file from a recording cut short")
    p.add_argument("recording", type=Path, help="a run.mcap file cut short (a killed recorder)")
    p.add_argument(
        "-o", "--output", type=Path, help="the clean file (default: <name>-recovered.mcap)"
    )
    p.add_argument(
        "--compression",
        choices=("zstd", "lz4", "none"),
        default="zstd",
        help="the clean file's chunk compression (default zstd)",
    )
    p.set_defaults(func=cmd_recover)

    p = sub.add_parser("export", help="a recording's tables (states, estimates, ...) as files")
    p.add_argument("recording", type=Path, help="a run.mcap file")
    p.add_argument("out_dir", type=Path, help="directory for <table>.parquet or <table>.csv")
    p.add_argument(
        "--format",
        choices=("parquet", "csv"),
        default="parquet",
        help="file format (default parquet: needs the parquet extra, pyarrow)",
    )
    p.set_defaults(func=cmd_export)


__all__ = ["register"]
