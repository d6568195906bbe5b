"""One executor for the coarse sweeps: local processes by default, a Dask cluster on request.

The benchmark (:mod:`forecast_design.benchmark`), ``bench-gap``
(:mod:`forecast_design.gap.bench`) and large Monte-Carlo sweeps hand their work to
:func:`make_executor` as a list of *tasks*: picklable arguments of a picklable
top-level function. A task is coarse (a batch of runs, not one sample) and
deterministic (it carries its own seeds), so the result of a task does not
depend on where or when it runs: the same list gives bit-for-bit the same
results serially, on local processes and on a cluster.

* ``LocalExecutor(workers=None)``: ``workers <= 1`` runs in this process;
  otherwise a :class:`concurrent.futures.ProcessPoolExecutor`. A worker process
  that dies (killed, out of memory) breaks the pool; the tasks not yet
  returned are resubmitted to a fresh pool (up to ``retries`` times), so no
  result is lost.
* ``DaskExecutor(address)``: a ``dask.distributed`` client on
  ``tcp://HOST:PORT``. Tasks are submitted with ``retries`` and ``pure=False``;
  the scheduler reschedules the tasks of a worker that dies. ``dask`` is
  imported only here, when an address is given, so command start-up stays
  fast.

Results come back in task order; ``progress(done, total)`` is called as tasks
finish.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from functools import partial
from typing import Any, Callable, Iterable, Sequence

from .errors import ForecastError, ParameterError

__all__ = ["Executor", "LocalExecutor", "DaskExecutor", "make_executor", "available_workers", "batched",
           "run_batch", "DEFAULT_RETRIES", "DASK_CONNECT_TIMEOUT_S", "DASK_WORKER_WAIT_S"]

#: Times a task is resubmitted after its worker died [-].
DEFAULT_RETRIES = 3

Progress = Callable[[int, int], None]


def available_workers() -> int:
    """Cores this process may run on [-]."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def batched(items: Sequence[Any], size: int) -> list[tuple[Any, ...]]:
    """Split ``items`` into consecutive tuples of at most ``size`` items (the last may be shorter).

    Parameters
    ----------
    items : sequence
        The items, in order.
    size : int
        Items per batch [-] (>= 1).

    Returns
    -------
    list of tuple
        The batches; concatenated they give ``items`` again.
    """
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise ParameterError(f"batch size must be an integer >= 1, got {size!r}", name="batch_size", value=size)
    items = list(items)
    return [tuple(items[i:i + size]) for i in range(0, len(items), size)]


def run_batch(func: Callable[[Any], Any], batch: Iterable[Any]) -> list[Any]:
    """``[func(x) for x in batch]``: the task of :meth:`Executor.map_batched` (picklable with its arguments).

    Parameters
    ----------
    func : callable
        A picklable top-level function of one argument.
    batch : iterable
        Its arguments.

    Returns
    -------
    list
        The results in order.
    """
    return [func(x) for x in batch]


class Executor:
    """Base class: ``map(func, tasks)`` in task order; subclasses decide where tasks run."""

    #: Short description for JSON and reports (``local:N`` or the scheduler address).
    name: str = "executor"
    workers: int = 1

    def map(self, func: Callable[[Any], Any], tasks: Sequence[Any], *, progress: Progress | None = None
            ) -> list[Any]:
        """Run ``func(task)`` for every task; results in task order.

        Parameters
        ----------
        func : callable
            A picklable top-level function of one argument.
        tasks : sequence
            Its arguments (picklable).
        progress : callable, optional
            ``progress(done, total)`` after each finished task.

        Returns
        -------
        list
            ``[func(t) for t in tasks]``.
        """
        raise NotImplementedError

    def map_batched(self, func: Callable[[Any], Any], items: Sequence[Any], *, batch_size: int,
                    progress: Progress | None = None) -> list[Any]:
        """``map`` over coarse tasks: ``items`` in batches of ``batch_size``, results flattened in order.

        Parameters
        ----------
        func : callable
            A picklable top-level function of one item.
        items : sequence
            The items.
        batch_size : int
            Items per task [-].
        progress : callable, optional
            ``progress(done_items, total_items)`` after each finished batch.

        Returns
        -------
        list
            ``[func(x) for x in items]``.
        """
        batches = batched(items, batch_size)
        total = len(items)

        def report(n_done: int, n_batches: int) -> None:
            if progress is not None:  # batches finish out of order: report the share of batches done
                progress(total if n_done == n_batches else min(total, n_done * batch_size), total)

        results = self.map(partial(run_batch, func), batches, progress=report)
        return [r for batch in results for r in batch]

    def close(self) -> None:
        """Release the workers or the connection."""

    def __enter__(self) -> "Executor":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def describe(self) -> dict[str, Any]:
        """``{"executor": name, "workers": n}`` for JSON provenance."""
        return {"executor": self.name, "workers": self.workers}


class LocalExecutor(Executor):
    """Tasks on this machine: in this process (``workers <= 1``) or on worker processes.

    Parameters
    ----------
    workers : int, optional
        Processes [-]; default :func:`available_workers`.
    retries : int
        Fresh pools started after a worker died [-].
    """

    def __init__(self, workers: int | None = None, *, retries: int = DEFAULT_RETRIES) -> None:
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise ParameterError(f"workers must be an integer >= 1, got {workers!r}", name="workers", value=workers)
        self.workers = available_workers() if workers is None else workers
        self.retries = int(retries)
        self.name = f"local:{self.workers}"
        self.restarts = 0

    def map(self, func, tasks, *, progress=None):
        tasks = list(tasks)
        total = len(tasks)
        report = progress or (lambda done, n: None)
        if self.workers <= 1 or total <= 1:
            out = []
            for task in tasks:
                out.append(func(task))
                report(len(out), total)
            return out
        results: dict[int, Any] = {}
        attempts = 0
        while len(results) < total:
            pending = [i for i in range(total) if i not in results]
            try:
                with ProcessPoolExecutor(max_workers=min(self.workers, len(pending))) as pool:
                    futures = {pool.submit(func, tasks[i]): i for i in pending}
                    while futures:
                        finished, _ = wait(futures, return_when=FIRST_COMPLETED)
                        for fut in finished:
                            i = futures.pop(fut)
                            results[i] = fut.result()
                            report(len(results), total)
            except BrokenProcessPool:
                attempts += 1
                self.restarts += 1
                if attempts > self.retries:
                    raise ParameterError(f"worker processes died {attempts} times; {total - len(results)} of "
                                         f"{total} tasks unfinished", name="workers", value=self.workers) from None
        return [results[i] for i in range(total)]


#: How long a Dask client waits to connect to the scheduler [s].
DASK_CONNECT_TIMEOUT_S = 10.0
#: How long the scheduler may have no worker (before the first task, or after every worker left
#: during a run) before the command fails in one line [s].
DASK_WORKER_WAIT_S = 30.0
_ADDRESS = re.compile(r"^(tcp|tls)://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+):([0-9]{1,5})$")


def _quiet_loggers() -> dict[str, int]:
    """Silence dask's own loggers (client reconnection tracebacks); return their levels to restore."""
    names = ["distributed", "tornado"] + [n for n in logging.root.manager.loggerDict
                                         if n.startswith(("distributed.", "tornado."))]
    levels = {}
    for name in names:
        logger = logging.getLogger(name)
        levels[name] = logger.level
        logger.setLevel(logging.CRITICAL + 1)
    return levels


def _restore_loggers(levels: dict[str, int]) -> None:
    for name, level in levels.items():
        logging.getLogger(name).setLevel(level)


def _cluster_error(address: str, what: str, exc: BaseException | None = None) -> ParameterError:
    why = "" if exc is None else f": {type(exc).__name__}" + (f" {' '.join(str(exc).split())}" if str(exc) else "")
    return ParameterError(f"the Dask cluster at {address} {what}{why}"[:400], name="scheduler", value=address)


def _probe_scheduler(address: str, timeout_s: float) -> None:
    """Connect to ``address`` and complete Dask's handshake within ``timeout_s`` [s], then hang up.

    ``distributed``'s connect bounds the TCP connection but not the handshake read after it: a
    port that accepts and never speaks would hang ``Client`` for ever. The probe runs its own
    event loop in a thread (the caller may be inside one, e.g. a notebook).

    Raises
    ------
    OSError
        Nothing answering, or not a Dask peer, within the time.
    """
    import asyncio
    from concurrent.futures import ThreadPoolExecutor

    from distributed.comm import connect

    async def probe() -> None:
        try:
            comm = await asyncio.wait_for(connect(address, timeout=timeout_s), timeout_s)
        except asyncio.TimeoutError:
            raise OSError(f"no Dask handshake within {timeout_s:g} s (something listens there, but not a "
                          "Dask scheduler)") from None
        await comm.close()

    with ThreadPoolExecutor(1) as pool:
        pool.submit(asyncio.run, probe()).result()


class DaskExecutor(Executor):
    """Tasks on a ``dask.distributed`` cluster (the scheduler at ``address``).

    Parameters
    ----------
    address : str
        Scheduler address, ``tcp://HOST:PORT`` (or ``tls://``), the port given.
    retries : int
        Resubmissions of a task whose worker died or that raised [-].
    timeout_s : float
        Time to wait for the scheduler to answer [s] (:data:`DASK_CONNECT_TIMEOUT_S`).
    worker_wait_s : float, optional
        Time to wait for a first worker, and for a worker again when all left during a run
        [s] (default :data:`DASK_WORKER_WAIT_S`).

    Raises
    ------
    ParameterError
        One line: a malformed address, no scheduler answering within ``timeout_s``, or no
        worker within ``worker_wait_s``.

    Notes
    -----
    The workers need the same ``forecast_design`` (and numpy/numba) as the client: tasks are
    pickled by reference to the package's functions. A scheduler that goes away during a run,
    or a task the cluster gave up on (its workers kept dying), ends the command in one line.
    """

    def __init__(self, address: str, *, retries: int = DEFAULT_RETRIES, timeout_s: float = DASK_CONNECT_TIMEOUT_S,
                 worker_wait_s: float | None = None) -> None:
        match = _ADDRESS.match(address) if isinstance(address, str) else None
        if match is None or not 1 <= int(match.group(3)) <= 65535:
            raise ParameterError(f"--scheduler must be an address like tcp://HOST:PORT (with the port), got "
                                 f"{address!r}", name="scheduler", value=address)
        try:
            from distributed import Client
        except ImportError:  # pragma: no cover - pinned dependency
            raise ParameterError("--scheduler needs dask.distributed (pip install distributed)", name="scheduler",
                                 value=address) from None
        self.address = address
        self.worker_wait_s = DASK_WORKER_WAIT_S if worker_wait_s is None else float(worker_wait_s)
        # the client logs its reconnection attempts with tracebacks: a lost scheduler is this
        # executor's one-line error instead (the level is restored by close)
        self._log_levels = _quiet_loggers()
        try:
            _probe_scheduler(address, timeout_s)
            self.client = Client(address, timeout=timeout_s, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            _restore_loggers(self._log_levels)
            raise ParameterError(f"cannot reach the Dask scheduler at {address}: {exc}", name="scheduler",
                                 value=address) from None
        try:
            self.client.wait_for_workers(1, timeout=self.worker_wait_s)
        except Exception:     # noqa: BLE001 - dask's TimeoutError, or the scheduler gone meanwhile
            self.close()
            raise _cluster_error(address, f"has no worker after {self.worker_wait_s:g} s; start workers with "
                                          f"'dask worker {address}'") from None
        self.retries = int(retries)
        self.name = address
        self.workers = len(self.client.scheduler_info().get("workers", {}))

    def _worker_count(self) -> int:
        return len(self.client.scheduler_info().get("workers", {}))

    def map(self, func, tasks, *, progress=None):
        from concurrent.futures import CancelledError

        from distributed import wait as dask_wait

        tasks = list(tasks)
        total = len(tasks)
        report = progress or (lambda done, n: None)
        if not tasks:
            return []
        stamp = f"{getattr(func, '__name__', 'task')}-{time.time_ns()}"
        results: dict[int, Any] = {}
        try:
            futures = [self.client.submit(func, t, pure=False, retries=self.retries, key=f"{stamp}-{i}")
                       for i, t in enumerate(tasks)]
            index = {f.key: i for i, f in enumerate(futures)}
            pending = list(futures)
            alone_since = None
            while pending:
                try:
                    with self.client.as_current():
                        done, not_done = dask_wait(pending, timeout=1.0, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    done, not_done = set(), pending
                for fut in done:
                    if fut.status == "error":
                        fut.result()              # the task's own exception, as it is
                    results[index[fut.key]] = fut.result()
                    report(len(results), total)
                pending = list(not_done)
                if pending and not done:
                    if self._worker_count() > 0:
                        alone_since = None
                    elif alone_since is None:
                        alone_since = time.monotonic()
                    elif time.monotonic() - alone_since > self.worker_wait_s:
                        raise _cluster_error(self.address, f"lost every worker and none came back within "
                                                           f"{self.worker_wait_s:g} s ({total - len(results)} of "
                                                           f"{total} tasks unfinished)")
        except ForecastError:
            raise
        except CancelledError as exc:       # the scheduler went away: its futures are cancelled
            raise _cluster_error(self.address, f"stopped during the run ({total - len(results)} of {total} tasks "
                                               "unfinished)", exc) from None
        except Exception as exc:  # noqa: BLE001 - connection errors, KilledWorker, ...: one line
            if type(exc).__module__.split(".")[0] in ("distributed", "dask", "tornado", "asyncio") \
                    or isinstance(exc, (OSError, TimeoutError)):
                raise _cluster_error(self.address, "failed during the run", exc) from None
            raise
        return [results[i] for i in range(total)]

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.client.close(timeout=2)
        _restore_loggers(self._log_levels)

    def describe(self) -> dict[str, Any]:
        return {"executor": "dask", "scheduler": self.address, "workers": self.workers}


def make_executor(scheduler: str | None = None, workers: int | None = None) -> Executor:
    """The executor of a command: a Dask cluster if ``scheduler`` is given, local processes otherwise.

    Parameters
    ----------
    scheduler : str, optional
        Dask scheduler address ``tcp://HOST:PORT`` (``--scheduler``).
    workers : int, optional
        Local worker processes (``--workers``; default all cores); ignored with a scheduler.

    Returns
    -------
    Executor
        Use as a context manager (closes pools and connections).
    """
    if scheduler:
        return DaskExecutor(scheduler)
    return LocalExecutor(workers)
