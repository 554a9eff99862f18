"""``formation run``: the distributed run from the terminal, with a progress bar and a summary."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from testbed.cli.arguments import add_common, load_checked, scenario_strategies
from testbed.cli.deadline_lines import deadline_cells, deadline_notes
from testbed.cli.progress import every
from testbed.cli.robot_lines import loss_cause, robot_notes
from testbed.cli.tables import header, print_table
from testbed.runtime.restart_policy import RESTART_POLICIES


def cmd_run(args: argparse.Namespace) -> int:
    from formation.errors import RunEnded, RuntimeFailure
    from recorder import write_deadlines, write_reports
    from testbed.runtime.launcher import launch
    from testbed.runtime.process_budget import realtime_layout

    console = Console(stderr=True)
    scenario = load_checked(args.scenario)
    if args.epochs is not None:
        scenario = scenario.with_overrides(epochs=args.epochs)
    pool = args.pool
    if args.mode == "realtime":
        period = args.period_s or scenario.runtime.realtime_period_s
        scenario = scenario.with_overrides(
            runtime={"mode": "realtime", "realtime_period_s": period}
        )
        if pool is None:
            packets = len(scenario.directed_links) + 2 * scenario.n
            layout = realtime_layout(scenario.n, period or scenario.control.period_s, None, packets)
            pool = layout.pools
            console.print(f"realtime layout: {layout.why}; --pool K to choose")
    live = _live_args(args)
    if live:
        console.print(live_view_line(args.foxglove), soft_wrap=True)
    outcomes = []
    recorded: dict[str, dict[str, Any]] = {}  # run_id → its recording's summary (trusted)
    strategies = scenario_strategies(args.strategy, scenario)
    for number, strategy in enumerate(strategies, 1):
        if not console.is_terminal:  # no bar: a line per run, then one every tenth of it
            _line(f"[{number}/{len(strategies)}] {strategy}: {scenario.epochs} epochs ...")
        with Progress(
            TextColumn(f"[bold]{strategy}[/]"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[rate]:.1f} epochs/s"),
            TextColumn("drops {task.fields[drops]}"),
            TimeElapsedColumn(),
            console=console,
            transient=False,
            disable=not console.is_terminal,
        ) as bar:
            task = bar.add_task("run", total=scenario.epochs, rate=0.0, drops=0)

            lines = None if console.is_terminal else epoch_lines(strategy, scenario.epochs)

            def progress(
                done: int, total: int, drops: int, _t: Any = task, _lines: Any = lines
            ) -> None:
                elapsed = bar.tasks[0].elapsed or 0.0
                bar.update(_t, completed=done, rate=done / elapsed if elapsed else 0.0, drops=drops)
                if _lines is not None:
                    _lines(done, total, drops)

            started: list[str] = []  # the run's id, once every process is up

            def on_started(run_id: str, _endpoint: str, _into: list[str] = started) -> None:
                _into.append(run_id)

            try:
                outcome = launch(
                    scenario,
                    strategy=strategy,
                    seed=args.seed,
                    runs_dir=Path(args.runs_dir),
                    pool=pool,
                    record=not args.no_record,
                    progress=progress,
                    restart=args.restart,
                    recorder_args=live,
                    on_started=on_started,
                )
            except RunEnded as exc:  # what was recorded is reported, with why the run ended
                if not args.no_record:
                    _report(Path(exc.run_dir), console)
                raise
            except RuntimeFailure:  # a run that started (every agent gone): its summary too
                if started and not args.no_record:
                    ended_summary(strategy, Path(args.runs_dir) / started[0], console)
                raise
        outcomes.append(outcome)
        write_deadlines(outcome.run_dir, outcome.summary())
        if not args.no_record:
            recorded[outcome.run_id] = _report(outcome.run_dir, console)
        console.print(f"{strategy}: files in [bold]{outcome.run_dir}[/]")
    if len(outcomes) > 1 and not args.no_record:
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
        compare = Path(args.runs_dir) / f"{scenario.name}-compare-{stamp}"
        report = write_reports([o.run_dir / "run.mcap" for o in outcomes], compare)
        console.print(f"comparison of the {len(outcomes)} runs: [bold]{report}[/]")
    _print_summary(outcomes, Console(), recorded)
    _print_losses(outcomes, Console())
    return 0


def _line(text: str) -> None:
    print(f"formation run: {text}", file=sys.stderr, flush=True)


def epoch_lines(
    strategy: str, epochs: int, out: Callable[[str], None] = _line
) -> Callable[[int, int, int], None]:
    """The progress callback off a terminal: a line every tenth of the run's epochs and at its
    end (the bar's figures: epochs done, drops, epochs/s)."""
    step, started, said = every(epochs), time.perf_counter(), [0]

    def progress(done: int, total: int, drops: int) -> None:
        if done == said[0] or (done - said[0] < step and done < total):
            return
        said[0] = done
        rate = done / max(time.perf_counter() - started, 1e-9)
        out(f"{strategy}: epoch {done}/{total}, {drops} packets dropped, {rate:.1f} epochs/s")

    return progress


def live_view_line(port: int) -> str:
    """Where to point Foxglove (Open connection → Foxglove WebSocket) for ``--foxglove PORT``."""
    if port == 0:
        return "live view for Foxglove: on a free port that the recorder's log names"
    return f"live view for Foxglove: ws://127.0.0.1:{port} (Open connection, Foxglove WebSocket)"


def _live_args(args: argparse.Namespace) -> tuple[str, ...]:
    """The recorder's live-view arguments (``--foxglove PORT [--foxglove-wait]``)."""
    if args.foxglove is None:
        return ()
    if args.no_record:
        from formation.errors import TestbedError

        raise TestbedError(
            "--foxglove needs the recorder (it serves the live view); drop --no-record"
        )
    return ("--foxglove", str(args.foxglove)) + (("--foxglove-wait",) if args.foxglove_wait else ())


def _print_losses(outcomes: list[Any], console: Console) -> None:
    """Each process lost during a run: when, its drops, and whether it came back."""
    for o in outcomes:
        for loss in o.summary().get("losses", []):
            when = "before the start" if loss["after_start_s"] < 0 else f"at epoch {loss['epoch']}"
            missed = (
                "" if "missed" not in loss else f", {loss['missed']} states its receivers missed"
            )
            again = (
                ""
                if loss["restarted_pid"] is None
                else f", restarted as pid {loss['restarted_pid']}"
            )
            back = loss["back_from_epoch"]
            cause = loss_cause(o.run_dir, loss["name"], loss["code"])
            console.print(
                f"{o.strategy}: {loss['name']} (pid {loss['pid']}) lost {when}: {cause} "
                f"(exit code {loss['code']}, {loss['dropped']} packets dropped on its links"
                f"{missed}){again}" + ("" if back is None else f", back from epoch {back}"),
                soft_wrap=True,  # one line even in a pipe, for grep
            )


def _report(run_dir: Path, console: Console) -> dict[str, Any]:
    """Writes the report; returns its ``summary.json`` entry: :func:`analysis.summarise` of the
    recording as the trust gate passed it (``skipped``: what it did not trust)."""
    from recorder import write_report

    path = write_report(run_dir / "run.mcap", run_dir)
    console.print(f"report: {path}")
    (summary,) = json.loads((run_dir / "summary.json").read_text())
    skipped: dict[str, Any] = summary.get("skipped", {})
    if skipped.get("total"):
        reasons = ", ".join(f"{r} {v}" for r, v in skipped["by_reason"].items())
        console.print(
            f"the report skipped {skipped['total']} recorded messages it does not trust "
            f"({reasons}) on {len(skipped['by_channel'])} channels: see {path}"
        )
    return summary  # type: ignore[no-any-return]


def ended_summary(strategy: str, run_dir: Path, console: Console) -> None:
    """A run that ended early: its report and summary from what was recorded (a recording
    its recorder could not close is recovered first); nothing if none is readable."""
    from formation.errors import RecordingError
    from recorder import recover, write_report

    mcap = run_dir / "run.mcap"
    try:
        try:
            recorded = _report(run_dir, console)
        except RecordingError:  # not closed: its records up to where it stopped
            recovered = recover(mcap, run_dir / "run-recovered.mcap").target
            path = write_report(recovered, run_dir)
            console.print(f"report: {path}")
            (recorded,) = json.loads((run_dir / "summary.json").read_text())
    except (RecordingError, OSError) as exc:
        console.print(f"{strategy}: no summary: the recording cannot be read ({exc})")
        return
    console.print(
        f"{strategy}: the run ended early, after {recorded['epochs']} epochs: final formation "
        f"error {_number(recorded['final_formation_error_m'])} m, shape "
        f"{_number(recorded['final_shape_error_m'])} m (from the recording)",
        soft_wrap=True,
    )
    for line in robot_notes(strategy, {}, recorded):
        console.print(line, soft_wrap=True)


def headline(outcome: Any, recorded: dict[str, Any] | None) -> dict[str, Any]:
    """The numbers of a run's summary row: its final errors, safety and skips from its
    recording as the trust gate passed it (``recorded``: its ``summary.json`` entry); without
    a recording (``--no-record``), from what the launcher saw."""
    if recorded is not None:
        safe = recorded["safety"]
        return {n: recorded[n] for n in _FINAL} | {
            "min_distance_m": safe["min_distance_m"],
            "collisions_total": safe["collisions_total"],
            "skipped": recorded["skipped"]["total"],
        }
    from analysis import safety_counts

    seen, safe = outcome.summary(), safety_counts(outcome.scenario, outcome.positions)
    return {n: seen[n] for n in _FINAL} | {
        "min_distance_m": safe["min_distance_m"],
        "collisions_total": safe["collisions_total"],
        "skipped": None,
    }


_FINAL = ("final_formation_error_m", "final_shape_error_m")

RUN_COLUMNS = (
    "strategy",
    "seed",
    "epochs",
    "formation\nfinal [m]",
    "shape\nfinal [m]",
    "sent\n[pkts]",
    "dropped\n[pkts]",
    "links with drops\n(sent/dropped) [pkts]",
    "mal-\nformed [msgs]",
    "skipped\n[msgs]",
    "min dist\n[m]",
    "colli-\nsions [#]",
    "wall [s]",
)
REALTIME_COLUMNS = ("modelled\nlosses [pkts]", "deadline\nmisses [pkts]")


def _print_summary(
    outcomes: list[Any], console: Console, recorded: dict[str, dict[str, Any]]
) -> None:
    realtime = any(o.scenario.runtime.mode == "realtime" for o in outcomes)
    table = Table(title="formation run: summary")
    cols = list(RUN_COLUMNS)
    if realtime:
        cols += REALTIME_COLUMNS
    for col in cols:
        table.add_column(header(col), justify="left" if col in ("strategy", cols[7]) else "right")
    for o in outcomes:
        s = o.summary()
        top = headline(o, recorded.get(o.run_id))
        worst = sorted(s["dropped_links"].items(), key=lambda kv: -kv[1][1])
        links = ", ".join(f"{k} {v[0]}/{v[1]}" for k, v in worst[:4]) or "-"
        if len(worst) > 4:
            links += f" (+{len(worst) - 4} more)"
        row = [
            s["strategy"],
            str(s["seed"]),
            str(s["epochs"]),
            _number(top["final_formation_error_m"]),
            _number(top["final_shape_error_m"]),
            str(s["packets_sent"]),
            str(s["packets_dropped"]),
            links,
            str(sum(s["malformed"].values())),
            "-" if top["skipped"] is None else str(top["skipped"]),
            "-" if top["min_distance_m"] is None else f"{top['min_distance_m']:.3g}",
            str(top["collisions_total"]),
            f"{s['wall_s']:.1f}",
        ]
        if realtime:
            row += deadline_cells(s)
        table.add_row(*row)
    print_table(table, console)
    for o in outcomes:
        s = o.summary()
        if "loss_split" in s:  # capacity queues (docs/model.md §9)
            lost = s["loss_split"]
            console.print(
                f"{o.strategy}: losses {lost['channel']} channel, {lost['queue']} queue (full), "
                f"{lost['deadline']} deadline (left a queue late)"
            )
        if "air_losses" in s:  # the shared air (docs/model.md §11)
            lost = ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in s["air_losses"].items())
            console.print(f"{o.strategy}: lost on the air: {lost}")
        for line in deadline_notes(o.strategy, s):
            console.print(line)
        for line in robot_notes(o.strategy, s, recorded.get(o.run_id)):
            console.print(line, soft_wrap=True)


def _number(v: float | None) -> str:
    return "-" if v is None else f"{v:.4g}"


def register(sub: Any) -> None:
    p = sub.add_parser("run", help="run a scenario as real processes over Zenoh")
    add_common(p)
    p.add_argument(
        "--mode",
        choices=["lockstep", "realtime"],
        default="lockstep",
        help="lockstep: every epoch waits for its packets (equals simulate to the bit); "
        "realtime: epochs on the wall clock (default lockstep)",
    )
    p.add_argument(
        "--period-s",
        type=float,
        help="realtime: wall-clock epoch period [s] (default: the scenario's)",
    )
    p.add_argument(
        "--pool",
        type=int,
        metavar="K",
        help="run the agents in K processes (default: one per agent; realtime: sized for the machine)",
    )
    p.add_argument("--runs-dir", default="runs", help="where run folders go (default: runs)")
    p.add_argument("--no-record", action="store_true", help="run without the recorder")
    p.add_argument(
        "--restart",
        choices=RESTART_POLICIES,
        default="no",
        help="on-failure: start a dead agent or leader again; it rejoins the run",
    )
    p.add_argument(
        "--foxglove",
        type=int,
        metavar="PORT",
        help="watch it live: Foxglove's WebSocket server on ws://127.0.0.1:PORT",
    )
    p.add_argument(
        "--foxglove-wait",
        action="store_true",
        help="with --foxglove: start once a viewer watches the scene (at most 50 s)",
    )
    p.set_defaults(func=cmd_run)
