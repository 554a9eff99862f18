"""The ``formation`` subcommands: the module that registers each, its summary and its examples.

Nothing here imports a subcommand's module: ``formation --help`` lists them from this table alone.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Command:
    """One subcommand: the module whose ``register`` adds it, its one-line help, its examples."""

    module: str
    summary: str
    examples: tuple[str, ...]


COMMANDS: dict[str, Command] = {
    "simulate": Command(
        "testbed.cli.simulate",
        "run the model in one process (no Zenoh)",
        (
            "formation simulate paper",
            "formation simulate paper --strategy all --seed 3",
            "formation simulate my_team.toml --epochs 200 --json > summary.json",
        ),
    ),
    "run": Command(
        "testbed.cli.run",
        "run a scenario as real processes over Zenoh",
        (
            "formation run paper --strategy all",
            "formation run paper --mode realtime --period-s 0.1",
            "formation run paper --foxglove 8765   # then open ws://127.0.0.1:8765 in Foxglove",
        ),
    ),
    "scenarios": Command(
        "testbed.cli.scenarios",
        "list the shipped scenarios, by the name the other commands take",
        ("formation scenarios", "formation simulate ring8"),
    ),
    "netem": Command(
        "testbed.cli.netem",
        "show or change a running run's link models",
        ("formation netem show", "formation netem set '1->2' bernoulli p_loss=0.3"),
    ),
    "report": Command(
        "testbed.cli.recorder",
        "report.md and PNG plots from one or more recordings",
        (
            "formation report runs/RUN/run.mcap",
            "formation report runs/A/run.mcap runs/B/run.mcap -o compare/",
        ),
    ),
    "info": Command(
        "testbed.cli.recorder",
        "scenario, duration, channels, message counts, drops per link",
        ("formation info runs/RUN/run.mcap", "formation info runs/RUN/run.mcap --validate"),
    ),
    "recover": Command(
        "testbed.cli.recorder",
        "a clean MCAP file from a recording cut short",
        ("formation recover runs/RUN/run.mcap",),
    ),
    "export": Command(
        "testbed.cli.recorder",
        "a recording's tables (states, estimates, ...) as files",
        ("formation export runs/RUN/run.mcap tables/ --format csv",),
    ),
    "replay": Command(
        "testbed.cli.replay",
        "publish a recording back onto Zenoh with its timing",
        (
            "formation replay runs/RUN/run.mcap --rate 2",
            "formation replay runs/RUN/run.mcap --foxglove 8765",
        ),
    ),
    "compose": Command(
        "testbed.cli.deploy",
        "print compose.yaml for a scenario (one service per process)",
        ("formation compose paper > compose.yaml", "formation compose paper --open"),
    ),
    "keys": Command(
        "testbed.cli.deploy",
        "write development credentials and the router's access control",
        ("formation keys keys/ paper", "formation keys keys/ paper --tls --tls-host router"),
    ),
    "experiment": Command(
        "testbed.cli.experiment",
        "reproduce the chapter's experiment and the studies beyond it",
        (
            "formation experiment paper",
            "formation experiment paper --seeds 5 --no-real --out /tmp/paper",
            "formation experiment wireless --seeds 3",
        ),
    ),
    "sweep": Command(
        "testbed.cli.experiment",
        "critical loss rate (or link model parameter) per strategy and topology",
        (
            "formation sweep paper --seeds 10 --loss 0:0.5:0.1",
            "formation sweep paper --topology none --strategy all --burst",
        ),
    ),
    "plugins": Command(
        "testbed.cli.plugins",
        "list every loss strategy, controller and link model, built-in or installed",
        ("formation plugins", "formation plugins --json"),
    ),
    "ros2-plant": Command(
        "testbed.cli.plant",
        "the headless ROS 2 plant: a scenario's robots, without a robot",
        ("formation ros2-plant robots", "formation ros2-plant robots --clock free --rate-hz 10"),
    ),
    "robots": Command(
        "testbed.cli.robots",
        "where to place a scenario's robots before a run",
        ("formation robots robots", "formation robots my_fleet.toml --seed 2"),
    ),
}


def epilog(examples: tuple[str, ...]) -> str:
    """The examples block printed under a parser's help."""
    return "examples:\n" + "\n".join(f"  {line}" for line in examples)


__all__ = ["COMMANDS", "Command", "epilog"]
