"""``formation run``: a router, the recorder, netem, the leader and the agents as real processes.

A :class:`LocalRun` waits for every process's liveliness before epoch 0 (netem declares the
start), follows the run over Zenoh (progress, drops, final states), ends every process by
PID on exit, error or Ctrl-C, and leaves ``runs/<run_id>/``; :func:`launch` is one run from
start to end.
"""

from __future__ import annotations

import contextlib
import json
import re
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import zenoh

from analysis import present
from formation import RuntimeFailure, deadline_counts
from formation.errors import RunEnded
from formation.scenario import Scenario, StrategyName
from shell import session_config
from testbed.runtime import steal
from testbed.runtime.events import EventDriver
from testbed.runtime.faults import (
    RestartPolicy,
    Supervisor,
    agent_ids,
    check_restart,
    first_missing_epoch,
)
from testbed.runtime.observer import Observer, all_final, flush_recorder, missing_final
from testbed.runtime.outcome import RunOutcome, Supervision
from testbed.runtime.priorities import favour_shared
from testbed.runtime.processes import ProcessGroup, free_port, wait_for_port

HOST = "127.0.0.1"
# How often the launcher looks at its processes while a run goes [s]: polling each one is most
# of what it does between epochs; a death is still noticed within this.
CHECK_S = 0.1


def _name_part(text: str) -> str:
    """``text`` as part of a folder's name and a Zenoh key: ``pkg.mod:name`` → ``pkg.mod.name``,
    any other character outside letters, digits, ``._+-`` → ``_``."""
    return re.sub(r"[^A-Za-z0-9._+-]", "_", text.replace(":", "."))


def make_run_id(scenario: Scenario, strategy: str, seed: int) -> str:
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S%f")
    return f"{_name_part(scenario.name)}-{_name_part(strategy)}-s{seed}-{stamp}"


def _pools(n: int, pool: int | None) -> list[list[int]]:
    if not pool:
        return [[i] for i in range(1, n + 1)]
    return [
        list(map(int, ids)) for ids in np.array_split(np.arange(1, n + 1), min(pool, n)) if len(ids)
    ]


def _process_name(ids: list[int]) -> str:
    """An agent process's name: one agent's, or a pool's (its first and last agent)."""
    return f"agent-{ids[0]}" if len(ids) == 1 else f"pool-{ids[0]}-{ids[-1]}"


Progress = Callable[[int, int, int], None]
"""Epochs done, epochs in all and packets dropped so far."""
OnStarted = Callable[[str, str], None]
"""The run's id and its router's endpoint."""


@dataclass(frozen=True)
class RunHooks:
    """What a caller hears while a run goes, each on the launcher's thread."""

    on_started: OnStarted | None = None  # every process is up, before epoch 0
    on_progress: Progress | None = None  # about every 20 ms while it runs, and at its end


class LocalRun:
    """``scenario`` run as real processes on this machine: a router, the recorder, netem, the
    leader and the agents, followed over Zenoh by the launcher's own session.

    :meth:`start` brings every process up (netem declares the start once each one's
    liveliness is in); :meth:`wait` follows the run to its end and returns what was
    observed; :meth:`stop` ends every child by PID. As a context manager it starts on entry
    and stops on exit; a failure in :meth:`start` or :meth:`wait` stops it before it is raised.

    An agent or the leader that dies is a loss, not the end (``restart="on-failure"``
    starts it again and it rejoins); netem, the router or the recorder dying is an error.
    Client mode, through the router, is the default: zenoh batches each process's traffic on
    its one link (bench/bench_runtime.py, bench/bench_realtime.py ``--zenoh-mode``).
    """

    def __init__(
        self,
        scenario: Scenario,
        strategy: StrategyName | None = None,
        seed: int | None = None,
        runs_dir: Path = Path("runs"),
        pool: int | None = None,
        record: bool = True,
        startup_timeout_s: float | None = None,
        epoch_timeout_s: float = 30.0,
        hooks: RunHooks = RunHooks(),
        run_id: str | None = None,
        zenoh_mode: str = "client",
        restart: RestartPolicy = "no",
        recorder_args: tuple[str, ...] = (),
    ) -> None:
        self.strategy = strategy or scenario.strategy.name
        self.seed = scenario.seed if seed is None else seed
        self.scenario = scenario.with_overrides(
            seed=self.seed, strategy={**scenario.strategy.model_dump(), "name": self.strategy}
        )
        self.run_id = run_id or make_run_id(self.scenario, self.strategy, self.seed)
        self.run_dir = runs_dir / self.run_id
        self.pool, self.record, self.hooks = pool, record, hooks
        if startup_timeout_s is None:  # large pools take a while to declare their subscribers
            startup_timeout_s = 60.0 + 0.2 * scenario.n
        self.startup_timeout_s = startup_timeout_s
        self.epoch_timeout_s, self.zenoh_mode = epoch_timeout_s, zenoh_mode
        self.restart, self.recorder_args = restart, recorder_args
        sc = self.scenario
        check_restart(restart, sc.body.robots(sc.n), sc.runtime.mode)
        self.scenario_path = self.run_dir / "scenario.toml"
        # Every process the run may start, and the launcher's own session: only they slow it down.
        self.members = [
            "launcher",
            "router",
            "recorder",
            "netem",
            "leader",
            *(_process_name(ids) for ids in _pools(self.scenario.n, pool)),
        ]
        self.members_file = self.run_dir / "members.json"
        self.group = ProcessGroup(self.run_dir / "logs", members_file=self.members_file)
        self.supervisor = Supervisor(self.group, restart, time.monotonic())
        self.events: EventDriver  # once the agents are started
        self.port, self.endpoint = 0, ""  # the router's, once it is started
        self._session: zenoh.Session | None = None
        self._observer: Observer | None = None
        self._started_at = 0.0
        self._priorities: str | None = None  # realtime: what was done, as a line
        self._cpu_before: steal.Ticks | None = None  # the CPU's counters at epoch 0
        self._agents: list[str] = []  # the agent processes' names at the start

    def __enter__(self) -> LocalRun:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def observer(self) -> Observer:
        if self._observer is None:
            raise RuntimeError(f"run {self.run_id} is not started: call start() first")
        return self._observer

    def start(self) -> None:
        """Every process up and netem's start declared; then ``hooks.on_started``."""
        with self._stopped_on_failure():
            self._prepare()
            self._start_services()
            self._start_agents()
            self.group.wait_for(
                lambda: self.observer.is_alive("clock", "start"),
                self.startup_timeout_s,
                "every process to come up",
                ignore=self.supervisor.replaced,
                check=self.supervisor.check_starting,
            )
            if self.hooks.on_started is not None:
                self.hooks.on_started(self.run_id, self.endpoint)
            self.events.began = time.monotonic()
            self.supervisor.begin(self.events.began)
            self._cpu_before = steal.ticks()
            names = self.supervisor.current
            self._agents = [n for n in names if n.startswith(("agent-", "pool-"))]

    def wait(self) -> RunOutcome:
        """Follow the run to its last epoch and its final states; every child ended."""
        with self._stopped_on_failure():
            self._follow()
            cpu_stolen = steal.share(self._cpu_before, steal.ticks())
            self._finish()
            outcome = self._outcome(cpu_stolen)
        self.stop()
        return outcome

    def stop(self) -> None:
        """End every child by PID (newest first) and close the launcher's session; again: no-op."""
        if self._observer is not None:
            self._observer.close()
            self._observer = None
        if self._session is not None:
            self._session.close()
            self._session = None
        self.group.stop_all()

    @contextlib.contextmanager
    def _stopped_on_failure(self) -> Iterator[None]:
        try:
            yield
        except RunEnded as exc:  # a plug-in failed: the recording is closed, whole, before the rest
            if self.record and self._session is not None and self._observer is not None:
                self._close_recorder(self._session, self._observer)
            self.stop()
            raise RunEnded(exc.reason, exc.epoch, str(self.run_dir)) from None
        except BaseException:
            self.stop()
            raise

    def _args(self, *args: str) -> list[str]:
        """A service's command line: ``args`` and what every service of the run is given."""
        common = ["--run-id", self.run_id, "--mode", self.zenoh_mode, "--connect", self.endpoint]
        if self.zenoh_mode == "peer":
            common += ["--listen", f"tcp/{HOST}:0"]  # peers meet directly, on loopback only
        return [*args, *common]

    def _prepare(self) -> None:
        """The run's folder: its resolved scenario and the team of processes it may start."""
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.scenario_path.write_text(self.scenario.to_toml())
        _write_atomic(self.members_file, json.dumps(self.members))
        self.port = free_port(HOST)
        self.endpoint = f"tcp/{HOST}:{self.port}"
        self._started_at = time.monotonic()

    def _write_pids(self) -> None:
        pids = {"endpoint": self.endpoint, "pids": self.group.pid_map()}
        _write_atomic(self.run_dir / "pids.json", json.dumps(pids))

    def _start(self, name: str, module: str, *args: str) -> None:
        self.supervisor.track(self.group.start(name, module, *args), module, *args)

    def _start_services(self) -> None:
        """The router, the launcher's session on it, then the recorder, netem and the leader."""
        self._start("router", "testbed.runtime.router", "--listen", self.endpoint)
        self.group.on_start = self._write_pids
        wait_for_port(HOST, self.port, 10.0)
        self._session = zenoh.open(
            session_config("client", self.endpoint, None, member="launcher", members=self.members)
        )
        self._observer = Observer(self._session, self.run_id, self.scenario)
        scenario = ["--scenario", str(self.scenario_path)]
        if self.record:
            out = ["--out", str(self.run_dir), *scenario, *self.recorder_args]
            self._start("recorder", "recorder", *self._args(), *out)
            self.group.wait_for(
                lambda: self.observer.is_alive("recorder", 0),
                self.startup_timeout_s,
                "the recorder to come up",
            )
        no_recorder = [] if self.record else ["--no-recorder"]
        self._start("netem", "netem", *self._args(*scenario), *no_recorder)
        self._start("leader", "leader", *self._args(*scenario))
        if self.scenario.runtime.mode == "realtime":
            self._priorities = favour_shared(self.group.pid_map())

    def _start_agents(self) -> None:
        """One process per agent or per pool, but those that join later (a scenario event)."""
        scenario = ["--scenario", str(self.scenario_path)]
        EventDriver.check(self.scenario, self.pool)
        self.events = EventDriver(
            self.scenario, self.supervisor, lambda i: self._args(*scenario, "--id", str(i))
        )
        for ids in _pools(self.scenario.n, self.pool):
            ident = str(ids[0]) if len(ids) == 1 else f"{ids[0]}-{ids[-1]}"
            if len(ids) == 1 and self.events.starts_later(ids[0]):
                continue
            self._start(_process_name(ids), "agent", *self._args(*scenario, "--id", ident))

    def _first_missing(self, name: str) -> int:
        """The first epoch process ``name`` has not done: an estimate, an agent's state, or
        for netem the first no agent got to (its packets carry every epoch's states)."""
        observer = self.observer
        with observer.lock:
            if name == "leader":
                return len(observer.estimated)
            seen = np.isfinite(observer.positions[:, :, 0])  # (E + 1, n)
            if name == "netem":
                return first_missing_epoch(np.asarray(seen.any(axis=1)))
            return min(first_missing_epoch(seen[:, i - 1]) for i in agent_ids(name))

    def _has_state(self, agent: int, epoch: int) -> bool:
        return bool(np.isfinite(self.observer.positions[epoch, agent - 1, 0]))

    def _progress(self, count: int, drops: int) -> None:
        if self.hooks.on_progress is not None:
            self.hooks.on_progress(count, self.scenario.epochs, drops)

    def _follow(self) -> None:
        """Until every essential process is done: losses and restarts handled, the scenario's
        events played, a run with no epoch finished for ``epoch_timeout_s`` an error."""
        observer, supervisor = self.observer, self.supervisor
        last_progress, last_count = time.monotonic(), -1
        next_check = 0.0
        while True:
            if time.monotonic() >= next_check:  # the processes, less often than the progress
                if not supervisor.running():
                    break
                supervisor.check(self._first_missing)
                supervisor.check_team(self._agents)
                next_check = time.monotonic() + CHECK_S
            with observer.lock:
                count, drops = len(observer.estimated), observer.drops
            self._progress(count, drops)
            if count != last_count:
                last_progress, last_count = time.monotonic(), count
            elif time.monotonic() - last_progress > self.epoch_timeout_s:
                self.group.dump_stacks()
                raise RuntimeFailure(
                    f"no epoch finished for {self.epoch_timeout_s:g} s (stuck at epoch {count}); "
                    f"each process's threads are at the end of its log in {self.group.log_dir}"
                )
            with observer.lock:
                self.events.step(count, self._has_state)
            time.sleep(0.02)
        supervisor.check(self._first_missing)
        supervisor.check_team(self._agents)

    def _finish(self) -> None:
        """The final states of the agents still taking part, netem's last decisions, and the
        recording closed."""
        observer, supervisor = self.observer, self.supervisor
        gone = supervisor.gone_for_good()
        self._progress(self.scenario.epochs, observer.drops)
        taking_part = [i for n in self._agents if n not in gone for i in agent_ids(n)]
        taking_part = self.events.finishing(gone) if self.scenario.events else taking_part
        self.group.wait_for(
            lambda: all_final(observer, taking_part),
            10.0,
            "the final states",
            lambda: missing_final(observer, taking_part),
            ignore=[*supervisor.losses, *supervisor.planned],
        )
        observer.netem_done()  # its last decisions are in the summary (no error: it has exited)
        if self.record and self._session is not None:
            senders = ["/".join(n.split("-")[:2]) for n in self._agents if n not in gone]
            self._await_statuses(senders)  # agent-4: agent/4; pool-1-125: pool/1
            flush_recorder(self._session, self.run_id, observer)
            rec = next(c for c in self.group.children if c.name == "recorder")
            code = self.group.stop(rec, timeout_s=30.0)
            if code not in (0, None):
                raise RuntimeFailure(
                    f"recorder (pid {rec.pid}) exited with code {code}:\n{rec.tail()}"
                )

    def _await_statuses(self, senders: list[str], timeout_s: float = 5.0) -> None:
        """Until the observer has each agent process's last status (sent after its final state):
        the recorder is flushed up to the statuses the observer has seen, so one still on its
        way would miss the recording."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with self.observer.lock:
                if all(s in self.observer.statuses for s in senders):
                    return
            time.sleep(0.02)

    def _outcome(self, cpu_stolen: float | None) -> RunOutcome:
        observer = self.observer
        with observer.lock:
            malformed: Counter[str] = Counter(observer.malformed.counts)
            sent: Counter[str] = Counter()
            delivered: Counter[str] = Counter()
            finals = [*observer.parts, *observer.statuses.values()]
            for st in finals:
                malformed.update(st.malformed)
                sent.update(st.sent)
                delivered.update(st.delivered)
            self.supervisor.note_returns(
                present(observer.positions), observer.returns, observer.team_events
            )
            return RunOutcome(
                run_id=self.run_id,
                run_dir=self.run_dir,
                scenario=self.scenario,
                strategy=self.strategy,
                seed=self.seed,
                positions=observer.positions.copy(),
                estimated_epochs=sorted(observer.estimated),
                decisions=list(observer.decisions),
                substitutions=sorted(observer.substitutions),
                malformed=dict(malformed),
                sent=dict(sent),
                delivered=dict(delivered),
                pids=self.group.pids,
                wall_s=time.monotonic() - self._started_at,
                supervision=Supervision(
                    deadline=deadline_counts(finals),
                    losses=[loss.as_json() for loss in self.supervisor.losses],
                    fallbacks=observer.fallbacks,
                    fallback_epochs=dict(sorted(observer.fallback_epochs.items())),
                    team_events=list(observer.team_events),
                    priorities=self._priorities,
                    cpu_steal=cpu_stolen,
                ),
            )

    def _close_recorder(self, session: zenoh.Session, observer: Observer) -> None:
        """Let the recorder take what was sent (the failing process's status among it), then
        end it as at a run's end, so its file is closed and readable without ``formation
        recover``."""
        with contextlib.suppress(RuntimeFailure):
            flush_recorder(session, self.run_id, observer)
        rec = next((c for c in self.group.children if c.name == "recorder"), None)
        if rec is not None:
            self.group.stop(rec, timeout_s=30.0)


def launch(
    scenario: Scenario,
    strategy: StrategyName | None = None,
    seed: int | None = None,
    runs_dir: Path = Path("runs"),
    pool: int | None = None,
    record: bool = True,
    startup_timeout_s: float | None = None,
    epoch_timeout_s: float = 30.0,
    progress: Progress | None = None,
    run_id: str | None = None,
    on_started: OnStarted | None = None,
    zenoh_mode: str = "client",
    restart: RestartPolicy = "no",
    recorder_args: tuple[str, ...] = (),
) -> RunOutcome:
    """Run ``scenario`` as real processes (a :class:`LocalRun` from start to end) and return
    what was observed; every child ends by PID."""
    hooks = RunHooks(on_started=on_started, on_progress=progress)
    run = LocalRun(
        scenario,
        strategy,
        seed,
        runs_dir,
        pool,
        record,
        startup_timeout_s,
        epoch_timeout_s,
        hooks,
        run_id,
        zenoh_mode,
        restart,
        recorder_args,
    )
    with run:
        return run.wait()


def _write_atomic(path: Path, text: str) -> None:
    """Readers never see half a file: write beside it, then rename over it."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)
