"""A standalone netem with a router, and a bench session posing as the agents (for the netem benches)."""

from __future__ import annotations

import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import zenoh

from formation import keys
from formation.scenario import Scenario
from shell import session_config
from testbed.runtime.processes import ProcessGroup, free_port, wait_for_port

ROOT = Path(__file__).resolve().parents[1]
RUN = "bench"


def bench_scenario(epochs: int, network: dict[str, Any] | None = None) -> Scenario:
    return Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(
        epochs=epochs, network=network or {}
    )


@contextmanager
def netem_rig(
    epochs: int, passthrough: bool = False, network: dict[str, Any] | None = None
) -> Iterator[tuple[zenoh.Session, str, int]]:
    """Yield ``(session, router endpoint, netem pid)`` once netem started.

    The scenario is the paper's with ``network`` (default: no loss).
    """
    with tempfile.TemporaryDirectory() as tmp:
        scenario = bench_scenario(epochs, network)
        path = Path(tmp) / "s.toml"
        path.write_text(scenario.to_toml())
        port = free_port()
        endpoint = f"tcp/127.0.0.1:{port}"
        group = ProcessGroup(Path(tmp) / "logs")
        try:
            group.start("router", "testbed.runtime.router", "--listen", endpoint)
            wait_for_port("127.0.0.1", port, 10)
            extra = ["--passthrough"] if passthrough else []
            netem = group.start("netem", "netem", "--scenario", str(path), "--run-id", RUN, "--mode", "peer",
                        "--connect", endpoint, "--listen", "tcp/127.0.0.1:0", "--no-recorder", *extra)  # fmt: skip
            with zenoh.open(session_config("peer", endpoint, "tcp/127.0.0.1:0")) as session:
                live = session.liveliness()
                tokens = [live.declare_token(keys.alive(RUN, "agent", i)) for i in range(1, 6)]
                tokens.append(live.declare_token(keys.alive(RUN, "leader", 0)))
                started: list[int] = []
                watch = live.declare_subscriber(
                    keys.start(RUN), lambda _: started.append(1), history=True
                )
                deadline = time.monotonic() + 30
                while not started:
                    if time.monotonic() > deadline:
                        raise RuntimeError("netem did not start:\n" + group.children[-1].tail())
                    time.sleep(0.01)
                yield session, endpoint, netem.pid
                watch.undeclare()
                for t in tokens:
                    t.undeclare()
        finally:
            group.stop_all()
