"""Where batches and sweeps run: threads of this process (:class:`ThreadPool`, from
:mod:`qchain.batch.threads`: a batch's default where its rollouts run in compiled code),
worker processes on this machine (:class:`LocalPool`, the default otherwise) or a Dask
cluster (:class:`DaskEngine`).

:func:`qchain.simulate_batch` and :func:`qchain.sweep` hand their work here as *items* (the
arguments of one rollout or one sweep run), a module-level function ``fn(shared, items) ->
list`` returning one result an item, and ``shared``: what every item needs, pickled once and
kept by each worker. Items go out in guided chunks (:func:`plan_chunks`); results do not
depend on the chunking. Engines, lost workers (:class:`Lost`) and lost clusters
(:class:`ClusterLost`, ``qchain.lost-timeout``): ``docs/sweeps.md`` ("Engines")."""

from __future__ import annotations

import asyncio
import atexit
import contextlib
import math
import os
import pickle
import signal
import socket
import sys
import threading
import time
import uuid
from collections import OrderedDict, deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass

import numpy as np

from ..checks import bounds
from ..checks.convert import describe_value
from ..errors import ClusterLost
from .threads import ThreadPool, _whole, resolve_workers

__all__ = ["LocalPool", "ThreadPool", "DaskEngine", "ClusterLost", "Lost", "Payload", "plan_chunks", "resolve_workers",
           "check_engine",
           "engine_for", "default_pool", "dumps", "DEFAULT_RETRIES", "DEFAULT_LOST_TIMEOUT"]

#: times an item is sent again after the worker running it died
DEFAULT_RETRIES = 3
#: chunks sent ahead to each local worker: one running, one waiting in its queue, so a
#: worker never waits for the caller between chunks
_AHEAD = 2
#: guided chunking's divisor on Dask: a Dask task costs milliseconds of scheduler and worker
#: time, a local one a pipe round trip, so Dask's chunks are twice as large
#: (benchmarks/bench_batch.py)
_DASK_FACTOR = 2


# ------------------------------------------------------------------------------ payloads


def dumps(obj, what: str) -> bytes:
    """``obj`` pickled for a worker process (cloudpickle, where installed, for what pickle cannot
    take: lambdas, closures, ``__main__``'s functions); ``TypeError`` naming ``what`` otherwise."""
    try:
        return pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    except (pickle.PicklingError, AttributeError, TypeError) as err:
        try:
            import cloudpickle
        except ImportError:
            raise TypeError(f"{what} cannot be sent to a worker process ({err}); define it at module level, use a "
                            "qchain.sim.inputs schedule, install cloudpickle, or run with workers=1") from None
        try:
            return cloudpickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as err2:  # cloudpickle raises whatever the object's reduction raises
            raise TypeError(f"{what} cannot be sent to a worker process ({err2}); run with workers=1") from None


@dataclass(frozen=True)
class Payload:
    """``shared`` pickled once, with a token a worker keeps the unpickled object under, and
    the caller's module search path (a worker started earlier, or elsewhere, can then import
    what the caller's functions live in)."""

    token: str
    blob: bytes
    path: tuple = ()

    @classmethod
    def of(cls, shared, what: str = "the shared data") -> Payload:
        return cls(uuid.uuid4().hex, dumps(shared, what), tuple(p for p in sys.path if isinstance(p, str)))


_SHARED: OrderedDict[str, object] = OrderedDict()  # in a worker: token -> the unpickled shared data
_SHARED_KEEP = 4


def _shared(token: str, blob: bytes, path: tuple = ()):
    obj = _SHARED.get(token)
    if obj is None:
        for p in path:
            if p not in sys.path:
                sys.path.append(p)
        obj = pickle.loads(blob)
        _SHARED[token] = obj
        while len(_SHARED) > _SHARED_KEEP:
            _SHARED.popitem(last=False)
    else:
        _SHARED.move_to_end(token)
    return obj


def _run_chunk(fn: Callable, payload: Payload, items: list) -> list:
    """In a worker: ``fn(shared, items)``."""
    return fn(_shared(payload.token, payload.blob, payload.path), items)


def _run_chunk_packed(fn: Callable, payload: Payload, items: list) -> bytes:
    """In a Dask worker: ``fn(shared, items)`` pickled in band, one bytes object.

    Dask would serialize a list of results with its out-of-band protocol, a frame per
    array: for a chunk of trajectories that costs the worker several times the
    plain pickle (``benchmarks/bench_batch.py``'s Dask overhead), on the cores that run
    the items."""
    return pickle.dumps(_run_chunk(fn, payload, items), protocol=pickle.HIGHEST_PROTOCOL)


def _call_shared(fn: Callable, payload: Payload):
    """In a worker: ``fn(shared)`` (a warm-up)."""
    return fn(_shared(payload.token, payload.blob, payload.path))


@dataclass(frozen=True)
class Lost:
    """The result of an item that could not be computed: the worker processes running it
    died ``attempts`` times (``message`` says where)."""

    message: str
    attempts: int


# ------------------------------------------------------------------------------ chunks


def plan_chunks(n_items: int, n_workers: int, factor: int = 4, max_chunk: int = 64) -> list[range]:
    """Guided chunks of ``range(n_items)``: each ``ceil(remaining / (factor n_workers))``
    items (at most ``max_chunk``, at least 1), so chunks shrink towards the end."""
    chunks = []
    start = 0
    while start < n_items:
        size = max(1, min(max_chunk, math.ceil((n_items - start) / (factor * max(1, n_workers)))))
        chunks.append(range(start, min(n_items, start + size)))
        start += size
    return chunks


def check_engine(workers, client, retries) -> int:
    """Check a batch's or a sweep's ``workers``, ``client`` and ``retries`` where they enter
    (``TypeError``/``ValueError`` naming the argument, the value and the bound); returns
    ``retries`` as an int."""
    if not (workers is None or isinstance(workers, (ThreadPool, LocalPool, DaskEngine))):
        resolve_workers(workers)
    if client is not None and not (isinstance(client, (str, DaskEngine)) or hasattr(client, "submit")):
        raise TypeError(f"client must be None, a scheduler address 'tcp://HOST:PORT', a dask.distributed.Client or a "
                        f"qchain.batch.workers.DaskEngine, got {describe_value(client)}")
    if isinstance(client, str):
        _check_address(client)
    if not (_whole(retries) and bounds.RETRIES.contains(retries)):
        raise ValueError(f"retries must be an int >= 0 and <= {bounds.RETRIES.high:g}, got {describe_value(retries)}")
    return int(retries)


#: The schemes of a Dask scheduler address (distributed's comm protocols)
SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx", "inproc")


def _check_address(address: str) -> None:
    """A scheduler address ``[SCHEME://]HOST:PORT`` (``tcp`` when no scheme is given);
    ``ValueError`` naming ``client`` otherwise (distributed's own error names nothing)."""
    from urllib.parse import urlsplit

    shown = address if len(address) <= 80 else address[:77] + "..."
    why = None
    try:
        parts = urlsplit(address if "://" in address else f"tcp://{address}")
        port = parts.port
    except ValueError as exc:
        parts, port, why = None, None, str(exc)
    if why is None and parts.scheme not in SCHEDULER_SCHEMES:
        why = f"the scheme {parts.scheme!r} is none of {', '.join(SCHEDULER_SCHEMES)}"
    elif why is None and parts.scheme != "inproc" and (not parts.hostname or port is None):
        why = "it needs a host and a port"
    if why is not None or any(c.isspace() for c in address):
        raise ValueError(f"client must be a scheduler address 'tcp://HOST:PORT', got {shown!r} "
                         f"({why or 'it has spaces'})")


# ------------------------------------------------------------------------------ local pool


def _worker_init(parent: int) -> None:
    """A local worker: Ctrl-C is the caller's to handle (it stops the pool), and the worker
    exits when its caller is gone (a worker waiting for work would otherwise outlive a
    killed caller)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def watch():
        while True:
            if os.getppid() != parent:
                os._exit(1)
            time.sleep(0.5)

    threading.Thread(target=watch, name="qchain-parent-watch", daemon=True).start()


class _Slot:
    """One worker process: an executor of one process and the chunks sent to it, oldest first."""

    def __init__(self, ctx):
        self.executor = ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_worker_init,
                                            initargs=(os.getpid(),))
        self.pid_future = self.executor.submit(os.getpid)
        self.sent: list = []  # futures, in the order sent

    @property
    def pid(self) -> int | None:
        try:
            return self.pid_future.result(timeout=120)
        except Exception:
            return None

    def kill(self) -> None:
        try:
            pid = self.pid_future.result(timeout=0) if self.pid_future.done() else None
        except Exception:
            pid = None
        if pid is not None:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, signal.SIGKILL)
        self.executor.shutdown(wait=False, cancel_futures=True)


class LocalPool:
    """Worker processes on this machine (``spawn``), kept alive across calls; ``workers``: None
    or -1 one a core this process may use. A context manager, or :meth:`close` it;
    :func:`default_pool` keeps one for the session. Workers ignore Ctrl-C and exit when the
    process that started them is gone."""

    kind = "local"

    def __init__(self, workers: int | None = None):
        self.workers = resolve_workers(workers)
        import multiprocessing

        self._ctx = multiprocessing.get_context("spawn")
        self._slots: list[_Slot | None] = [None] * self.workers
        self.replaced = 0  #: worker processes replaced after they died

    def __enter__(self) -> LocalPool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"LocalPool(workers={self.workers})"

    def _slot(self, k: int) -> _Slot:
        s = self._slots[k]
        if s is None:
            s = self._slots[k] = _Slot(self._ctx)
        return s

    def start(self) -> LocalPool:
        """Start every worker process now (they import qchain meanwhile); returns self."""
        for k in range(self.workers):
            self._slot(k)
        return self

    def pids(self) -> list[int]:
        """Process ids of the workers (started if they were not)."""
        return [self._slot(k).pid for k in range(self.workers)]

    def warm(self, fn: Callable, payload: Payload, key=None) -> None:
        """Nothing to do: the caller has compiled or loaded the engine in this process, so
        the workers, on this machine, find it in numba's cache and only load it."""

    def map(self, fn: Callable, payload: Payload, items: Sequence, *, retries: int = DEFAULT_RETRIES
            ) -> Iterator[tuple[int, object]]:
        """Run ``fn(shared, chunk)`` over chunks of ``items``; yield ``(index, result)`` as
        chunks finish (a :class:`Lost` for an item given up). Closing the iterator early
        (an exception, Ctrl-C) kills the workers still busy."""
        queue = deque(list(c) for c in plan_chunks(len(items), self.workers))
        attempts = [0] * len(items)
        owner: dict = {}  # future -> (slot index, chunk)
        finished = False
        try:
            while queue or owner:
                for k in range(self.workers):
                    slot = self._slot(k)
                    while queue and len(slot.sent) < _AHEAD:
                        chunk = queue.popleft()
                        try:
                            fut = slot.executor.submit(_run_chunk, fn, payload, [items[i] for i in chunk])
                        except BrokenProcessPool:  # its process died while it had nothing to do
                            queue.appendleft(chunk)
                            if slot.sent:  # those fail too: _replace sends them again
                                break
                            slot.executor.shutdown(wait=False)
                            self._slots[k] = None
                            self.replaced += 1
                            slot = self._slot(k)
                            continue
                        slot.sent.append(fut)
                        owner[fut] = (k, chunk)
                done, _ = wait(list(owner), return_when=FIRST_COMPLETED)
                broken: set[int] = set()
                for fut in done:
                    k, chunk = owner[fut]
                    err = fut.exception()
                    if isinstance(err, BrokenProcessPool):
                        broken.add(k)
                        continue
                    del owner[fut]
                    self._slots[k].sent.remove(fut)
                    if err is not None:
                        raise err
                    yield from zip(chunk, fut.result())
                for k in sorted(broken):
                    yield from self._replace(k, owner, queue, attempts, items, retries)
            finished = True
        finally:
            if not finished:
                self._abort(owner)

    def _replace(self, k, owner, queue, attempts, items, retries):
        """Slot ``k``'s process died: charge its running chunk, send its chunks again (the
        running one as single items), start a new process in its place."""
        slot = self._slots[k]
        wait([slot.pid_future])
        if slot.pid_future.exception() is not None:  # it died before it could run anything
            self._abort(owner)
            raise RuntimeError("a worker process died while starting (spawn runs the main script again in every "
                               "worker: a script that starts workers must do so under "
                               "`if __name__ == '__main__':`)") from slot.pid_future.exception()
        pid = slot.pid_future.result()
        # every chunk the dead process had is failed; wait until the executor says so
        wait(slot.sent)
        done, again = [], []
        running = True  # the oldest chunk that failed was the one running
        for fut in slot.sent:
            _, chunk = owner.pop(fut)
            if fut.exception() is None:  # finished before the process died
                done.append((chunk, fut.result()))
            elif running:
                running = False
                for i in chunk:
                    attempts[i] += 1
                again.extend([i] for i in chunk)
            else:
                again.append(chunk)
        slot.executor.shutdown(wait=False, cancel_futures=True)
        self._slots[k] = None
        self.replaced += 1
        for chunk, results in done:
            yield from zip(chunk, results)
        for chunk in reversed(again):
            if len(chunk) == 1 and attempts[chunk[0]] > retries:
                i = chunk[0]
                yield i, Lost(f"its worker process died {attempts[i]} times (last pid {pid})", attempts[i])
            else:
                queue.appendleft(chunk)

    def _abort(self, owner) -> None:
        for k, s in enumerate(self._slots):
            if s is not None and any(not f.done() for f in s.sent):
                s.kill()
                self._slots[k] = None
            elif s is not None:
                s.sent.clear()
        owner.clear()

    def close(self) -> None:
        """Stop the worker processes."""
        for k, s in enumerate(self._slots):
            if s is not None:
                if any(not f.done() for f in s.sent):
                    s.kill()
                else:
                    s.executor.shutdown(wait=True)
                self._slots[k] = None


_DEFAULT: LocalPool | None = None


def default_pool(workers: int | None = None) -> LocalPool:
    """The session's pool of ``workers`` processes (made at first use, kept until exit; a
    call with another count replaces it)."""
    global _DEFAULT
    n = resolve_workers(workers)
    if _DEFAULT is None or _DEFAULT.workers != n:
        if _DEFAULT is not None:
            _DEFAULT.close()
        _DEFAULT = LocalPool(n)
    return _DEFAULT


@atexit.register
def _close_default() -> None:  # pragma: no cover - interpreter shutdown
    if _DEFAULT is not None:
        _DEFAULT.close()


# ------------------------------------------------------------------------------ dask


#: s without a worker or an answer before :class:`ClusterLost` (docs/sweeps.md, "Lost cluster")
DEFAULT_LOST_TIMEOUT = 300.0
_POLL = 0.25  #: s, the longest the Dask engine sleeps between looks at its tasks
_CHECK = 1.0  #: s between asking the scheduler for its workers while tasks are outstanding
_ASK = 10.0  #: s the scheduler has to answer that question
#: s the first fetch of a finished task's result may take before the engine looks at the
#: cluster again (the result died with its worker: the fetch waits for the scheduler to run the
#: task again); each further try of the same fetch waits twice as long, up to _FETCH_MAX
_FETCH = 2.0
_FETCH_MAX = 60.0
#: a failed fetch of a finished task's result to look at again: its worker died (the
#: scheduler runs the task again), the scheduler did not answer in time
_FETCH_FAILED = (OSError, TimeoutError, asyncio.CancelledError)
_KEEP = object()  # lost_timeout not given: the dask config's, else DEFAULT_LOST_TIMEOUT


def _lost_timeout(value) -> float | None:
    if value is _KEEP:
        import dask

        value = dask.config.get("qchain.lost-timeout", DEFAULT_LOST_TIMEOUT)
    if value is None:
        return None
    from dask.utils import parse_timedelta

    try:
        seconds = parse_timedelta(value, default="s")
    except (TypeError, ValueError, KeyError):
        seconds = None
    if seconds is None or isinstance(value, bool) or not math.isfinite(seconds) or seconds <= 0:
        raise ValueError(f"lost_timeout (dask config qchain.lost-timeout) must be a positive number of seconds or "
                         f"None (wait for ever), got {value!r}")
    return float(seconds)


class DaskEngine:
    """Items as tasks on a ``dask.distributed`` cluster: ``client`` a client or a scheduler
    address (connected here, closed by :meth:`close`); ``lost_timeout`` s without a worker or an
    answer before :class:`ClusterLost` (default the dask config ``qchain.lost-timeout``, else
    300 s; None waits for ever). Start workers with ``--nthreads 1``: an item's Python holds the GIL."""

    kind = "dask"

    def __init__(self, client, *, lost_timeout=_KEEP):
        try:
            import distributed
        except ImportError:  # pragma: no cover - the dask extra is missing
            raise ImportError("the Dask engine needs dask.distributed: pip install 'qchain[dask]'") from None
        self.lost_timeout = _lost_timeout(lost_timeout)
        self._own = isinstance(client, str)
        if self._own:
            address = client
            try:
                client = distributed.Client(address, set_as_default=False)
            except OSError as err:  # distributed's connect timeout, a refused connection
                raise ClusterLost(f"cannot reach the Dask scheduler at {address}: {err}") from None
            _quiet_gathers_given_up(client)
        elif not isinstance(client, distributed.Client):
            raise TypeError(f"client must be a dask.distributed.Client or a scheduler address, got {client!r}")
        self.client = client
        self._warmed: set = set()

    def __repr__(self) -> str:
        return f"DaskEngine({self._address()})"

    def __enter__(self) -> DaskEngine:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _address(self) -> str:
        try:
            return str(self.client.scheduler.address)
        except AttributeError:  # a closed client
            return "(closed client)"

    def _workers(self) -> dict:
        return self.client.scheduler_info(n_workers=-1)["workers"] if _takes_n_workers(self.client) \
            else self.client.scheduler_info()["workers"]

    @property
    def workers(self) -> int:
        """Threads over all workers (the items running at once)."""
        return max(1, sum(int(w.get("nthreads", 1)) for w in self._workers().values()))

    def _threads(self) -> dict | None:
        """{address: threads} of the scheduler's running workers; None when the client is
        not connected or the scheduler does not answer within ``_ASK`` seconds."""
        if self.client.status != "running":
            return None
        try:
            return dict(self.client.sync(self.client.scheduler.ncores_running, callback_timeout=_ASK))
        except (OSError, TimeoutError):  # CommClosedError, a refused connection, no answer in time
            return None

    def _lost(self, since: float, what: str) -> ClusterLost | None:
        """The error to raise when the cluster has been unusable (``what``) since ``since``."""
        if self.client.status in ("closing", "closed"):
            return ClusterLost(f"the Dask client of the scheduler at {self._address()} closed ({what})")
        waited = time.monotonic() - since
        if self.lost_timeout is not None and waited > self.lost_timeout:
            return ClusterLost(f"the Dask cluster at {self._address()}: {what} for {waited:.0f} s (lost_timeout = "
                               f"{self.lost_timeout:g} s, dask config qchain.lost-timeout)")
        return None

    def _wait_for_threads(self) -> dict:
        """The running workers' threads, waiting (bounded by ``lost_timeout``) for a first
        worker: a cluster still starting, jobs in a queue."""
        since = time.monotonic()
        said = False
        while True:
            threads = self._threads()
            if threads:
                return threads
            what = "no worker" if threads is not None else "the scheduler does not answer"
            err = self._lost(since, what)
            if err is not None:
                raise err
            if not said:
                wait = "" if self.lost_timeout is None else f" (up to {self.lost_timeout:g} s)"
                print(f"qchain: waiting for a worker to join the Dask cluster at {self._address()}{wait}",
                      file=sys.stderr, flush=True)
                said = True
            time.sleep(_POLL)

    def warm(self, fn: Callable, payload: Payload, key=None) -> None:
        """Run ``fn(shared)`` (a one-step run) on one worker of each machine other than
        this one, once per ``key``; a worker that dies meanwhile is skipped (the warm-up only
        saves time)."""
        if key is not None and key in self._warmed:
            return
        here = socket.gethostname()
        names = self.client.run(socket.gethostname, on_error="return")
        first: dict[str, str] = {}
        for addr, host in sorted(names.items()):
            if isinstance(host, str) and host != here:
                first.setdefault(host, addr)
        if first:
            self.client.run(_call_shared, fn, payload, workers=list(first.values()), on_error="return")
        if key is not None:
            self._warmed.add(key)

    def map(self, fn: Callable, payload: Payload, items: Sequence, *, retries: int = DEFAULT_RETRIES
            ) -> Iterator[tuple[int, object]]:
        """As :meth:`LocalPool.map`, on the cluster. Chunks of dead workers go again, as single
        items, after the scheduler's own retries (``KilledWorker``); tasks the scheduler forgot go
        again once the client reconnects; :class:`ClusterLost` after ``lost_timeout`` s without a
        worker or an answer; ``fn``'s own exception is raised here. Closing the iterator early
        releases the outstanding tasks."""
        from distributed import KilledWorker

        threads = list(self._wait_for_threads().values())
        if any(n > 1 for n in threads):
            import warnings

            warnings.warn(f"Dask workers with {max(threads)} threads run the Python of qchain items one at a time "
                          "each (the GIL: a sweep run's scene, metrics and files, a rollout's set-up): start one "
                          "worker process a core with --nthreads 1",
                          RuntimeWarning, stacklevel=3)
        attempts = [0] * len(items)
        pending: dict = {}  # future -> chunk (item indices), in the order sent
        lost: list = []  # chunks whose tasks the scheduler forgot, to send again when connected
        fetch_wait: dict = {}  # future -> seconds its next fetch may take
        wake = threading.Event()

        def woken(_fut) -> None:
            wake.set()

        def submit(chunk: list) -> None:
            fut = self.client.submit(_run_chunk_packed, fn, payload, [items[i] for i in chunk], pure=False,
                                     key=f"qchain-{payload.token[:8]}-{chunk[0]}-{uuid.uuid4().hex[:8]}")
            pending[fut] = chunk
            fut.add_done_callback(woken)

        def killed(chunk: list, err) -> Iterator[tuple[int, object]]:
            for i in chunk:
                attempts[i] += 1
                if attempts[i] > retries:
                    yield i, Lost(f"the Dask workers running it died ({err})", attempts[i])
                else:
                    submit([i])

        for c in plan_chunks(len(items), sum(threads), factor=_DASK_FACTOR):
            submit(list(c))
        lost_since = None  # when the engine first found the cluster without a worker or an answer
        checked = time.monotonic()
        try:
            while pending or lost:
                wake.wait(_POLL)
                wake.clear()
                for fut in list(pending):
                    status = fut.status  # "pending" and "lost" (its result died with a worker): the scheduler's
                    chunk = pending[fut]
                    if status == "finished":
                        wait_s = fetch_wait.get(fut, _FETCH)
                        try:
                            res = fut.result(timeout=wait_s)
                        except Exception as err:
                            if fut.status == "finished" and not isinstance(err, _FETCH_FAILED):
                                raise
                            if fut.status == "finished":  # a slow transfer, or no answer: next time wait longer
                                fetch_wait[fut] = min(2 * wait_s, _FETCH_MAX)
                            continue  # else its worker died before handing it over: the scheduler runs it again
                        fetch_wait.pop(fut, None)
                        del pending[fut]
                        fut.release()
                        yield from zip(chunk, pickle.loads(res))
                    elif status == "error":
                        err = fut.exception(timeout=_FETCH_MAX)
                        tb = fut.traceback(timeout=_FETCH_MAX)
                        del pending[fut]
                        fut.release()  # (releasing a future cancels its state: read it first)
                        if not isinstance(err, KilledWorker):
                            raise err.with_traceback(tb)
                        yield from killed(chunk, err)
                    elif status == "cancelled":  # the scheduler forgot it: this client lost its connection
                        del pending[fut]
                        lost.append(chunk)
                if lost and self.client.status == "running":
                    for chunk in lost:
                        submit(chunk)
                    lost.clear()
                now = time.monotonic()
                if now - checked >= _CHECK:
                    checked = now
                    threads_now = self._threads()
                    if threads_now:
                        lost_since = None
                    else:
                        lost_since = time.monotonic() if lost_since is None else lost_since
                        err = self._lost(lost_since, "no worker" if threads_now is not None else
                                         "the scheduler does not answer")
                        if err is not None:
                            n_open = sum(len(c) for c in pending.values()) + sum(len(c) for c in lost)
                            raise ClusterLost(f"{err}; {n_open} of {len(items)} items not computed") from None
        finally:
            for fut in pending:  # a message to the scheduler, never a wait: it cancels what no one wants
                fut.release()

    def close(self) -> None:
        """Close the client if this engine opened it."""
        if not self._own:
            return
        if self.client.status == "running":
            self.client.close()
            return
        # a client still trying to reach a lost scheduler logs the end of its attempts as an
        # error with two tracebacks: ClusterLost has said what happened
        import logging

        log = logging.getLogger("distributed.client")
        level = log.level
        log.setLevel(logging.CRITICAL)
        try:
            self.client.close()
        finally:
            log.setLevel(level)


def _quiet_gathers_given_up(client) -> None:
    """On the event loop of a client the engine opened: distributed ends the inner waits of a
    fetch the engine gave up on (its worker died meanwhile) with its own ``AllExit``, which
    asyncio would print as "Task exception was never retrieved" with a traceback when the
    client closes. Everything else goes to asyncio's handler as before."""
    def handler(loop, context):
        if type(context.get("exception")).__name__ != "AllExit":
            loop.default_exception_handler(context)

    with contextlib.suppress(AttributeError):  # a loop without one
        client.loop.asyncio_loop.set_exception_handler(handler)


def _takes_n_workers(client) -> bool:
    import inspect

    try:
        return "n_workers" in inspect.signature(client.scheduler_info).parameters
    except (TypeError, ValueError):
        return False


def engine_for(workers=None, client=None, tasks: int | None = None, threads: bool = False):
    """The engine for ``workers`` (an int, None for every core, a :class:`ThreadPool` or a
    :class:`LocalPool`) and ``client`` (a Dask client or address, or a :class:`DaskEngine`);
    None where the work runs in this process (``workers=1`` without a client). A count gives
    threads where ``threads`` (the work runs in compiled code, which releases Python's lock),
    else worker processes. ``tasks``: how many there are to run; no more workers start than
    that (``workers=1024`` for two runs starts two)."""
    if client is not None:
        if workers is not None:
            raise ValueError("give workers or client, not both: a Dask cluster has its own workers")
        return client if isinstance(client, DaskEngine) else DaskEngine(client)
    if isinstance(workers, (ThreadPool, LocalPool, DaskEngine)):
        return workers
    n = resolve_workers(workers)
    if tasks is not None:
        n = max(1, min(n, int(tasks)))
    if n == 1:
        return None
    return ThreadPool(n) if threads else default_pool(n)
