"""``formation netem show|set``: read and change a running run's link models through netem's queryable."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from formation import keys
from formation.errors import TestbedError
from testbed.cli.tables import print_table


def parse_models(words: list[str]) -> list[dict[str, Any]]:
    """``outage start=10 + bernoulli p_loss=0.2`` → model dicts (validated by netem)."""
    models: list[dict[str, Any]] = []
    for group in " ".join(words).split("+"):
        parts = group.split()
        if not parts:
            raise TestbedError("expected a model name, e.g. bernoulli p_loss=0.2")
        spec: dict[str, Any] = {"model": parts[0]}
        for kv in parts[1:]:
            key, sep, value = kv.partition("=")
            if not sep:
                raise TestbedError(f"{kv!r}: expected NAME=VALUE, e.g. p_loss=0.2")
            try:
                spec[key] = json.loads(value)
            except json.JSONDecodeError:
                spec[key] = value
        models.append(spec)
    return models


def queue_request(target: str, models: list[dict[str, Any]]) -> dict[str, Any]:
    """``3->0`` / ``radio:3`` / ``medium:ap`` and ``rate NAME=VALUE ...`` as a capacity entry."""
    if len(models) != 1:
        raise TestbedError(
            "rate takes no other model: formation netem set 3->0 rate rate_bps=64000"
        )
    params = {k: v for k, v in models[0].items() if k != "model"}
    scope, _, name = target.partition(":")
    if scope == "radio" and name:
        try:
            return {"scope": "radio", "agent": int(name), **params}
        except ValueError:
            raise TestbedError(f"{target!r}: expected radio:AGENT, e.g. radio:3") from None
    if scope == "medium" and name:
        return {"scope": "medium", "medium": name, "links": "all", **params}
    try:
        src, dst = (int(e) for e in target.split("->"))
    except ValueError:
        raise TestbedError(
            f"{target!r}: expected SRC->DST (0 is the leader), radio:AGENT or medium:NAME"
        ) from None
    return {"scope": "link", "link": [src, dst], **params}


def find_run(args: argparse.Namespace) -> tuple[str, str]:
    """The run id and endpoint: from flags, or the newest run under ``--runs-dir`` that has a pids.json."""
    if args.run_id and args.connect:
        return str(args.run_id), str(args.connect)
    runs = sorted(Path(args.runs_dir).glob("*/pids.json"), key=lambda p: p.stat().st_mtime)
    if args.run_id:
        runs = [p for p in runs if p.parent.name == args.run_id]
    if not runs:
        raise TestbedError(
            f"no running run found under {args.runs_dir}/ (give --run-id and --connect)"
        )
    path = runs[-1]
    return path.parent.name, str(args.connect or json.loads(path.read_text())["endpoint"])


def ask(
    run_id: str, endpoint: str, request: dict[str, Any], timeout_s: float = 5.0
) -> dict[str, Any]:
    import zenoh  # here: `formation netem --help` loads no Zenoh

    from shell import session_config

    try:
        session = zenoh.open(session_config("client", endpoint, None))
    except zenoh.ZError as exc:
        raise TestbedError(f"cannot reach {endpoint}: {str(exc).split(' at /')[0]}") from None
    try:
        for reply in session.get(
            keys.netem_config(run_id), payload=json.dumps(request).encode(), timeout=timeout_s
        ):
            if reply.ok is not None:
                answer: dict[str, Any] = json.loads(reply.ok.payload.to_bytes())
                return answer
    finally:
        session.close()
    raise TestbedError(f"netem of run {run_id} did not answer on {endpoint}")


def cmd_netem(args: argparse.Namespace) -> int:
    run_id, endpoint = find_run(args)
    console = Console()
    if args.action == "show":
        answer = ask(run_id, endpoint, {"op": "show"})
        table = Table(title=f"netem of {run_id} (epoch {answer['epoch']})")
        for col in ("link", "class", "models"):
            table.add_column(col)
        for link in answer["links"]:
            models = " + ".join(
                m["model"] + "".join(f" {k}={v}" for k, v in m.items() if k != "model")
                for m in link["models"]
            )
            table.add_row(link["link"], link["class"], models or "up")
        print_table(table, console)
        if answer.get("air"):  # the shared air (docs/model.md §11)
            air = answer["air"]
            params = " ".join(f"{k}={v}" for k, v in air.items() if k not in ("kind", "links"))
            console.print(f"medium:air carries {air['links']} links: {params}")
        return 0
    if not args.link or not args.model:
        raise TestbedError("usage: formation netem set LINK MODEL [NAME=VALUE ...] [+ MODEL ...]")
    if args.link == "medium:air":  # the shared air's parameters, not a queue's
        (air_params,) = parse_models(["air", *[w for w in args.model if w != "air"]])
        air_params.pop("model")
        answer = ask(run_id, endpoint, {"op": "air", "air": air_params})
        if not answer.get("ok"):
            raise TestbedError(f"netem refused the change: {answer.get('error')}")
        console.print(f"medium:air: {_words(answer['air'])} from epoch {answer['from_epoch']}")
        return 0
    specs = parse_models(args.model)
    if specs[0]["model"] == "rate":  # a capacity queue (docs/model.md §9)
        answer = ask(run_id, endpoint, {"op": "capacity", "queue": queue_request(args.link, specs)})
        if not answer.get("ok"):
            raise TestbedError(f"netem refused the change: {answer.get('error')}")
        console.print(
            f"{answer['queue']} ({answer['links']} links): new rate from epoch {answer['from_epoch']}"
        )
        return 0
    answer = ask(run_id, endpoint, {"op": "set", "link": args.link, "models": specs})
    if not answer.get("ok"):
        raise TestbedError(f"netem refused the change: {answer.get('error')}")
    console.print(
        f"link {answer['link']} ({answer['class']}): new models from epoch {answer['from_epoch']}"
    )
    return 0


def _words(params: dict[str, Any]) -> str:
    return " ".join(f"{k}={v}" for k, v in params.items() if k != "model")


# what makes a queue equal Linux's (docs/model.md §9)
RATE_HELP = """\
a queue's parameters are tc's (docs/model.md §9):
  rate_bps        [bit/s] the rate, a multiple of 8 (tc keeps bytes a second)
  burst_bytes     [B] tbf's burst; 0 is netem rate (serialisation), not a small bucket
  limit_bytes     [B] tbf's limit
  limit_packets   a pfifo child of tbf (tc qdisc add ... parent 1:1 pfifo limit N)
  policy          tail, or oldest: a pfifo_head_drop child (Linux has none in bytes)
  overhead_bytes  [B] added to each payload: 42 for UDP over IPv4 on Ethernet or loopback
e.g. formation netem set 3->0 rate rate_bps=64000 burst_bytes=3000 limit_packets=5 \\
       policy=oldest overhead_bytes=42
the shared air's ([network.air], docs/model.md §11), from the next epoch:
  formation netem set medium:air rate_mbps=12 shadowing_sigma_db=4"""


def register(sub: Any) -> None:
    p = sub.add_parser(
        "netem",
        help="show or change a running run's link models",
        description="Show or change a running run's link models and capacity queues.",
        epilog=RATE_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "action", choices=["show", "set"], help="show every link's models, or set one link's"
    )
    p.add_argument(
        "link",
        nargs="?",
        help="SRC->DST, e.g. 1->2 (0 is the leader); with rate also radio:AGENT or medium:NAME; "
        "medium:air for the shared air",
    )
    p.add_argument(
        "model",
        nargs="*",
        help="e.g. bernoulli p_loss=0.3, or outage start=0 + bernoulli p_loss=0.1, or a queue's "
        "rate rate_bps=64000 limit_packets=4",
    )
    p.add_argument(
        "--runs-dir",
        default="runs",
        help="where to find the newest running run (default: runs)",
    )
    p.add_argument("--run-id", help="the run to talk to (default: the newest under --runs-dir)")
    p.add_argument("--connect", help="the run's Zenoh endpoint (default: from its pids.json)")
    p.set_defaults(func=cmd_netem)
