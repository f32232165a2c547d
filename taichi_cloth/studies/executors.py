"""Where a batch of independent runs executes (``sweep``, ``compare``): one interface, three
executors.

- ``SerialExecutor``: one run after another in this process (its one Taichi runtime).
- ``LocalExecutor``: ``workers`` processes on this machine (started with *spawn*: a forked
  Taichi runtime is not safe), each keeping its own runtime across the runs it is given. A
  worker that dies (killed, out of memory) is replaced, and its run given to another worker, at
  most ``ATTEMPTS`` times.
- ``DaskExecutor``: a Dask distributed cluster at ``address`` (``--cluster``): the optional
  dependency ``distributed`` (pyproject's ``cluster`` extra). Dask rather than Ray because it is
  pure Python and small (Ray's wheel is ~70 MB with its own object store and dashboard), its
  ``LocalCluster`` starts in a test, and its scheduler already gives a task whose worker died to
  another worker (``distributed.scheduler.allowed-failures``); the runs here need nothing more
  (no shared objects, no actors). The workers must import ``taichi_cloth`` (the same version) and
  see the output folder (a shared file system).

``run(function, jobs)`` yields ``(job, outcome)`` as runs finish, in any order; ``outcome`` is
``function(job)``'s return value, or a ``Lost`` when the run's worker died every time. The
function must be a module-level function (pickled by reference) that catches its own errors.
"""

import multiprocessing
import os
import queue
import socket
from dataclasses import dataclass

from taichi_cloth.errors import InputError

ATTEMPTS = 3  # a run whose worker process dies this many times is recorded as lost
CONNECT_SECONDS = 10  # s: how long --cluster waits for the scheduler
WORKER_THREADS = 1  # Taichi CPU threads per worker: runs side by side do not share cores


@dataclass(frozen=True)
class Lost:
    """A run whose worker died under it (every attempt): why, in one line."""

    reason: str


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


class SerialExecutor:
    """Every run in this process, in order."""

    kind = "serial"

    def __init__(self):
        self.workers = 1

    def machines(self) -> dict:
        """Host name → the number of workers running there side by side."""
        return {socket.gethostname(): 1}

    def run(self, function, jobs):
        for job in jobs:
            yield job, function(job)

    def close(self) -> None:
        pass


def worker_loop(function, tasks, results) -> None:
    """A local worker process: run ``function`` on each (key, job) from its own ``tasks`` queue
    and put (its PID, key, outcome) on ``results``, until it gets None."""
    while (task := tasks.get()) is not None:
        key, job = task
        try:
            outcome = function(job)
        except Exception as error:  # the function's own bug: the run's result says so
            outcome = Lost(f"{type(error).__name__}: {' '.join(str(error).split())}")
        results.put((os.getpid(), key, outcome))


class LocalExecutor:
    """``workers`` processes on this machine, each given one job at a time (so the executor
    knows which run a worker that dies was running: that run is given to a new worker, at most
    ``ATTEMPTS`` times in all, and no other run is charged for it)."""

    kind = "local"
    POLL_SECONDS = 0.5  # how often the workers are checked for life while waiting

    def __init__(self, workers: int):
        self.workers = workers

    def machines(self) -> dict:
        return {socket.gethostname(): self.workers}

    def run(self, function, jobs):
        context = multiprocessing.get_context("spawn")
        results = context.Queue()
        waiting = list(enumerate(jobs))[::-1]  # popped from the end: in order
        attempts = {}
        busy = {}  # worker → (its task queue, the key of the job it runs)
        idle = []
        by_key = dict(waiting)
        finished = set()  # keys whose outcome was yielded

        def start_worker():
            tasks = context.Queue()
            worker = context.Process(target=worker_loop, args=(function, tasks, results),
                                     daemon=True)
            worker.start()
            idle.append((worker, tasks))

        try:
            for _ in range(min(self.workers, len(by_key))):
                start_worker()
            while len(finished) < len(by_key):
                while idle and waiting:
                    worker, tasks = idle.pop()
                    if not worker.is_alive():  # died after its last result: no run to charge
                        start_worker()
                        continue
                    key, job = waiting.pop()
                    if key in finished:  # its first worker's result came after all
                        idle.append((worker, tasks))
                        continue
                    tasks.put((key, job))
                    busy[worker] = (tasks, key)
                try:
                    pid, key, outcome = results.get(timeout=self.POLL_SECONDS)
                except queue.Empty:
                    for worker in [w for w in busy if not w.is_alive()]:
                        _, key = busy.pop(worker)
                        attempts[key] = attempts.get(key, 0) + 1
                        start_worker()
                        if key in finished:
                            continue
                        if attempts[key] < ATTEMPTS:
                            waiting.append((key, by_key[key]))
                        else:
                            finished.add(key)
                            yield by_key[key], Lost(f"its worker process died {ATTEMPTS} times")
                    continue
                sender = next((w for w in busy if w.pid == pid), None)
                if sender is not None:  # (a worker that died after sending is not busy now)
                    idle.append((sender, busy.pop(sender)[0]))
                if key not in finished:  # a run retried after its result was sent: once
                    finished.add(key)
                    yield by_key[key], outcome
        finally:  # idle workers stop; busy ones (an interrupted sweep) are stopped
            for worker, tasks in idle:
                tasks.put(None)
            for worker in busy:
                worker.terminate()
            for worker in [*busy, *(worker for worker, _ in idle)]:
                worker.join(timeout=5)

    def close(self) -> None:
        pass


class DaskExecutor:
    """The workers of the Dask cluster whose scheduler is at ``address``."""

    kind = "dask"

    def __init__(self, address: str):
        try:
            from distributed import Client
        except ImportError:
            raise InputError("--cluster: needs Dask's distributed package (pip install "
                             "'taichi-cloth[cluster]', or distributed from "
                             "requirements-test.txt)") from None
        try:
            self.client = Client(address, timeout=CONNECT_SECONDS)
        except (OSError, TimeoutError, ValueError) as error:
            raise InputError(f"--cluster {address}: no Dask scheduler answered "
                             f"({' '.join(str(error).split())})") from None
        self.address = address
        workers = self.client.scheduler_info(n_workers=-1)["workers"].values()
        threaded = [worker for worker in workers if worker.get("nthreads", 1) != 1]
        if not workers or threaded:
            self.client.close()
            raise InputError(f"--cluster {address}: " + (
                "the cluster has no workers" if not workers else
                f"a worker runs {threaded[0].get('nthreads')} threads; a worker process holds "
                f"one Taichi runtime, which runs one simulation at a time: start the workers "
                f"with --nthreads 1 (docs/scaling.md)"))
        self.workers = sum(worker.get("nthreads", 1) for worker in workers)
        self.hosts = {}
        for worker in workers:
            host = worker.get("host", "?")
            self.hosts[host] = self.hosts.get(host, 0) + worker.get("nthreads", 1)

    def machines(self) -> dict:
        return dict(self.hosts)

    def run(self, function, jobs):
        from distributed import as_completed
        futures = {self.client.submit(function, job, pure=False): job for job in jobs}
        try:
            for future in as_completed(futures):
                job = futures[future]
                try:
                    outcome = future.result()
                except Exception as error:  # KilledWorker: its workers died every time
                    outcome = Lost(f"{type(error).__name__}: {' '.join(str(error).split())}")
                yield job, outcome
        except BaseException:
            self.client.cancel(list(futures))
            raise

    def close(self) -> None:
        self.client.close()


def make_executor(workers: int | None, cluster: str | None):
    """--cluster ADDRESS: Dask; else --workers N (default: the usable cores): one runs in this
    process, more in that many local processes."""
    if cluster is not None:
        if workers is not None:
            raise InputError("--workers: a --cluster run uses the cluster's workers; give one "
                             "of the two")
        return DaskExecutor(cluster)
    count = usable_cores() if workers is None else workers
    if count < 1:
        raise InputError(f"--workers {workers}: must be at least 1")
    return SerialExecutor() if count == 1 else LocalExecutor(count)
