"""Rollouts on threads of this process (:class:`ThreadPool`): the default engine of
:func:`qchain.simulate_batch` where every rollout runs in compiled code.

The compiled engine releases Python's lock for each stretch of steps
(:data:`qchain._jit.ejit`), so rollouts on threads run in parallel: no process started, no
main-script guard, nothing pickled, each thread writing its results straight into the
batch's arrays. What a rollout does in Python (its set-up, a held controller's calls, the
Python between stretches) holds the lock, and that part does not scale: the rule for when
threads are the default is in ``docs/sweeps.md`` ("Engines").
"""

from __future__ import annotations

import os
import queue
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..checks import bounds
from ..checks.convert import describe_value

__all__ = ["ThreadPool", "resolve_workers"]

_LOOK = 0.1  #: s between the caller's looks at its signals while it waits for the threads


def _whole(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))


def resolve_workers(workers) -> int:
    """The number of workers (threads or processes) for ``workers``: None or -1 every core
    this process may use, else an int within :data:`qchain.checks.bounds.WORKERS`."""
    if workers is None or (_whole(workers) and workers == -1):
        try:
            return len(os.sched_getaffinity(0))
        except AttributeError:  # not Linux
            return os.cpu_count() or 1
    if not (_whole(workers) and bounds.WORKERS.contains(workers)):
        raise ValueError(f"workers must be None or -1 (every core), an int >= 1 and <= {bounds.WORKERS.high:g}, a "
                         f"qchain.batch.threads.ThreadPool or a qchain.batch.workers.LocalPool, got "
                         f"{describe_value(workers)}")
    return int(workers)


class ThreadPool:
    """``workers`` threads of this process (None or -1: one a core this process may use),
    started for each :meth:`map` and ended with it. Pass it as ``workers=`` to choose threads
    where the default would start processes (a rollout that calls Python at every step then
    runs correctly but does not scale)."""

    kind = "threads"

    def __init__(self, workers: int | None = None):
        self.workers = resolve_workers(workers)

    def __repr__(self) -> str:
        return f"ThreadPool(workers={self.workers})"

    def __enter__(self) -> ThreadPool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Nothing to stop: a pool's threads end with each :meth:`map`."""

    def warm(self, fn: Callable, payload, key=None) -> None:
        """Nothing to do: the threads share this process's engine, compiled or loaded by the caller."""

    def map(self, fn: Callable, shared, items: Sequence, *, retries: int = 0, stop: threading.Event | None = None
            ) -> Iterator[tuple[int, object]]:
        """Run ``fn(shared, [item])`` for each item on the threads; yield ``(index, result)``
        as items finish. ``shared`` is the object itself, shared by the threads (nothing is
        pickled). ``stop``: an event set when the caller stops early (an exception in an
        item, Ctrl-C, the iterator closed), for ``fn`` to stop at
        (:func:`qchain.sim.engine.driver.stop_on`); items not started then are not started,
        and this waits for those running to end before it returns or raises. A thread cannot
        die alone, so ``retries`` is not used."""
        stop = threading.Event() if stop is None else stop
        n = max(1, min(self.workers, len(items)))
        ex = ThreadPoolExecutor(max_workers=n, thread_name_prefix="qchain-rollout")
        futures = {}
        # each item's future as it finishes: O(1) Python a finished item (concurrent.futures.wait
        # looks at every pending future at each call, Python that holds the lock the threads need)
        finished_q: queue.SimpleQueue = queue.SimpleQueue()
        finished = False
        try:
            for i, item in enumerate(items):
                fut = ex.submit(_one, fn, shared, item, stop)
                futures[fut] = i
                fut.add_done_callback(finished_q.put)
            for _ in range(len(futures)):
                while True:
                    # a bounded wait: Ctrl-C may reach one of the pool's threads, whose signal this thread
                    # handles only when it next runs Python (an unbounded wait would hold it off to the end)
                    try:
                        fut = finished_q.get(timeout=_LOOK)
                        break
                    except queue.Empty:
                        continue
                err = fut.exception()
                if err is not None:
                    raise err
                yield futures[fut], fut.result()
            finished = True
        finally:
            if not finished:
                stop.set()
            ex.shutdown(wait=True, cancel_futures=True)


def _one(fn: Callable, shared, item, stop: threading.Event):
    """On a thread: ``fn(shared, [item])[0]``, the thread's runs stopping once ``stop`` is set."""
    from ..sim.engine.driver import stop_on

    if stop.is_set():  # (the pool's shutdown cancels the items not started; one may start meanwhile)
        raise _Stopped()
    with stop_on(stop):
        return fn(shared, [item])[0]


class _Stopped(Exception):
    """An item not run: the caller stopped (never raised to the caller: it has its own reason)."""
