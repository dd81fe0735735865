"""Where independent work runs: one small interface over three executors.

The benchmark's independent work (render a chunk of poses, parse and describe a chunk of
views, train a variant, score a chunk of views) is written as *tasks*: plain module-level
functions of one picklable job that return a picklable result (:mod:`ssga_bench.tasks`,
:mod:`ssga_bench.variant_training`, :func:`ssga_bench.scoring.score_chunk`). An :class:`Executor` maps a task over jobs
and yields the results in job order::

    with open_executor(ExecutionConfig(executor="processes")) as executor:
        for result in executor.map(render_views, jobs, describe=lambda job: job.what, progress=bar):
            ...

* ``serial``: in this process (for debugging; a breakpoint in a stage works).
* ``processes`` (the default): spawned local worker processes, every core by default.
* ``ray``: Ray tasks, on a local Ray it starts or one already running in this process,
  or on the cluster at ``address`` (``ray start --head`` on one node, ``ray start
  --address`` on the others; docs/scaling.md).

Whatever the executor, a task runs with torch, OpenCV and BLAS at one thread (two busy
processes on two cores, each with a pool of two threads, were slower than one), jobs
are cut by the caller independently of the number of workers, and every task seeds
itself from its job: so results are identical, bit for bit, whatever the executor and
the number of workers. Only a bounded window of jobs is in flight, so results stream
and memory is bounded by the window, not by the run. A task that fails is reported
with the job it was working on (``describe``): a user error as one line, a bug with the
worker's traceback.
"""

from __future__ import annotations

import os
import pickle
import sys
import traceback
from abc import ABC, abstractmethod
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, Literal, TypeVar

from pydantic import ConfigDict, Field, ValidationError, model_validator

from ssga_core.config import Strict
from ssga_core.errors import InputError, SsgaError

J = TypeVar("J")
R = TypeVar("R")

ExecutorName = Literal["serial", "processes", "ray"]
EXECUTORS: tuple[str, ...] = ("serial", "processes", "ray")

THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "OPENCV_FOR_THREADS_NUM",
)
"""Read by the numeric libraries when they load, which in a worker is before any code of ours runs."""


class ExecutionConfig(Strict):
    """Which executor runs the independent work, and how it is cut (``[execution]``)."""

    model_config = ConfigDict(allow_inf_nan=False)

    executor: ExecutorName | None = Field(
        default=None,
        description="'processes': local worker processes; 'serial': this process, for debugging; 'ray': Ray tasks, "
        "locally or on the cluster at `address`. Unset: the environment's SSGA_EXECUTOR, else 'processes'.",
    )
    workers: int = Field(
        default=0,
        ge=0,
        le=65536,
        description="Workers: 0 takes every local core ('processes') or every CPU of the Ray cluster ('ray'). Results do not depend on it.",
    )
    address: str | None = Field(
        default=None,
        min_length=1,
        description="executor = 'ray': the cluster to join ('auto', or the head's 'host:port'); unset: a local Ray.",
    )
    batch: int = Field(
        default=16,
        ge=1,
        le=4096,
        description="Views per task (and per network call of a learned stage); larger keeps a GPU busier. Results do not depend on the executor or workers.",
    )

    @model_validator(mode="after")
    def _address_needs_ray(self) -> ExecutionConfig:
        if self.address is not None and self.executor not in (None, "ray"):
            raise ValueError(f"address is for executor = 'ray' (executor is {self.executor!r})")
        return self

    def executor_name(self) -> str:
        """The executor to use: the config's, else ``$SSGA_EXECUTOR`` (a machine's or a test
        suite's default), else ``"processes"``; with an ``address``, ``"ray"``."""
        if self.executor is not None:
            return self.executor
        if self.address is not None:
            return "ray"
        name = os.environ.get("SSGA_EXECUTOR", "").strip() or "processes"
        if name not in EXECUTORS:
            raise InputError(f"SSGA_EXECUTOR={name!r}: expected one of {', '.join(EXECUTORS)}")
        return name

    def updated(self, **options: Any) -> ExecutionConfig:
        """This config with the command line's options that were given (not ``None``), validated."""
        given = {k: v for k, v in options.items() if v is not None}
        if not given:
            return self
        data = {**self.model_dump(), **given}
        if given.get("executor", "ray") != "ray" and "address" not in given:
            data["address"] = None  # the config's cluster address does not follow a switch away from Ray
        try:
            return ExecutionConfig.model_validate(data)
        except ValidationError as exc:  # one line naming the options
            detail = "; ".join(e["msg"].removeprefix("Value error, ") for e in exc.errors())
            raise InputError(f"--executor/--workers/--address: {detail}") from None


def local_cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


class TaskError(SsgaError):
    """A task stopped on a user error (a broken file, a missing checkpoint): one line naming its job."""


class TaskCrashed(RuntimeError):
    """A task raised something that is not a user error: a bug, reported with the worker's traceback."""


# -- what runs in a worker --------------------------------------------------------------

_MEMO: OrderedDict[Hashable, Any] = OrderedDict()
MEMO_SIZE = 8
"""Opened datasets, stage instances and workspaces a process keeps (a bench opens one
workspace per seed; a learned stage's network is large)."""


def memo(key: Hashable, make: Callable[[], R]) -> R:
    """What ``make`` returns, made once per process for ``key``: a worker opens a dataset,
    builds a stage (loads its network) or opens a workspace once, not once per task."""
    if key in _MEMO:
        _MEMO.move_to_end(key)
        return _MEMO[key]  # type: ignore[no-any-return]
    value = make()
    _MEMO[key] = value
    while len(_MEMO) > MEMO_SIZE:
        _MEMO.popitem(last=False)
    return value


_worker_ready = False


def worker_setup() -> None:
    """One thread for torch, OpenCV and BLAS in this (worker) process; done once."""
    global _worker_ready  # noqa: PLW0603 - once per process
    if _worker_ready:
        return
    os.environ.update(dict.fromkeys(THREAD_VARIABLES, "1"))
    import cv2
    from threadpoolctl import threadpool_limits

    cv2.setNumThreads(1)
    threadpool_limits(1)
    if "torch" in sys.modules:  # else torch reads OMP_NUM_THREADS when it loads
        import torch

        torch.set_num_threads(1)
    _worker_ready = True


def _outcome(task: Callable[[J], R], job: J, worker: bool) -> tuple[str, Any]:
    """Run ``task(job)``; what happened. In a worker, in a form that always pickles back to
    the driver: a user error as itself where it survives the trip (its type tells the
    caller what went wrong), else as its message; a bug as its traceback's text. Here (the
    serial executor), the exception itself, so a debugger stops where it was raised."""
    try:
        if worker:
            worker_setup()
        return "ok", task(job)
    except SsgaError as exc:
        return "user", _portable(exc) if worker else exc
    except Exception as exc:  # noqa: BLE001 - a bug: raised in the driver with what the task was doing
        return "bug", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}" if worker else exc


def _portable(exc: SsgaError) -> SsgaError | str:
    try:
        copy = pickle.loads(pickle.dumps(exc))
        return copy if str(copy) == str(exc) else str(exc)
    except Exception:  # noqa: BLE001 - an error whose constructor does not survive pickling: its message then
        return str(exc)


def _raise(status: str, value: Any, what: str) -> None:
    """Raise a failed task's error in the driver, saying which job it was working on."""
    if isinstance(value, BaseException):
        if isinstance(value, SsgaError) and len(value.args) == 1 and isinstance(value.args[0], str):
            value.args = (f"{what}: {value.args[0]}",)  # one line still, now naming the job
        else:
            value.add_note(f"(while working on {what})")
        raise value
    if status == "user":
        raise TaskError(f"{what}: {value}")
    raise TaskCrashed(f"{what}: {value}")


# -- the executors ------------------------------------------------------------------------


class Executor(ABC):
    """Maps a task over jobs; results come back in job order (see the module docstring)."""

    workers: int = 1

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        # Interrupted (Ctrl-C; a scheduler's SIGTERM, which `ssga` turns into the same): the
        # tasks running now are stopped, not waited for, and no worker outlives the run.
        if kind is not None and issubclass(kind, KeyboardInterrupt):
            self.abort()
        self.close()

    def close(self) -> None:
        """Release the workers (a Ray this executor started is shut down; one it joined is left)."""

    def abort(self) -> None:
        """Stop the tasks running now, before :meth:`close` (an interrupted run; what they
        would have written is written again when it resumes)."""

    def map(
        self,
        task: Callable[[J], R],
        jobs: Sequence[J],
        *,
        describe: Callable[[J], str] = repr,
        progress: Callable[[int, int], None] | None = None,
    ) -> Iterator[R]:
        """``task(job)`` for every job, yielded in job order as they finish.

        Args:
            task: a module-level function (workers import it by name).
            describe: what a job is working on, for the error of a task that fails
                (``"views test-0001-00003 ... test-0001-00018"``, ``"variant SIFT (SD)"``).
            progress: called with ``(finished, total)`` as jobs finish, in any order.
        """
        jobs = list(jobs)
        window = self._window()
        pending: dict[int, Any] = {}
        finished: dict[int, tuple[str, Any]] = {}
        submitted = yielded = done = 0
        try:
            while yielded < len(jobs):
                # Finished-but-not-yet-yielded results count against the window too: memory
                # stays bounded while the job at the head of the queue is slow.
                while submitted < len(jobs) and len(pending) + len(finished) < window:
                    pending[submitted] = self._submit(task, jobs[submitted])
                    submitted += 1
                if yielded not in finished:
                    for index, outcome in self._wait(pending):
                        del pending[index]
                        finished[index] = outcome
                        done += 1
                        if progress:
                            progress(done, len(jobs))
                    continue
                status, value = finished.pop(yielded)
                if status != "ok":
                    _raise(status, value, describe(jobs[yielded]))
                yielded += 1
                yield value
        finally:
            if pending:
                self._cancel(pending)

    def _window(self) -> int:
        return 2 * self.workers + 1

    @abstractmethod
    def _submit(self, task: Callable[[J], R], job: J) -> Any: ...

    @abstractmethod
    def _wait(self, pending: dict[int, Any]) -> list[tuple[int, tuple[str, Any]]]:
        """At least one finished job of ``pending``: ``(index, outcome)``."""

    def _cancel(self, pending: dict[int, Any]) -> None:
        """Drop jobs not yet started (a task failed, or the consumer stopped)."""


class SerialExecutor(Executor):
    """Every task in this process, in order, single-threaded as a worker would be."""

    def __init__(self) -> None:
        self._threads = _single_threaded_here()
        self._threads.__enter__()

    def close(self) -> None:
        if self._threads is not None:
            self._threads.__exit__(None, None, None)
            self._threads = None  # type: ignore[assignment]

    def _window(self) -> int:
        return 1

    def _submit(self, task: Callable[[J], R], job: J) -> Any:
        return _outcome(task, job, worker=False)

    def _wait(self, pending: dict[int, Any]) -> list[tuple[int, tuple[str, Any]]]:
        return list(pending.items())


class ProcessExecutor(Executor):
    """Spawned local worker processes (spawned, not forked: forking after Embree or torch
    have started their threads is unsafe), started on the first job and kept until closed."""


    def __init__(self, workers: int = 0) -> None:
        self.workers = workers or local_cores()
        self._pool: Any = None
        self._environment: Any = None

    def _submit(self, task: Callable[[J], R], job: J) -> Any:
        if self._pool is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            # Set while the pool lives: workers start on demand and their BLAS reads it on load.
            self._environment = single_threaded_children()
            self._environment.__enter__()
            self._pool = ProcessPoolExecutor(self.workers, multiprocessing.get_context("spawn"), worker_setup)
        return self._pool.submit(_outcome, task, job, True)

    def _wait(self, pending: dict[int, Any]) -> list[tuple[int, tuple[str, Any]]]:
        from concurrent.futures import FIRST_COMPLETED, wait
        from concurrent.futures.process import BrokenProcessPool

        index_of = {future: index for index, future in pending.items()}
        finished, _ = wait(index_of, return_when=FIRST_COMPLETED)
        out = []
        for future in finished:
            try:
                out.append((index_of[future], future.result()))
            except BrokenProcessPool as exc:  # a worker died: killed for memory, or a crash in C
                out.append((index_of[future], ("bug", f"a worker process died ({exc}); was it killed for memory?")))
        return out

    def _cancel(self, pending: dict[int, Any]) -> None:
        for future in pending.values():
            future.cancel()

    def abort(self) -> None:
        if self._pool is not None:
            if hasattr(self._pool, "terminate_workers"):  # Python 3.14
                self._pool.terminate_workers()
                return
            for process in list((self._pool._processes or {}).values()):  # no public way before 3.14
                process.terminate()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
            self._environment.__exit__(None, None, None)


class RayExecutor(Executor):
    """Ray tasks of one CPU each: on the Ray this process already runs, else a local Ray
    it starts (``address`` unset) or the cluster at ``address``."""


    def __init__(self, workers: int = 0, address: str | None = None) -> None:
        try:
            import ray
        except ImportError:
            raise InputError("executor = 'ray' needs Ray: pip install 'ssga-bench[ray]' (or pip install ray)") from None
        self._ray = ray
        self._started = False
        if not ray.is_initialized():
            if address is not None:
                _check_reachable(address)
            env = {"env_vars": dict.fromkeys(THREAD_VARIABLES, "1")}
            try:
                ray.init(
                    address=address,
                    num_cpus=(workers or None) if address is None else None,
                    include_dashboard=False,
                    runtime_env=env,
                    logging_level="WARNING",
                    configure_logging=True,
                )
            except ConnectionError as exc:
                raise InputError(f"address {address!r}: no Ray cluster answers there ({exc}); start one with `ray start --head`") from None
            self._started = True
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.workers = min(workers, cpus) if workers else cpus
        self._remote = ray.remote(num_cpus=1, max_retries=0)(_outcome)

    def _submit(self, task: Callable[[J], R], job: J) -> Any:
        return self._remote.remote(task, job, True)

    def _wait(self, pending: dict[int, Any]) -> list[tuple[int, tuple[str, Any]]]:
        index_of = {ref: index for index, ref in pending.items()}
        ready, _ = self._ray.wait(list(index_of), num_returns=1)
        out = []
        for ref in ready:
            try:
                out.append((index_of[ref], self._ray.get(ref)))
            except Exception as exc:  # noqa: BLE001 - a worker or node lost: Ray's own error
                out.append((index_of[ref], ("bug", f"Ray lost the task: {type(exc).__name__}: {exc}")))
        return out

    def _cancel(self, pending: dict[int, Any]) -> None:
        for ref in pending.values():
            try:
                self._ray.cancel(ref)
            except Exception:  # noqa: BLE001, S110 - already finished or gone: nothing to cancel
                pass

    def close(self) -> None:
        if self._started:
            self._ray.shutdown()
            self._started = False


def _check_reachable(address: str) -> None:
    """A ``host:port`` nothing listens on is a one-line error now (Ray itself retries for a minute)."""
    import socket

    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdecimal():
        return  # "auto", or a form Ray resolves itself
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=5):
            pass
    except OSError as exc:
        raise InputError(f"address {address!r}: no Ray cluster answers there ({exc.strerror or exc}); start one with `ray start --head`") from None


def open_executor(config: ExecutionConfig | None = None) -> Executor:
    """The executor ``config`` names (default: local processes on every core)."""
    config = config or ExecutionConfig()
    name = config.executor_name()
    if name == "serial":
        return SerialExecutor()
    if name == "ray":
        return RayExecutor(config.workers, config.address)
    return ProcessExecutor(config.workers)


@contextmanager
def single_threaded_children() -> Iterator[None]:
    """Processes started inside this block load their numeric libraries single-threaded.

    Set in the environment, not in a worker's initializer, because BLAS and OpenMP read it
    when they load, which is before any initializer runs.
    """
    saved = {k: os.environ.get(k) for k in THREAD_VARIABLES}
    os.environ.update(dict.fromkeys(THREAD_VARIABLES, "1"))
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


@contextmanager
def _single_threaded_here() -> Iterator[None]:
    """This process at one thread per library while the serial executor is open, as a
    worker is: the same arithmetic, so the same results to the bit."""
    import cv2
    from threadpoolctl import threadpool_limits

    # torch loads now, not inside the block: loaded there, it would read the block's
    # OMP_NUM_THREADS and stay at one thread for the rest of the process.
    import torch

    before_cv2, before_torch = cv2.getNumThreads(), torch.get_num_threads()
    # threadpoolctl restores OpenMP (torch's pool) to what it found: enter it before
    # touching torch, and leave it before restoring torch.
    try:
        with single_threaded_children(), threadpool_limits(1):
            cv2.setNumThreads(1)
            torch.set_num_threads(1)
            yield
    finally:
        cv2.setNumThreads(before_cv2)
        torch.set_num_threads(before_torch)
