"""Where a sweep's chunks run: the local process pool, or a Dask distributed cluster.

Both are an :class:`Executor`: ``map_unordered(fn, items)`` yields ``fn(item)`` for every item as
each finishes, in any order, so the sweep appends results to its CSV as they come; and
``task_overhead_s``, what one task costs beyond its work, from which :func:`seeds_per_task`
sizes the chunks. ``--scheduler`` picks one (:func:`executor_for`):

* none: :class:`LocalPool`, a ``multiprocessing`` pool on this machine (needs no Dask);
* ``tcp://HOST:PORT`` (or ``tls://``): :class:`DaskCluster` on a running Dask scheduler, whose
  workers must have this package installed (they import ``testbed`` to run a chunk);
* ``local:N``: :class:`DaskCluster` on a ``distributed.LocalCluster`` of N single-threaded worker
  processes on 127.0.0.1, started for the sweep and closed after it.

Dask (``pip install 'formation-testbed[dask]'``) is imported only when ``--scheduler`` is
given: it is an optional extra, and importing ``distributed`` costs about 0.5 s that every other
``formation`` command would pay.
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import os
import pickle
import re
import signal
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from types import ModuleType
from typing import Any, Protocol, TypeVar

from formation.errors import ExecutorError

T = TypeVar("T")
R = TypeVar("R")

# Per task, beyond its work (bench/bench_sweep.py --overhead: a grid20 chunk in, 84 rows out,
# 2 workers, this 2-core machine at load 5-12): Dask 6.5-16 ms (local:2 6.5, a scheduler 9.8),
# the pool 1.5-2.1 ms. Sized on about twice the worst, as loads vary.
DASK_TASK_OVERHEAD_S = 0.02
POOL_TASK_OVERHEAD_S = 0.002
OVERHEAD_SHARE = 0.05  # a task's overhead stays under 5 % of the task
# The cheapest cell per epoch, batched: paper.toml (5 agents, 14 links), ~2 ms for 200 epochs
# unloaded. Every other topology costs more, so chunks sized on it are long enough for all.
CHEAPEST_CELL_EPOCH_S = 1e-5
SCHEDULER_TIMEOUT_S = 30.0  # how long a scheduler address may take to answer
SCHEDULER_FORMS = "tcp://HOST:PORT, tls://HOST:PORT or local:N"


class Executor(Protocol):
    """Runs ``fn`` over ``items`` somewhere and yields each result as it finishes."""

    @property
    def task_overhead_s(self) -> float: ...

    def map_unordered(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[R]: ...


def seeds_per_task(
    requested: int,
    cells_per_seed: int,
    epochs: int,
    overhead_s: float,
    share: float = OVERHEAD_SHARE,
) -> int:
    """Seeds per chunk: at least ``requested``, and enough that ``overhead_s`` is under ``share``.

    A chunk of ``s`` seeds runs ``s · cells_per_seed`` cells of ``epochs`` epochs, each at least
    ``CHEAPEST_CELL_EPOCH_S · epochs`` seconds, so its overhead share is at most
    ``overhead_s / (s · cells_per_seed · epochs · CHEAPEST_CELL_EPOCH_S)``.
    """
    cell_s = CHEAPEST_CELL_EPOCH_S * max(1, epochs)
    need = math.ceil(overhead_s / share / (cell_s * max(1, cells_per_seed)) - 1e-9)
    return max(1, requested, need)


@dataclass(frozen=True)
class LocalPool:
    """A ``multiprocessing`` pool of ``jobs`` processes (default: every core; 1: this process)."""

    jobs: int | None = None

    @property
    def task_overhead_s(self) -> float:
        return POOL_TASK_OVERHEAD_S if self.workers > 1 else 0.0

    @property
    def workers(self) -> int:
        return self.jobs or os.cpu_count() or 1

    def map_unordered(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[R]:
        if self.workers <= 1 or len(items) == 1:
            for item in items:
                yield fn(item)
            return
        pool = multiprocessing.get_context().Pool(
            min(self.workers, len(items)), initializer=_ignore_sigint
        )
        try:
            yield from pool.imap_unordered(fn, items)
        except BaseException:
            # Ctrl-C or a failed task: end the workers now rather than after the queued tasks;
            # what finished is already with the caller, and a re-run resumes from there.
            pool.terminate()
            raise
        else:
            pool.close()
        finally:
            pool.join()


def _ignore_sigint() -> None:
    """Workers leave Ctrl-C to the parent, which ends them (a worker would skip one task only)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@dataclass(frozen=True)
class DaskCluster:
    """A Dask scheduler at ``address`` (``tcp://HOST:PORT``), or ``local:N`` started here."""

    address: str

    def __post_init__(self) -> None:
        parse_scheduler(self.address)

    @property
    def task_overhead_s(self) -> float:
        return DASK_TASK_OVERHEAD_S

    def map_unordered(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[R]:
        dask, distributed = _import_dask(self.address)
        local = parse_scheduler(self.address)
        with ExitStack() as stack:
            target: Any = self.address
            if local is not None:
                # Forked workers start with this process's imports, as the local pool's do:
                # spawned ones took 5 s of CPU and up to 10 s here to import testbed again.
                stack.enter_context(
                    dask.config.set({"distributed.worker.multiprocessing-method": "fork"})
                )
                target = stack.enter_context(
                    distributed.LocalCluster(
                        n_workers=local,
                        threads_per_worker=1,
                        processes=True,
                        host="127.0.0.1",
                        dashboard_address="127.0.0.1:0",  # None still takes :8787
                        # a task's failure comes back through its future; what the workers
                        # log is noise here (a heartbeat racing the close logs a traceback)
                        silence_logs=logging.CRITICAL,
                    )
                )
            try:
                client = stack.enter_context(
                    distributed.Client(target, timeout=SCHEDULER_TIMEOUT_S, set_as_default=False)
                )
            except OSError as exc:
                raise ExecutorError(
                    "--scheduler",
                    self.address,
                    f"no Dask scheduler answered within {SCHEDULER_TIMEOUT_S:g} s ({exc})",
                ) from None
            # Pickled both ways: Dask walks a task's arguments and results looking for futures,
            # which for a chunk and its rows costs about as much again as the bytes (measured).
            # Priorities keep the caller's order (heaviest first); the keys alone are random.
            # Dask's pickle falls back to cloudpickle, so fn may live in __main__ or be a lambda.
            dumps = distributed.protocol.pickle.dumps
            futures = [
                client.submit(run_pickled, dumps((fn, item)), pure=False, priority=len(items) - i)
                for i, item in enumerate(items)
            ]
            try:
                for future in distributed.as_completed(futures, loop=client.loop):
                    try:
                        payload = future.result()
                    except distributed.KilledWorker as exc:
                        raise ExecutorError(
                            "--scheduler",
                            self.address,
                            f"the workers running a task died too often ({exc}); "
                            "finished tasks are kept, a re-run resumes",
                        ) from None
                    yield pickle.loads(payload)
            finally:
                client.cancel(futures)


def run_pickled(payload: bytes) -> bytes:
    """On a worker: ``fn(item)`` from ``pickle((fn, item))``, the result pickled."""
    fn, item = pickle.loads(payload)
    return pickle.dumps(fn(item), protocol=pickle.HIGHEST_PROTOCOL)


def parse_scheduler(text: str) -> int | None:
    """``local:N`` → N workers; a scheduler address → None; anything else is an error."""
    if text.startswith("local:"):
        count = text.removeprefix("local:")
        if not count.isdigit() or int(count) < 1:
            raise ExecutorError(
                "--scheduler",
                repr(text),
                f"local:N needs N ≥ 1 workers; expected {SCHEDULER_FORMS}",
            )
        return int(count)
    if not re.fullmatch(r"(tcp|tls)://[^\s/:]+:\d{1,5}", text):
        raise ExecutorError("--scheduler", repr(text), f"expected {SCHEDULER_FORMS}")
    return None


def _import_dask(address: str) -> tuple[ModuleType, ModuleType]:
    """``dask`` and ``distributed``, or an error saying how to install them."""
    try:
        # here, not at the top: an optional extra, and 0.5 s to import
        import dask.config
        import distributed
    except ImportError as exc:
        raise ExecutorError(
            "--scheduler", address, f"needs Dask (pip install 'formation-testbed[dask]'): {exc}"
        ) from None
    return dask, distributed


def executor_for(scheduler: str | None, jobs: int | None = None) -> Executor:
    """The executor ``--scheduler``/``--jobs`` ask for; ``--jobs`` belongs to the local pool."""
    if scheduler is None:
        return LocalPool(jobs)
    if jobs is not None:
        raise ExecutorError(
            "--jobs",
            f"{jobs} with --scheduler {scheduler}",
            "--jobs sizes the local pool; a Dask cluster runs as many tasks as it has worker threads",
        )
    return DaskCluster(scheduler)


__all__ = [
    "DASK_TASK_OVERHEAD_S",
    "SCHEDULER_FORMS",
    "DaskCluster",
    "Executor",
    "LocalPool",
    "executor_for",
    "parse_scheduler",
    "run_pickled",
    "seeds_per_task",
]
