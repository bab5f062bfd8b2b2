"""Executors that run many independent jobs (a log to convert, a slice of samples to score) on this machine's
processes or on a Ray cluster, and worker processes that do not outlive the process that started them.

We do not schedule work ourselves: :class:`ProcessExecutor` is ``concurrent.futures.ProcessPoolExecutor`` and
:class:`RayExecutor` is Ray's tasks (``ray.remote``, ``ray.wait``). Both yield ``(index, result)`` as jobs finish, in
any order: callers that need an order (``convert`` assembles shards in log order) restore it from the index.

Worker processes start from a forkserver that has imported the caller's ``__main__`` (:mod:`lead_s2r.forkserver_main`)
and the modules the jobs need once: a spawned worker imports them again each (a script that imports torch paid 2-4 s
per worker before its first job). A driver killed by SIGKILL (the OOM killer, a scheduler's time limit) runs no
clean-up: its workers would keep writing into a folder nobody finishes (and a forkserver lives as long as its
children). Each worker therefore watches its driver's sentinel from a daemon thread (:func:`exit_with_parent`):
portable, where Linux's ``PR_SET_PDEATHSIG`` is not.
"""

import contextlib
import json
import multiprocessing as mp
import os
import pickle
import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from lead_s2r.errors import UserError

#: The environment variable that tells a starting forkserver how the caller's ``__main__`` was started.
FORKSERVER_MAIN = "LEAD_S2R_FORKSERVER_MAIN"

#: How often Ray runs a job again whose worker or node died before it returned (Ray's ``max_retries``).
RAY_RETRIES = 3

Job = Callable[..., Any]


class WorkerDied(RuntimeError):
    """A worker ended without returning its job's result (killed, out of memory, a crash in native code)."""


def exit_with_parent() -> None:
    """End this worker process as soon as the process that started it ends; call it first thing in a worker.

    The parent is the one multiprocessing records (``parent_process()``: the driver, also for a forkserver's
    children), watched through its sentinel pipe, which the kernel closes when the driver dies, zombie or not. The
    exit is immediate (``os._exit``): whatever the worker was writing is left partial, for the resuming run to drop."""
    parent = mp.parent_process()
    if parent is None:
        raise RuntimeError("exit_with_parent() is for a worker process multiprocessing started: it has no parent here")

    def watch() -> None:
        parent.join()
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


class Executor(ABC):
    """Runs ``job(*args)`` for every ``args`` of a list, yielding ``(index, result)`` as each finishes."""

    @abstractmethod
    def run(self, job: Job, arguments: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
        """Every job's result with its index in ``arguments``; an exception a job raises is raised here. Closing
        the iterator early (or an exception in the caller's loop) cancels the jobs not yet started."""

    def session(self) -> contextlib.AbstractContextManager[None]:
        """A context in which several :meth:`run` calls share what each would set up alone (a Ray connection)."""
        return contextlib.nullcontext()

    def map(self, function: Job, items: Sequence[tuple[Any, ...]], per_job: int) -> list[Any]:
        """``[function(*item) for item in items]``, in order, computed in jobs of ``per_job`` consecutive items (one
        job per item would cost more in messages than many a function call)."""
        chunks = [(function, items[start : start + per_job]) for start in range(0, len(items), per_job)]
        results: list[list[Any]] = [[] for _ in chunks]
        for index, chunk_results in self.run(_apply_to_chunk, chunks):
            results[index] = chunk_results
        return [result for chunk_results in results for result in chunk_results]


def _apply_to_chunk(function: Job, items: Sequence[tuple[Any, ...]]) -> list[Any]:
    return [function(*item) for item in items]


def make_executor(
    workers: int,
    executor: str = "processes",
    address: str | None = None,
    preload: Sequence[str] = (),
    initializer: Callable[[], None] | None = None,
) -> Executor:
    """The executor the CLI's ``--workers``, ``--executor`` and ``--address`` name (checked before any work)."""
    if executor == "ray":
        return RayExecutor(address, initializer=initializer)
    if address is not None:
        raise UserError("--address names a Ray cluster: add --executor ray")
    if workers <= 1:
        return InlineExecutor()
    return ProcessExecutor(workers, preload=preload, initializer=initializer)


class InlineExecutor(Executor):
    """Every job in this process, in list order: no start-up, the reference the others must match."""

    def run(self, job: Job, arguments: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
        for index, args in enumerate(arguments):
            yield index, job(*args)


def _start_worker(initializer: Callable[[], None] | None) -> None:
    exit_with_parent()
    if initializer is not None:
        initializer()


class ProcessExecutor(Executor):
    """``workers`` processes of this machine from ``concurrent.futures.ProcessPoolExecutor``, forked from a
    forkserver that preloaded ``__main__`` and ``preload`` (module names). ``initializer`` runs once per worker."""

    def __init__(
        self, workers: int, preload: Sequence[str] = (), initializer: Callable[[], None] | None = None
    ) -> None:
        if workers < 1:
            raise UserError(f"--workers {workers}: give at least 1")
        self.workers, self.preload, self.initializer = workers, list(preload), initializer

    def run(self, job: Job, arguments: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
        _start_forkserver(self.preload)
        pool = ProcessPoolExecutor(
            min(self.workers, max(len(arguments), 1)),
            mp_context=mp.get_context("forkserver"),
            initializer=_start_worker,
            initargs=(self.initializer,),
        )
        try:
            futures: dict[Future[Any], int] = {pool.submit(job, *args): i for i, args in enumerate(arguments)}
            pending = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in sorted(done, key=futures.__getitem__):
                    try:
                        result = future.result()
                    except BrokenProcessPool as err:
                        raise WorkerDied("a worker process died") from err
                    yield futures[future], result
        except BaseException:  # closed early, or failed: jobs handed to a worker cannot be cancelled, only stopped
            _terminate_workers(pool)
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _start_forkserver(preload: Sequence[str]) -> None:
    """Start this process's forkserver with the caller's main module and ``preload`` imported (see
    :mod:`lead_s2r.forkserver_main`). A forkserver already running keeps what it imported: still correct, if slower."""
    from multiprocessing import forkserver, spawn

    started = spawn.get_preparation_data("forkserver")
    main = {name: value for name, value in started.items() if name.startswith("init_main_from")}
    forkserver.set_forkserver_preload(["lead_s2r.forkserver_main", *preload])
    os.environ[FORKSERVER_MAIN] = json.dumps(main)
    try:
        forkserver.ensure_running()
    finally:
        del os.environ[FORKSERVER_MAIN]


def _terminate_workers(pool: ProcessPoolExecutor) -> None:
    """Stop the pool's workers now: ``terminate_workers`` from Python 3.14, the same by hand before it."""
    if hasattr(pool, "terminate_workers"):
        pool.terminate_workers()
        return
    for process in list((pool._processes or {}).values()):
        process.terminate()


def _ray_job(initializer: Callable[[], None] | None, job: Job, *args: Any) -> Any:
    """A job on a Ray worker: Ray reuses its workers between tasks, so the initializer is cheap and idempotent."""
    if initializer is not None:
        initializer()
    return job(*args)


class RayExecutor(Executor):
    """Each job a Ray task on the cluster at ``address`` (``"auto"``, ``"HOST:PORT"``, or None: ``RAY_ADDRESS``,
    else a Ray started on this machine for the run). A job whose worker or node dies is run again up to
    :data:`RAY_RETRIES` times (a job's own exceptions are not retried: they are its result); after that
    :class:`WorkerDied`. Ray is connected for the run and disconnected after, unless the caller had connected it."""

    def __init__(self, address: str | None = None, initializer: Callable[[], None] | None = None) -> None:
        try:
            import ray
        except ModuleNotFoundError:
            raise UserError(
                "--executor ray needs Ray: pip install 'lead-s2r[ray]' on every node (see docs/scaling.md)"
            ) from None
        self.ray = ray
        self.address, self.initializer = address, initializer

    @contextlib.contextmanager
    def session(self) -> Iterator[None]:
        """Connected to Ray throughout (a run without a session connects for itself: a Ray started on this machine for
        the run would start again for the next)."""
        ray = self.ray
        connected_here = not ray.is_initialized()
        if connected_here:
            try:
                ray.init(address=self.address, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
            except (ConnectionError, ValueError) as err:
                raise UserError(f"--address {self.address}: cannot connect to a Ray cluster ({err})") from None
        try:
            yield
        finally:
            if connected_here:
                ray.shutdown()

    def run(self, job: Job, arguments: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
        ray = self.ray
        with self.session():
            remote = ray.remote(max_retries=RAY_RETRIES)(_ray_job)
            references = {remote.remote(self.initializer, job, *args): i for i, args in enumerate(arguments)}
            pending = list(references)
            try:
                while pending:
                    done, pending = ray.wait(pending, num_returns=1)
                    yield references[done[0]], self._result(done[0])
            finally:
                for reference in pending:
                    ray.cancel(reference, force=True)

    def _result(self, reference: Any) -> Any:
        """The task's return value or its own exception; a lost worker or node after the retries is WorkerDied.

        The value is copied out: Ray hands numpy arrays over as views into its object store, which the disconnect at
        the end of :meth:`session` unmaps (a second run over the first one's results then read freed memory). A
        pickle round trip copies them at C speed, where ``copy.deepcopy`` walked every list and dict in Python (half
        the driver's CPU on decoded samples); protocol 4, as 5 would leave the copies read-only views of its bytes."""
        exceptions = self.ray.exceptions
        try:
            return pickle.loads(pickle.dumps(self.ray.get(reference), protocol=4))
        except exceptions.RayTaskError as err:  # the job raised: hand its exception on as the job's own
            raise err.as_instanceof_cause() from None
        except (exceptions.WorkerCrashedError, exceptions.NodeDiedError, exceptions.OwnerDiedError) as err:
            raise WorkerDied(f"a Ray worker died {RAY_RETRIES + 1} times on one job: {err}") from err
