"""``formation run``: a router, the recorder, netem, the leader and the agents as real processes.

The launcher waits for every process's liveliness before epoch 0 (netem declares
the start), follows the run over Zenoh (progress, drops, final states), ends
every process by PID on exit, error or Ctrl-C, and leaves ``runs/<run_id>/``.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections import Counter
from dataclasses import dataclass, field
from datetime import UTC, datetime
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import zenoh

from analysis import RunData, formation_error, loss_split, present, shape_error, spans, summarise
from formation import RuntimeFailure, deadline_counts, realtime_accounting
from formation.errors import RunEnded
from formation.scenario import Scenario, StrategyName
from shell import session_config
from testbed.runtime import steal
from testbed.runtime.events import EventDriver, bodies
from testbed.runtime.faults import RestartPolicy, Supervisor, first_missing_epoch
from testbed.runtime.observer import Observer, Verdict, all_final, flush_recorder, missing_final
from testbed.runtime.priorities import favour_shared
from testbed.runtime.processes import ProcessGroup, free_port, wait_for_port

HOST = "127.0.0.1"


@dataclass
class RunOutcome:
    """What a distributed run produced, as the launcher observed it over Zenoh."""

    run_id: str
    run_dir: Path
    scenario: Scenario
    strategy: str
    seed: int
    positions: npt.NDArray[np.float64]  # (E + 1, n, d) true states x[k] [m], NaN where never seen
    estimated_epochs: list[int]  # epochs whose estimate the leader published
    decisions: list[Verdict]
    malformed: dict[str, int]
    sent: dict[str, int]  # messages published per key
    pids: list[int]
    wall_s: float
    substitutions: list[tuple[int, int, int, list[float]]]
    extra: dict[str, Any] = field(default_factory=dict)
    delivered: dict[str, int] = field(default_factory=dict)  # packets netem delivered per link

    @property
    def bodies(self) -> npt.NDArray[np.float64]:
        """(E + 1, n, d) positions, a body without a state where it last was (events, losses)."""
        return bodies(self.positions, self.scenario.initial_positions(self.seed))

    @property
    def formation_error(self) -> npt.NDArray[np.float64]:
        return formation_error(self.bodies, self.scenario.edge_array, self.scenario.weights)

    @property
    def shape_error(self) -> npt.NDArray[np.float64]:
        return shape_error(self.bodies, self.scenario.edge_array, self.scenario.offsets)

    def drops_per_link(self) -> dict[str, tuple[int, int]]:
        """``"src->dst" → (sent, dropped)`` over every decision."""
        sent: Counter[str] = Counter()
        dropped: Counter[str] = Counter()
        for d in self.decisions:
            link = f"{d.source}->{d.target}"
            sent[link] += 1
            dropped[link] += d.verdict == "drop"
        return {k: (sent[k], dropped[k]) for k in sorted(sent)}

    def substitution_errors(self) -> npt.NDArray[np.float64]:
        """``x̃_j[k] − x_j[k]`` of every substituted variable, ordered by (epoch, agent, neighbour)."""
        d = self.scenario.dimension
        rows = [np.asarray(v) - self.positions[k, j - 1] for k, _, j, v in self.substitutions]
        return np.array(rows).reshape(-1, d)

    def deadline_accounting(self) -> dict[str, Any]:
        """Realtime: modelled losses, deadline misses by cause, in time (lockstep: no rate)."""
        return realtime_accounting(
            self.extra.get("deadline") or {}, self.drops_per_link(), self.extra.get("cpu_steal")
        )

    def deadline_miss_rate(self) -> float | None:
        """Realtime: deadline misses of the testbed's own making, over the packets sent."""
        return self.deadline_accounting().get("deadline_miss_rate")

    def record(self) -> RunData:
        """What the launcher saw as a run's record: the states (in the team: a state seen)
        and the substitutions; the leader's outputs and the deliveries are the recording's."""
        sc = self.scenario
        n, d, m = sc.n, sc.dimension, len(sc.edges)
        none = np.zeros(0, dtype=np.int64)
        return RunData(
            label=self.strategy,
            scenario=sc,
            strategy=self.strategy,
            seed=self.seed,
            positions=self.positions,
            formation_error=self.formation_error,
            shape_error=self.shape_error,
            estimates=np.zeros((0, n, d)),
            estimate_cov=np.zeros((0, n, d, d)),
            observable=np.zeros((0, n), dtype=bool),
            delivered=np.zeros((0, len(sc.directed_links)), dtype=bool),
            healthy=np.zeros((0, m), dtype=bool),
            tree=np.zeros((0, m), dtype=bool),
            components=none,
            rigidity_rank=none,
            substitution_errors=self.substitution_errors(),
            nees_values=np.zeros(0),
            estimation_errors=np.zeros((0, d)),
            source=str(self.run_dir),
        )

    @cached_property
    def headline(self) -> dict[str, Any]:
        """:func:`analysis.summarise` of :meth:`record`, once (its safety counts are O(n²))."""
        return summarise(self.record())

    def summary(self) -> dict[str, Any]:
        drops = self.drops_per_link()
        headline = self.headline  # the team's final errors, as every summary's
        return {
            "run_id": self.run_id,
            "strategy": self.strategy,
            "seed": self.seed,
            "epochs": int(self.positions.shape[0] - 1),
            "final_formation_error_m": headline["final_formation_error_m"],
            "final_shape_error_m": headline["final_shape_error_m"],
            "packets_sent": sum(s for s, _ in drops.values()),
            "packets_dropped": sum(d for _, d in drops.values()),
            "dropped_links": {k: v for k, v in drops.items() if v[1]},
            **self.capacity_losses(),
            "malformed": self.malformed,
            "mode": self.scenario.runtime.mode,
            "deadline": self.extra.get("deadline", {}),
            **self.deadline_accounting(),
            "priorities": self.extra.get("priorities"),  # realtime: what the launcher set
            "cpu_steal": self.extra.get("cpu_steal"),  # the hypervisor's share of the CPU
            "wall_s": self.wall_s,
            **self.faults_summary(),
        }

    def capacity_losses(self) -> dict[str, Any]:
        """With capacity queues: the drops split into channel, queue and deadline losses."""
        if not self.scenario.network.capacity:
            return {}
        return {"loss_split": loss_split(self.decisions)}

    def faults_summary(self) -> dict[str, Any]:
        """Who died, when and whether it came back, and who was in the team at each epoch
        (``team``: agent → its spans of epochs with a state, with losses and whenever some
        agent lacks a state at some epoch, as with the scenario's events)."""
        losses = self.extra.get("losses", [])
        seen = present(self.positions)
        out: dict[str, Any] = {}
        if losses or not seen.all():
            out["team"] = {str(i): s for i, s in spans(seen).items()}
        if not losses:
            return out
        drops = self.drops_per_link()
        links = self.scenario.directed_links
        for loss in losses:  # its drops: decisions on its links, and the epochs it missed
            name = loss["name"]
            ident = "0" if name == "leader" else name.removeprefix("agent-")
            loss["dropped"] = sum(d for link, (_, d) in drops.items() if ident in link.split("->"))
            if name != "leader":  # the states its receivers went without while it was out
                i = int(ident)
                absent = int((~seen[loss["epoch"] :, i - 1]).sum())
                loss["missed"] = absent * int((links[:, 0] == i).sum())
        return {"losses": losses, **out, "fallbacks": self.extra.get("fallbacks", 0)}


def make_run_id(scenario: Scenario, strategy: str, seed: int) -> str:
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S%f")
    return f"{scenario.name}-{strategy}-s{seed}-{stamp}"


def _pools(n: int, pool: int | None) -> list[list[int]]:
    if not pool:
        return [[i] for i in range(1, n + 1)]
    return [
        list(map(int, ids)) for ids in np.array_split(np.arange(1, n + 1), min(pool, n)) if len(ids)
    ]


def _process_name(ids: list[int]) -> str:
    """An agent process's name: one agent's, or a pool's (its first and last agent)."""
    return f"agent-{ids[0]}" if len(ids) == 1 else f"pool-{ids[0]}-{ids[-1]}"


def launch(
    scenario: Scenario,
    strategy: StrategyName | None = None,
    seed: int | None = None,
    runs_dir: Path = Path("runs"),
    pool: int | None = None,
    record: bool = True,
    startup_timeout_s: float | None = None,
    epoch_timeout_s: float = 30.0,
    progress: Any = None,
    run_id: str | None = None,
    on_started: Any = None,
    zenoh_mode: str = "client",
    restart: RestartPolicy = "no",
    recorder_args: tuple[str, ...] = (),
) -> RunOutcome:
    """Run ``scenario`` as real processes; returns what was observed. Every child ends by PID.

    An agent or the leader that dies is a loss, not the end (``restart="on-failure"``
    starts it again and it rejoins); netem, the router or the recorder dying is an error.
    Client mode, through the router, is the default: zenoh batches each process's traffic on
    its one link (bench/bench_runtime.py, seed 1: 50 agents 16.8 epochs/s against 11.4 as
    peers; 1,000 pooled 1.8 against 1.2; 5 agents the same within noise). Realtime too:
    20 agents at 20 Hz missed 8-10 % of their deadlines as clients against 19-32 % as peers
    (bench_realtime --quick --zenoh-mode, three interleaved pairs).
    """
    strategy = strategy or scenario.strategy.name
    if startup_timeout_s is None:
        startup_timeout_s = (
            60.0 + 0.2 * scenario.n
        )  # large pools take a while to declare their subscribers
    seed = scenario.seed if seed is None else seed
    scenario = scenario.with_overrides(
        seed=seed, strategy={**scenario.strategy.model_dump(), "name": strategy}
    )
    run_id = run_id or make_run_id(scenario, strategy, seed)
    run_dir = runs_dir / run_id
    run_dir.mkdir(parents=True, exist_ok=True)
    scenario_path = run_dir / "scenario.toml"
    scenario_path.write_text(scenario.to_toml())
    # Every process the run may start, and the launcher's own session: only they slow it down.
    members = [
        "launcher",
        "router",
        "recorder",
        "netem",
        "leader",
        *(_process_name(ids) for ids in _pools(scenario.n, pool)),
    ]
    members_file = run_dir / "members.json"
    _write_atomic(members_file, json.dumps(members))
    group = ProcessGroup(run_dir / "logs", members_file=members_file)
    port = free_port(HOST)
    endpoint = f"tcp/{HOST}:{port}"
    common = ["--run-id", run_id, "--mode", zenoh_mode, "--connect", endpoint]
    if zenoh_mode == "peer":
        common += ["--listen", f"tcp/{HOST}:0"]  # peers meet directly, on loopback only
    started = time.monotonic()
    session = None
    observer = None
    try:
        supervisor = Supervisor(group, restart, time.monotonic())
        supervisor.track(
            group.start("router", "testbed.runtime.router", "--listen", endpoint),
            "testbed.runtime.router",
        )
        group.on_start = lambda: _write_atomic(
            run_dir / "pids.json", json.dumps({"endpoint": endpoint, "pids": group.pid_map()})
        )
        wait_for_port(HOST, port, 10.0)
        session = zenoh.open(
            session_config("client", endpoint, None, member="launcher", members=members)
        )
        observer = Observer(session, run_id, scenario)
        if record:
            rec_args = [
                *common,
                "--out",
                str(run_dir),
                "--scenario",
                str(scenario_path),
                *recorder_args,
            ]
            supervisor.track(group.start("recorder", "recorder", *rec_args), "recorder", *rec_args)
            _wait(
                lambda: observer.is_alive("recorder", 0),
                group,
                startup_timeout_s,
                "the recorder to come up",
            )
        netem_args = ["--scenario", str(scenario_path), *common] + (
            [] if record else ["--no-recorder"]
        )
        supervisor.track(group.start("netem", "netem", *netem_args), "netem", *netem_args)
        leader_args = ["--scenario", str(scenario_path), *common]
        supervisor.track(group.start("leader", "leader", *leader_args), "leader", *leader_args)
        realtime = scenario.runtime.mode == "realtime"
        priorities = favour_shared(group.pid_map()) if realtime else None
        EventDriver.check(scenario, pool)
        events = EventDriver(
            scenario,
            supervisor,
            lambda i: ["--scenario", str(scenario_path), "--id", str(i), *common],
        )
        for ids in _pools(scenario.n, pool):
            name = _process_name(ids)
            ident = str(ids[0]) if len(ids) == 1 else f"{ids[0]}-{ids[-1]}"
            agent_args = ["--scenario", str(scenario_path), "--id", ident, *common]
            if len(ids) == 1 and events.starts_later(ids[0]):
                continue  # it joins later (a scenario event)
            supervisor.track(group.start(name, "agent", *agent_args), "agent", *agent_args)
        _wait(
            lambda: observer.is_alive("clock", "start"),
            group,
            startup_timeout_s,
            "every process to come up",
            ignore=supervisor.replaced,
            check=supervisor.check_starting,
        )
        if on_started is not None:
            on_started(run_id, endpoint)
        events.began = time.monotonic()
        supervisor.begin(events.began)
        cpu_before = steal.ticks()
        agent_names = [n for n in supervisor.current if n.startswith(("agent-", "pool-"))]

        def first_missing(name: str) -> int:
            with observer.lock:
                if name == "leader":
                    return len(observer.estimated)
                ids = _ids_of(name)
                return min(
                    first_missing_epoch(np.isfinite(observer.positions[:, i - 1, 0])) for i in ids
                )

        last_progress, last_count = time.monotonic(), -1
        while supervisor.running():
            supervisor.check(first_missing)
            supervisor.check_team(agent_names)
            with observer.lock:
                count, drops = len(observer.estimated), observer.drops
            if progress is not None:
                progress(count, scenario.epochs, drops)
            if count != last_count:
                last_progress, last_count = time.monotonic(), count
            elif time.monotonic() - last_progress > epoch_timeout_s:
                group.dump_stacks()
                raise RuntimeFailure(
                    f"no epoch finished for {epoch_timeout_s:g} s (stuck at epoch {count}); "
                    f"each process's threads are at the end of its log in {group.log_dir}"
                )
            with observer.lock:
                events.step(count, lambda i, k: bool(np.isfinite(observer.positions[k, i - 1, 0])))
            time.sleep(0.02)
        supervisor.check(first_missing)
        supervisor.check_team(agent_names)
        cpu_stolen = steal.share(cpu_before, steal.ticks())
        gone = supervisor.gone_for_good()
        if progress is not None:
            progress(scenario.epochs, scenario.epochs, observer.drops)
        taking_part = [i for n in agent_names if n not in gone for i in _ids_of(n)]
        taking_part = events.finishing(gone) if scenario.events else taking_part
        _wait(
            lambda: all_final(observer, taking_part),
            group,
            10.0,
            "the final states",
            lambda: missing_final(observer, taking_part),
            ignore=[*supervisor.losses, *supervisor.planned],
        )
        observer.netem_done()  # its last decisions are in the summary (no error: it has exited)
        if record:
            flush_recorder(session, run_id, observer)
            rec = next(c for c in group.children if c.name == "recorder")
            code = group.stop(rec, timeout_s=30.0)
            if code not in (0, None):
                raise RuntimeFailure(
                    f"recorder (pid {rec.pid}) exited with code {code}:\n{rec.tail()}"
                )
        with observer.lock:
            malformed: Counter[str] = Counter(observer.malformed.counts)
            sent: Counter[str] = Counter()
            delivered: Counter[str] = Counter()
            for st in observer.statuses.values():
                malformed.update(st.malformed)
                sent.update(st.sent)
                delivered.update(st.delivered)
            supervisor.note_returns(
                present(observer.positions), observer.returns, observer.team_events
            )
            losses = [loss.as_json() for loss in supervisor.losses]
            return RunOutcome(
                run_id=run_id,
                run_dir=run_dir,
                scenario=scenario,
                strategy=strategy,
                seed=seed,
                positions=observer.positions.copy(),
                estimated_epochs=sorted(observer.estimated),
                decisions=list(observer.decisions),
                substitutions=sorted(observer.substitutions),
                malformed=dict(malformed),
                sent=dict(sent),
                delivered=dict(delivered),
                pids=group.pids,
                wall_s=time.monotonic() - started,
                extra={
                    "deadline": deadline_counts(observer.statuses.values()),
                    "losses": losses,
                    "fallbacks": observer.fallbacks,
                    "fallback_epochs": dict(sorted(observer.fallback_epochs.items())),
                    "team_events": list(observer.team_events),
                    "priorities": priorities,
                    "cpu_steal": cpu_stolen,
                },
            )
    except RunEnded as exc:  # a plug-in failed: the recording is closed, whole, before the rest
        if record and session is not None and observer is not None:
            _close_recorder(session, run_id, observer, group)
        raise RunEnded(exc.reason, exc.epoch, str(run_dir)) from None
    finally:
        if observer is not None:
            observer.close()
        if session is not None:
            session.close()
        group.stop_all()


def _close_recorder(session: Any, run_id: str, observer: Observer, group: ProcessGroup) -> None:
    """Let the recorder take what was sent (the failing process's status among it), then end it
    as at a run's end, so its file is closed and readable without ``formation recover``."""
    with contextlib.suppress(RuntimeFailure):
        flush_recorder(session, run_id, observer)
    rec = next((c for c in group.children if c.name == "recorder"), None)
    if rec is not None:
        group.stop(rec, timeout_s=30.0)


def _write_atomic(path: Path, text: str) -> None:
    """Readers never see half a file: write beside it, then rename over it."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def _ids_of(name: str) -> list[int]:
    """The agent ids of a process's name: ``agent-3`` → [3], ``pool-1-25`` → 1..25."""
    parts = [int(p) for p in name.split(".")[0].split("-")[1:]]
    return list(range(parts[0], parts[-1] + 1))


def _wait(
    cond: Any,
    group: ProcessGroup,
    timeout_s: float,
    what: str,
    detail: Any = None,
    ignore: Any = (),
    check: Any = None,
) -> None:
    """Wait for ``cond``; a child failing meanwhile is an error unless among the ``ignore``d
    losses (or pids, or a callable giving them); ``check()`` is called first each time."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        if check is not None:
            check()
        gone = ignore() if callable(ignore) else ignore
        lost = {getattr(loss, "pid", loss) for loss in gone}  # losses, or planned pids
        failed = [c for c in group.failed() if c.pid not in lost]
        if failed:
            c = failed[0]
            raise RuntimeFailure(
                f"{c.name} (pid {c.pid}) exited with code {c.proc.returncode} while waiting "
                f"for {what}; its log is {c.log_path}:\n{c.tail()}"
            )
        if time.monotonic() > deadline:
            more = "" if detail is None else detail()
            group.dump_stacks()
            raise RuntimeFailure(
                f"timed out after {timeout_s:g} s waiting for {what}{more}; "
                f"each process's threads are at the end of its log in {group.log_dir}"
            )
        time.sleep(0.01)
