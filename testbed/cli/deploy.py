"""``formation compose | keys``: the deployment's compose file and its development credentials."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from testbed.cli.arguments import DEFAULT_SCENARIO, SCENARIO_HELP, load_checked


def cmd_compose(args: argparse.Namespace) -> int:
    from testbed.deploy.compose import ComposeOptions, render

    options = ComposeOptions(
        secure=not args.open,
        tls=args.tls,
        plugins=tuple(args.plugin or ()),
        file=args.file or "compose.yaml",
    )
    path = _checkout_path(args.scenario)
    sys.stdout.write(render(path, options, load_checked(args.scenario)))
    return 0


def _checkout_path(scenario: str) -> str:
    """How the compose file mounts the scenario: a shipped one by its path in the checkout
    (``scenarios/NAME.toml``, beside the Dockerfile that compose builds), a file as given."""
    from formation.shipped_scenarios import resolve

    return scenario if resolve(scenario) == Path(scenario) else f"scenarios/{scenario}.toml"


def cmd_keys(args: argparse.Namespace) -> int:
    from testbed.deploy.security import generate

    scenario = load_checked(args.scenario)
    hosts = args.tls_host or ["router"]
    keyset = generate(
        Path(args.out_dir),
        scenario.n,
        tls=args.tls,
        tls_hosts=hosts,
        force=args.force,
        body=scenario.body,
    )
    users = ", ".join(sorted(keyset.configs))
    print(
        f"keys: {keyset.out_dir}: {keyset.passwords_file.name}, {keyset.router_config.name} "
        f"(access control for {scenario.n} agents), one config per user ({users})"
        + (f"; TLS for {', '.join(hosts)}" if args.tls else ""),
        file=sys.stderr,
    )
    return 0


def register(sub: Any) -> None:
    p = sub.add_parser(
        "compose", help="print compose.yaml for a scenario (one service per process)"
    )
    p.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO, help=SCENARIO_HELP)
    p.add_argument(
        "--open",
        action="store_true",
        help="no authentication or access control (trusted networks only)",
    )
    p.add_argument("--tls", action="store_true", help="TLS links (needs `formation keys --tls`)")
    p.add_argument(
        "--plugin",
        action="append",
        help="a plug-in package the image installs: a pip requirement or a folder of the "
        "build context (repeatable; the Dockerfile's PLUGINS build argument)",
    )
    p.add_argument("--file", help="the file's name, for its usage lines (default compose.yaml)")
    p.set_defaults(func=cmd_compose)

    p = sub.add_parser("keys", help="write development credentials and the router's access control")
    p.add_argument("out_dir", help="folder for the files (e.g. keys/, never committed)")
    p.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO, help=SCENARIO_HELP)
    p.add_argument("--tls", action="store_true", help="also a CA and the router's TLS certificate")
    p.add_argument(
        "--tls-host",
        action="append",
        help="name or IP in the router's certificate (repeatable; default: router)",
    )
    p.add_argument("--force", action="store_true", help="overwrite a non-empty folder")
    p.set_defaults(func=cmd_keys)
