"""``formation experiment`` and ``formation sweep``: experiments from the terminal."""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from formation.errors import SweepError, TestbedError
from formation.shipped_scenarios import resolve, shipped
from testbed.cli.arguments import (
    DEFAULT_SCENARIO,
    SCENARIO_HELP,
    StrategiesHelp,
    load_checked,
    parse_strategies,
)
from testbed.cli.progress import every
from testbed.cli.tables import print_table
from testbed.experiments.executors import SCHEDULER_FORMS, executor_for
from testbed.experiments.sweep_spec import SweepSpec, loss_grid, value_grid

if TYPE_CHECKING:
    from formation.scenario import Scenario

# The experiments themselves load in their commands: `formation sweep --help` and `formation
# experiment --help` load no numerics, Zenoh or plots.

EXPERIMENTS = ("paper", "wireless", "capacity", "value")
DEFAULT_TOPOLOGIES = ("ring8", "grid20", "octahedron3d")
LOSS = "0:1:0.05"  # sweep's default grid of loss rates
CHAPTER_STRATEGIES = ("zero", "hold", "estimate", "blend")
VALUE_EPOCHS = 300  # testbed.experiments.value.EPOCHS, which loads numpy (a test holds them equal)


def cmd_experiment(args: argparse.Namespace) -> int:
    if args.name not in EXPERIMENTS:
        raise TestbedError(f"experiment {args.name!r}: expected one of {', '.join(EXPERIMENTS)}")
    console = Console(stderr=True)
    scenario = load_checked(args.scenario)
    out = Path(args.out or f"experiments/{args.name}")
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    started = time.perf_counter()
    if args.name == "wireless" and args.contention:
        return _contention(args, out, tuple(seeds), console)
    if args.name == "wireless":
        return _wireless(args, scenario, out, tuple(seeds), console)
    if args.name == "capacity":
        return _capacity(args, scenario, out, tuple(seeds), console)
    if args.name == "value":
        return _value(args, scenario, out, tuple(seeds), console)
    from testbed.experiments.paper_run import run_paper

    result = run_paper(
        scenario,
        out,
        seeds=seeds,
        real=not args.no_real,
        record=not args.no_record,
        log=lambda m: console.print(m, soft_wrap=True),
    )
    table = Table(title=f"formation experiment {args.name}: the chapter's claims")
    for col in ("claim", "verdict"):
        table.add_column(col)
    for c in result.claims:
        table.add_row(c.text.replace("`", ""), c.verdict)
    print_table(table)
    for row in result.real:
        console.print(
            f"real processes {row['strategy']} seed {row['seed']}: max |Δx| {row.get('max_diff_text')}"
            f", recorded {row.get('recorded_diff_text', '-')}, match {row.get('match', 'no')}"
        )
    times = ", ".join(f"{k} {v:.1f} s" for k, v in result.timings_s.items())
    console.print(
        f"wrote {out}/results.md ({times}; total {time.perf_counter() - started:.1f} s)",
        soft_wrap=True,
    )
    return 0


def _wireless(
    args: argparse.Namespace, scenario: Scenario, out: Path, seeds: tuple[int, ...], console: Any
) -> int:
    """``formation experiment wireless``: success against radio range, then the real runs."""
    from testbed.experiments.wireless import (
        WirelessSpec,
        run_wireless,
        run_wireless_real,
        write_outputs,
    )

    started = time.perf_counter()
    spec = WirelessSpec(scenario, seeds=seeds, epochs=args.epochs or 100)
    result = run_wireless(spec, log=lambda m: console.print(m, soft_wrap=True))
    if not args.no_real:
        run_wireless_real(
            result, out, record=not args.no_record, log=lambda m: console.print(m, soft_wrap=True)
        )
    write_outputs(result, out)
    Console().print(result.critical_markdown(), markup=False)  # brackets are text
    for row in result.real:
        console.print(
            f"real processes {row['case']}, {row['strategy']} seed {row['seed']}: "
            f"max |Δx| {row['max_diff']}, recorded {row['recorded_diff']}, match {row['match']}"
        )
    console.print(
        f"wrote {out}/results.md, critical.md, runs.csv, phase.png "
        f"({time.perf_counter() - started:.1f} s)"
    )
    return 0


def _contention(args: argparse.Namespace, out: Path, seeds: tuple[int, ...], console: Any) -> int:
    """``formation experiment wireless --contention``: success against team size and PHY rate
    on a shared channel (docs/model.md §11); the simulator only."""
    from testbed.experiments.contention import ContentionSpec, run_contention, write_outputs

    started = time.perf_counter()
    spec = ContentionSpec(
        sizes=_numbers("--agents", args.agents, int) if args.agents else ContentionSpec.sizes,
        rates_mbps=_numbers("--rates", args.rates, float)
        if args.rates
        else ContentionSpec.rates_mbps,
        seeds=seeds,
        epochs=args.epochs or 150,
    )
    result = run_contention(spec, log=lambda m: console.print(m, soft_wrap=True))
    write_outputs(result, out)
    Console().print(result.critical_markdown(), markup=False)
    console.print(
        f"wrote {out}/results.md, critical.md, runs.csv, phase.png "
        f"({time.perf_counter() - started:.1f} s)"
    )
    return 0


def _capacity(
    args: argparse.Namespace, scenario: Scenario, out: Path, seeds: tuple[int, ...], console: Any
) -> int:
    """``formation experiment capacity``: success against the access point's and the radios'
    capacity, the scenario and grid20, then one real run per strategy."""
    from formation.scenario import Scenario
    from testbed.experiments.capacity import CapacitySpec, run_capacity, run_capacity_real
    from testbed.experiments.capacity import write_outputs as write_capacity

    started = time.perf_counter()
    topologies = [(Path(args.scenario).stem, scenario)]
    beside = resolve(args.scenario).parent / "grid20.toml"
    grid = beside if beside.exists() else shipped()["grid20"]
    if args.topology != "none" and grid.stem != topologies[0][0]:
        topologies.append((grid.stem, Scenario.from_file(grid)))
    spec = CapacitySpec(tuple(topologies), seeds=seeds, epochs=args.epochs or 50)
    result = run_capacity(spec, log=lambda m: console.print(m, soft_wrap=True))
    if not args.no_real:
        run_capacity_real(
            result, out, record=not args.no_record, log=lambda m: console.print(m, soft_wrap=True)
        )
    write_capacity(result, out)
    Console().print(result.critical_markdown(), markup=False)  # brackets are text
    for row in result.real:
        console.print(
            f"real processes {row['strategy']} seed {row['seed']}: max |Δx| {row['max_diff']}, "
            f"recorded {row['recorded_diff']}, match {row['match']}"
        )
    console.print(
        f"wrote {out}/results.md, critical.md, runs.csv, phase.png "
        f"({time.perf_counter() - started:.1f} s)"
    )
    return 0


def _value(
    args: argparse.Namespace, scenario: Scenario, out: Path, seeds: tuple[int, ...], console: Any
) -> int:
    """``formation experiment value``: where estimate beats drop and hold, then one real run
    of estimate and drop per region."""
    from testbed.experiments.value import EPOCHS, ValueSpec, run_value
    from testbed.experiments.value_outputs import run_value_real
    from testbed.experiments.value_outputs import write_outputs as write_value

    started = time.perf_counter()
    spec = ValueSpec(scenario, seeds=seeds, epochs=args.epochs or EPOCHS)
    frame = run_value(spec, log=lambda m: console.print(m))
    real = []
    if not args.no_real:
        real = run_value_real(frame, spec, out, not args.no_record, lambda m: console.print(m))
    write_value(frame, spec, out, real)
    for row in real:
        console.print(
            f"real processes {row['controller']}, {row['case']}, {row['strategy']} seed "
            f"{row['seed']}: max |Δx| {row['max_diff']}, recorded {row['recorded_diff']}, "
            f"match {row['match']}"
        )
    console.print(
        f"wrote {out}/results.md, runs.csv, value.png ({time.perf_counter() - started:.1f} s)"
    )
    return 0


def _topologies(args: argparse.Namespace) -> list[tuple[str, Scenario]]:
    main = resolve(args.scenario)
    names = (
        [t.strip() for t in args.topology.split(",") if t.strip()]
        if args.topology != "none"
        else []
    )
    out = [(main.stem, load_checked(str(main)))]
    for name in names:
        path = Path(name)
        if not path.suffix:  # a name: beside SCENARIO, else a shipped scenario
            beside = main.parent / f"{name}.toml"
            path = beside if beside.exists() else resolve(name)
        if path.stem not in {n for n, _ in out}:
            out.append((path.stem, load_checked(str(path))))
    return out


def _strategy_list(arg: str | None) -> tuple[Any, ...]:
    return tuple(parse_strategies(arg, CHAPTER_STRATEGIES, {"chapter": CHAPTER_STRATEGIES}))


def _variants(args: argparse.Namespace) -> tuple[tuple[str, ...], tuple[float, ...]]:
    """The loss models and the grid: ``--vary TAG.PARAM=VALUES``, else ``--loss`` (and
    ``--burst``) over the built-in Bernoulli (and Gilbert-Elliott) loss."""
    from testbed.experiments.loss_variants import LOSS_MODELS

    if args.vary is None:
        return (LOSS_MODELS if args.burst else ("bernoulli",)), loss_grid(args.loss or LOSS)
    name, _, values = args.vary.partition("=")
    tag, _, param = name.rpartition(".")
    if not tag or not param or not values:
        raise SweepError(
            f"--vary {args.vary!r}", "expected TAG.PARAM=VALUES, e.g. jammer.length=0:30:5"
        )
    if args.loss is not None or args.burst:
        raise SweepError(
            f"--vary {args.vary!r}",
            "it sets the link models itself: give it without --loss and --burst",
        )
    return (name,), value_grid(values, "--vary")


def cmd_sweep(args: argparse.Namespace) -> int:
    from testbed.experiments.loss_variants import is_parameter, with_parameter
    from testbed.experiments.sweep import critical_table, run_sweep

    console = Console(stderr=True)
    executor = executor_for(args.scheduler, args.jobs)
    topologies = _topologies(args)
    first = topologies[0][1].seed if args.seed is None else args.seed
    models, losses = _variants(args)
    for (_, scenario), model, value in itertools.product(topologies, models, losses):
        if is_parameter(model):  # every topology has the model, and takes every value
            with_parameter(scenario, model, value)
    spec = SweepSpec(
        topologies=tuple(topologies),
        losses=losses,
        strategies=_strategy_list(args.strategy),
        seeds=tuple(range(first, first + args.seeds)),
        models=models,
        epochs=args.epochs,
        threshold_m=args.threshold,
        burst_epochs=args.burst_epochs,
        seeds_per_chunk=args.chunk_seeds,
    )
    out = Path(args.out)
    started = time.perf_counter()
    with Progress(
        TextColumn("[bold]sweep[/]"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[rate]} cells/s"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        disable=not console.is_terminal,
    ) as bar:
        task = bar.add_task("cells", total=None, rate="-")
        first_done: list[int] = []
        said = [0]  # off a terminal: the cells done at the last line

        def progress(done: int, total: int) -> None:
            if not first_done:
                first_done.append(done)
            ran = done - first_done[0]
            elapsed = time.perf_counter() - started
            rate = f"{ran / elapsed:.0f}" if elapsed > 0 and ran else "-"
            bar.update(task, completed=done, total=total, rate=rate)
            step = done - said[0]
            if not console.is_terminal and step and (step >= every(total) or done == total):
                said[0] = done
                console.print(f"sweep: {done}/{total} cells, {rate} cells/s, {elapsed:.0f} s")

        summary = run_sweep(spec, out, progress=progress, executor=executor)
    wall = time.perf_counter() - started
    ran = len(spec.keys()) - (first_done[0] if first_done else 0)
    Console().print(critical_table(summary), markup=False)
    console.print(
        f"{ran} cells run in {wall:.1f} s ({ran / wall if wall else 0:.0f} cells/s), "
        f"{len(spec.keys()) - ran} already in {out / 'runs.csv'}; tables: {out}/critical.md, "
        f"{out}/success.md, {out}/phase.png"
    )
    return 0


def _numbers(flag: str, text: str, kind: type[int] | type[float]) -> tuple[Any, ...]:
    """A comma list of positive numbers, or a ``TestbedError`` naming ``flag`` and the value."""
    try:
        got = tuple(kind(v) for v in text.split(","))
    except ValueError:
        got = ()
    if not got or min(got) <= 0:
        raise TestbedError(f"{flag} = {text!r}: expected a comma list of positive numbers")
    return got


def register(sub: Any) -> None:
    p = sub.add_parser(
        "experiment", help="reproduce the chapter's experiment and the studies beyond it"
    )
    p.add_argument(
        "name",
        choices=EXPERIMENTS,
        help="which experiment (paper: docs/model.md §8; wireless: success against radio range; "
        "capacity: success against the access point's and the radios' capacity, §9; "
        "value: where estimate beats drop and hold)",
    )
    p.add_argument("--scenario", default=DEFAULT_SCENARIO, help=SCENARIO_HELP)
    p.add_argument("--seeds", type=int, default=20, help="number of seeds (default 20)")
    p.add_argument("--first-seed", type=int, default=1, help="first seed (default 1)")
    p.add_argument("--out", help="output folder (default experiments/NAME)")
    p.add_argument("--no-real", action="store_true", help="skip the runs through real processes")
    p.add_argument("--no-record", action="store_true", help="real processes without the recorder")
    p.add_argument(
        "--epochs",
        type=int,
        help=f"epochs per run (wireless: default 100, with --contention 150; capacity: 50; "
        f"value: {VALUE_EPOCHS})",
    )
    p.add_argument(
        "--contention",
        action="store_true",
        help="wireless: success against team size and PHY rate on one shared 802.11 channel "
        "(the estimation traffic on the states' channel, on its own or off the air) instead of "
        "against radio range",
    )
    p.add_argument(
        "--agents",
        metavar="N,N,...",
        help="wireless --contention: the team sizes, evenly spaced (default 5,10,15,20)",
    )
    p.add_argument(
        "--rates",
        metavar="MBPS,...",
        help="wireless --contention: the PHY rates [Mb/s] (default 6,24)",
    )
    p.add_argument(
        "--topology",
        default="grid20",
        help="capacity: also grid20 beside SCENARIO (default), or none",
    )
    p.set_defaults(func=cmd_experiment)

    p = sub.add_parser(
        "sweep",
        help="critical loss rate (or link model parameter) per strategy and topology",
        description="By default every formation link of each topology is put under the "
        "built-in Bernoulli loss (--burst: also Gilbert-Elliott) at each rate of --loss, "
        "replacing the scenario's own formation link models. --vary TAG.PARAM=VALUES keeps "
        "the scenario's link models and sets PARAM of every model TAG in it (yours or ours) "
        "to each value instead.",
    )
    p.add_argument(
        "scenario", nargs="?", default=DEFAULT_SCENARIO, help=f"the first topology: {SCENARIO_HELP}"
    )
    p.add_argument(
        "--loss",
        help=f"START:STOP:STEP or a comma list of loss rates, replacing the formation links' "
        f"models (default {LOSS})",
    )
    p.add_argument(
        "--vary",
        metavar="TAG.PARAM=VALUES",
        help="keep the scenario's link models and set PARAM of each model TAG to every value "
        "(START:STOP:STEP or a comma list), e.g. jammer.length=0:30:5 or bernoulli.p_loss=0,0.2",
    )
    p.add_argument(
        "--strategy",
        help=StrategiesHelp(
            "chapter (zero,hold,estimate,blend; default), all (every installed one: "
            "{strategies}) or a comma list"
        ),
    )
    p.add_argument("--seeds", type=int, default=50, help="seeds per cell (default 50)")
    p.add_argument("--seed", type=int, help="first seed (default: the scenario's)")
    p.add_argument(
        "--contention",
        action="store_true",
        help="wireless: success against team size and PHY rate on one shared 802.11 channel "
        "(reports and estimates on it or off it) instead of against radio range",
    )
    p.add_argument(
        "--topology",
        default=",".join(DEFAULT_TOPOLOGIES),
        help="more topologies: names beside SCENARIO or paths, comma separated; none for only SCENARIO "
        f"(default {','.join(DEFAULT_TOPOLOGIES)})",
    )
    p.add_argument(
        "--burst", action="store_true", help="also Gilbert-Elliott loss at the same mean rate"
    )
    p.add_argument(
        "--burst-epochs", type=float, default=4.0, help="mean burst of the Gilbert-Elliott model"
    )
    p.add_argument("--epochs", type=int, default=200, help="epochs per run (default 200)")
    p.add_argument(
        "--threshold",
        type=float,
        default=0.05,
        help="final shape error that keeps [m] (default 0.05)",
    )
    p.add_argument(
        "--out", default="experiments/sweep", help="output folder (default experiments/sweep)"
    )
    p.add_argument(
        "--jobs", type=int, help="worker processes of the local pool (default: every core)"
    )
    p.add_argument(
        "--scheduler",
        help=f"run the cells on a Dask cluster: {SCHEDULER_FORMS} (a local cluster of N "
        "workers); default: the local pool",
    )
    p.add_argument(
        "--chunk-seeds",
        type=int,
        default=10,
        help="seeds per task (default 10; more where a task would be too short for its overhead)",
    )
    p.set_defaults(func=cmd_sweep)


__all__ = ["register"]
