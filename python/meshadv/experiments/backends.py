"""Execution backends: where jobs run. The runner talks to them through ``submit`` / ``wait`` / ``close``.

- :class:`LocalBackend` (default): ``workers`` long-lived worker processes started with ``spawn`` (torch and ``fork``
  do not mix), fed by a ``concurrent.futures`` thread pool; a segfault or an ``os._exit`` in one job (a native
  renderer crash, Mitsuba, an OOM kill) is recorded as that job's crash, its worker is replaced and the sweep goes on.
  A per-job timeout kills the worker. Workers exit by themselves when the driver dies.
- :class:`RayBackend`: Ray tasks (``ray.init(address)`` on a cluster, a local Ray instance when no address is given).
  No shared file system is needed: each task runs its job in a temporary folder of its node and its artefacts come
  back to the driver with the task's result (or go to a URL, e.g. ``s3://bucket/run``, through fsspec); the driver
  alone writes the artefact folders and the database (:mod:`meshadv.experiments.artifacts`). Tasks can be pinned to
  nodes by custom resources (``ray start --resources '{"meshadv": 4}'``); a task lost with its node is recorded as a
  failed attempt and retried by the runner on another node.
- :class:`SerialBackend`: runs jobs one by one inside the driver process (debugging, profiling; no crash isolation).

Step progress: a job's :func:`~meshadv.experiments.worker.report_steps` calls reach the driver's ``on_steps`` as
:class:`~meshadv.experiments.worker.StepReport` objects while the job runs with the local backend (over the worker's
pipe, before its outcome) and the serial one (directly). Ray tasks do not report steps: the driver sees a Ray job's
progress when it finishes.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os
import queue
import signal
import threading
import time
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

from meshadv.experiments.artifacts import run_detached
from meshadv.experiments.worker import Outcome, StepReport, execute

__all__ = ["Backend", "LocalBackend", "SerialBackend", "RayBackend", "make_backend", "BACKENDS"]

#: Backend names accepted by :func:`make_backend` and ``meshadv sweep --backend``.
BACKENDS = ("local", "ray", "serial")


class Backend:
    """Interface of an execution backend.

    ``submit`` starts a job and returns a handle; ``wait`` blocks until at least one submitted job finishes (or
    ``timeout`` passes) and returns the finished ``(handle, Outcome)`` pairs; ``close`` releases the workers.
    ``capacity`` is how many jobs should be in flight at once. ``on_steps``, when set by the driver, receives the
    running jobs' :class:`~meshadv.experiments.worker.StepReport` objects (from any thread; those of a job before its
    outcome) on backends that forward them.
    """

    capacity: int = 1
    on_steps: Optional[Callable[[StepReport], None]] = None

    def submit(self, job_ref: str, job_id: str, spec: Dict[str, Any], out_dir: str) -> Any:
        """Start one job; return a handle."""
        raise NotImplementedError

    def wait(self, handles: Sequence[Any], timeout: Optional[float] = None) -> List[Tuple[Any, Outcome]]:
        """Return the finished jobs among ``handles`` (at least one unless ``timeout`` passed)."""
        raise NotImplementedError

    def close(self) -> None:
        """Stop the workers (jobs still running are abandoned)."""

    def __enter__(self) -> "Backend":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: SIGUSR1 where the platform has it (and ``pthread_sigmask``): workers ignore it (see :func:`_worker_main`).
_USR1 = getattr(signal, "SIGUSR1", None) if hasattr(signal, "pthread_sigmask") else None


def _parent_watchdog(parent_pid: int) -> None:
    while True:
        time.sleep(1.0)
        if os.getppid() != parent_pid:
            os._exit(3)


def _worker_main(conn: Any, parent_pid: int, threads: int) -> None:
    """Body of a local worker process: run the jobs received on ``conn`` until told to stop."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C stops the driver, which then stops its workers
    if _USR1 is not None:  # the driver's "stop starting jobs" (meshadv sweep), sent to the whole process group, must
        signal.signal(_USR1, signal.SIG_IGN)  # not kill a job (SIGUSR1's default action); blocked since the spawn
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {_USR1})  # (_Worker), so none arriving meanwhile is lost on us
    threading.Thread(target=_parent_watchdog, args=(parent_pid,), daemon=True).start()
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        conn.send(execute(*msg, threads=threads, step_sink=conn.send))  # step reports, then the outcome


def _crash_reason(exitcode: Optional[int]) -> str:
    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        return f"job process crashed: killed by {name} (exit code {exitcode})"
    return f"job process died without reporting a result (exit code {exitcode})"


class _Worker:
    """A spawned worker process and the pipe to it."""

    def __init__(self, ctx: Any, threads: int) -> None:
        self.conn, child = ctx.Pipe(duplex=True)
        self.proc = ctx.Process(target=_worker_main, args=(child, os.getpid(), threads), name="meshadv-worker")
        blocked = {_USR1} if _USR1 is not None else set()
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, blocked)  # the child inherits this thread's mask
        try:
            self.proc.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        child.close()
        self.jobs = 0

    def stop(self, kill: bool = False) -> None:
        if kill:
            self.proc.kill()
        else:
            try:
                self.conn.send(None)
            except (OSError, BrokenPipeError):
                self.proc.kill()
        self.proc.join(timeout=10)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()
        self.conn.close()


class LocalBackend(Backend):
    """Run jobs in ``workers`` spawned worker processes on this machine.

    Each worker process is started with the ``spawn`` method, imports torch and the job module once and runs job
    after job (so imports and loaded victims are paid once per worker, not per job). When a job kills its worker
    (segfault, ``os._exit``, OOM kill) or exceeds ``timeout``, only that job is recorded as crashed and a fresh worker
    replaces the dead one.

    Args:
        workers: parallel jobs (0 = every core).
        threads_per_job: intra-op threads of each job (0 = ``cores // workers``, at least 1).
        timeout: seconds after which a job's worker is killed and the attempt recorded as failed (0 = none).
        max_jobs_per_worker: restart a worker after this many jobs, to bound leaks (0 = never).

    Raises:
        ValueError: negative arguments.
    """

    def __init__(self, workers: int = 0, threads_per_job: int = 0, timeout: float = 0.0,
                 max_jobs_per_worker: int = 0) -> None:
        if workers < 0 or threads_per_job < 0 or timeout < 0 or max_jobs_per_worker < 0:
            raise ValueError(
                "workers, threads_per_job, timeout and max_jobs_per_worker must be >= 0, got "
                f"{workers}, {threads_per_job}, {timeout}, {max_jobs_per_worker}"
            )
        cores = os.cpu_count() or 1
        self.capacity = workers or cores
        self.threads_per_job = threads_per_job or max(1, cores // self.capacity)
        self.timeout = float(timeout)
        self.max_jobs_per_worker = int(max_jobs_per_worker)
        self._ctx = mp.get_context("spawn")
        self._pool = cf.ThreadPoolExecutor(max_workers=self.capacity, thread_name_prefix="meshadv-job")
        self._idle: "queue.SimpleQueue[_Worker]" = queue.SimpleQueue()
        self._busy: Dict[int, _Worker] = {}
        self._lock = threading.Lock()
        self._closing = False

    def _acquire(self) -> Optional[_Worker]:
        with self._lock:
            if self._closing:
                return None
            try:
                worker = self._idle.get_nowait()
            except queue.Empty:
                worker = _Worker(self._ctx, self.threads_per_job)
            self._busy[id(worker)] = worker
            return worker

    def _release(self, worker: _Worker, healthy: bool) -> None:
        with self._lock:
            self._busy.pop(id(worker), None)
            recycle = self.max_jobs_per_worker and worker.jobs >= self.max_jobs_per_worker
            if healthy and not recycle and not self._closing:
                self._idle.put(worker)
                return
        worker.stop(kill=not healthy)

    def _receive(self, worker: _Worker) -> Optional[Outcome]:
        """The next message of ``worker``: a step report is passed to ``on_steps`` (``None`` returned), an outcome
        returned."""
        msg = worker.conn.recv()
        if isinstance(msg, StepReport):
            if self.on_steps is not None:
                self.on_steps(msg)
            return None
        return msg

    def _run(self, job_ref: str, job_id: str, spec: Dict[str, Any], out_dir: str) -> Outcome:
        start = time.perf_counter()
        worker = self._acquire()
        if worker is None:
            return Outcome(job_id, False, None, "sweep stopped before the job started", 0.0)
        outcome: Optional[Outcome] = None
        error = None
        try:
            worker.conn.send((job_ref, job_id, spec, out_dir))
            worker.jobs += 1
            while True:
                if worker.conn.poll(0.2):
                    outcome = self._receive(worker)
                    if outcome is not None:
                        break
                if not worker.proc.is_alive():
                    while outcome is None and worker.conn.poll(0):
                        outcome = self._receive(worker)
                    break
                if self.timeout and time.perf_counter() - start > self.timeout:
                    worker.proc.kill()
                    error = f"job timed out after {self.timeout:g} s and was killed"
                    break
        except (EOFError, OSError):
            outcome = None
        if outcome is not None:
            self._release(worker, healthy=True)
            return outcome
        worker.proc.join(timeout=10)
        exitcode = worker.proc.exitcode
        self._release(worker, healthy=False)
        return Outcome(job_id, False, None, error or _crash_reason(exitcode), time.perf_counter() - start)

    def submit(self, job_ref: str, job_id: str, spec: Dict[str, Any], out_dir: str) -> cf.Future:
        """Queue one job for the next free worker; return its future."""
        return self._pool.submit(self._run, job_ref, job_id, spec, out_dir)

    def wait(self, handles: Sequence[Any], timeout: Optional[float] = None) -> List[Tuple[Any, Outcome]]:
        """Wait for the first finished job(s)."""
        done, _ = cf.wait(list(handles), timeout=timeout, return_when=cf.FIRST_COMPLETED)
        return [(f, f.result()) for f in done]

    def close(self) -> None:
        """Kill the workers still running a job, stop the idle ones and the pool."""
        with self._lock:
            self._closing = True
            busy = list(self._busy.values())
        for worker in busy:
            if worker.proc.is_alive():
                worker.proc.kill()
        self._pool.shutdown(wait=True, cancel_futures=True)
        while True:
            try:
                self._idle.get_nowait().stop()
            except queue.Empty:
                break


class SerialBackend(Backend):
    """Run jobs one at a time in the driver process (no isolation: a segfault ends the sweep).

    Args:
        threads_per_job: intra-op threads (0 = process default).
    """

    capacity = 1

    def __init__(self, threads_per_job: int = 0) -> None:
        self.threads_per_job = threads_per_job
        self._pending: Dict[int, Tuple[str, str, Dict[str, Any], str]] = {}
        self._next = 0

    def submit(self, job_ref: str, job_id: str, spec: Dict[str, Any], out_dir: str) -> int:
        """Queue one job (it runs inside :meth:`wait`)."""
        self._next += 1
        self._pending[self._next] = (job_ref, job_id, spec, out_dir)
        return self._next

    def wait(self, handles: Sequence[Any], timeout: Optional[float] = None) -> List[Tuple[Any, Outcome]]:
        """Run the first queued job among ``handles`` and return its outcome."""
        for handle in handles:
            if handle in self._pending:
                args = self._pending.pop(handle)
                return [(handle, execute(*args, threads=self.threads_per_job, step_sink=self.on_steps))]
        return []


class RayBackend(Backend):
    """Run jobs as Ray tasks (one CPU each unless ``cpus_per_job`` says otherwise).

    Args:
        address: the cluster address (``"auto"``, ``"ray://host:10001"``, ...); ``None`` starts a local Ray instance.
        num_cpus: CPUs of the local instance (ignored with an address; ``None`` = every core).
        cpus_per_job: CPUs reserved per task (and its intra-op threads).
        max_in_flight: tasks submitted at once (0 = what the cluster's CPUs and ``resources`` allow at once).
        artifacts: ``"return"`` (default): jobs run in a temporary folder of their node and their files come back
            with the task's result, the driver writes them; an fsspec URL (``s3://bucket/run``): files are uploaded
            to ``<URL>/jobs/<id[:2]>/<id>/`` and that location is recorded; ``"shared"``: the job writes the
            driver's folder directly (every node must see it).
        resources: custom Ray resources each task needs, e.g. ``{"meshadv": 1}`` to run only on nodes started
            with ``--resources '{"meshadv": N}'``.

    Raises:
        ImportError: Ray is not installed (``pip install 'ray>=2.9'``).
        ValueError: bad ``cpus_per_job`` or ``resources``.
    """

    def __init__(self, address: Optional[str] = None, *, num_cpus: Optional[int] = None, cpus_per_job: int = 1,
                 max_in_flight: int = 0, artifacts: str = "return",
                 resources: Optional[Dict[str, float]] = None) -> None:
        try:
            import ray
        except ImportError as err:
            raise ImportError("the ray backend needs Ray: pip install 'ray>=2.9'") from err
        if cpus_per_job < 1:
            raise ValueError(f"cpus_per_job must be >= 1, got {cpus_per_job}")
        resources = dict(resources or {})
        if any(not isinstance(v, (int, float)) or v <= 0 for v in resources.values()):
            raise ValueError(f"resources must map resource names to amounts > 0, got {resources}")
        if artifacts not in ("return", "shared") and "://" not in str(artifacts):
            raise ValueError(f"artifacts must be 'return', 'shared' or an fsspec URL (s3://...), got {artifacts!r}")
        self._ray = ray
        self._owns = False
        if not ray.is_initialized():
            if address:
                ray.init(address=address)
            else:
                ray.init(num_cpus=num_cpus, include_dashboard=False)
            self._owns = True
        total = ray.cluster_resources()
        slots = [int(total.get("CPU", 1)) // cpus_per_job] + [int(total.get(k, 0) // v) for k, v in resources.items()]
        self.capacity = max_in_flight or max(1, min(slots))
        self.cpus_per_job = cpus_per_job
        self.artifacts = artifacts
        options = {"num_cpus": cpus_per_job, "max_retries": 0, **({"resources": resources} if resources else {})}
        self._remote = ray.remote(**options)(execute if artifacts == "shared" else run_detached)
        self._ids: Dict[Any, str] = {}

    def submit(self, job_ref: str, job_id: str, spec: Dict[str, Any], out_dir: str) -> Any:
        """Submit one job as a Ray task; return its object ref (the driver's ``out_dir`` travels only in
        ``"shared"`` mode)."""
        if self.artifacts == "shared":
            ref = self._remote.remote(job_ref, job_id, spec, out_dir, self.cpus_per_job)
        else:
            destination = None if self.artifacts == "return" else self.artifacts
            ref = self._remote.remote(job_ref, job_id, spec, self.cpus_per_job, destination)
        self._ids[ref] = job_id
        return ref

    def wait(self, handles: Sequence[Any], timeout: Optional[float] = None) -> List[Tuple[Any, Outcome]]:
        """Wait for the first finished task(s); a crashed worker becomes a failed outcome."""
        ready, _ = self._ray.wait(list(handles), num_returns=1, timeout=timeout)
        out = []
        for ref in ready:
            job_id = self._ids.pop(ref, "?")
            try:
                outcome = self._ray.get(ref)
            except Exception as err:  # noqa: BLE001 - worker crash, node loss, ...
                outcome = Outcome(job_id, False, None, f"ray task failed: {type(err).__name__}: {err}", 0.0)
            out.append((ref, outcome))
        return out

    def close(self) -> None:
        """Shut Ray down when this backend started it."""
        if self._owns:
            self._ray.shutdown()
            self._owns = False


def make_backend(name: str, *, workers: int = 0, threads_per_job: int = 0, timeout: float = 0.0,
                 address: Optional[str] = None, max_jobs_per_worker: int = 0, artifacts: str = "return",
                 resources: Optional[Dict[str, float]] = None) -> Backend:
    """Build a backend by name.

    Args:
        name: one of :data:`BACKENDS`.
        workers: parallel jobs (local) or local Ray CPUs (ray without address); 0 = every core.
        threads_per_job: intra-op threads per job (0 = automatic).
        timeout: per-job timeout in seconds for the local backend (0 = none).
        address: Ray cluster address (ray only).
        max_jobs_per_worker: local backend: restart a worker process after this many jobs (0 = never).
        artifacts, resources: ray only (see :class:`RayBackend`).

    Raises:
        ValueError: unknown name, or an address given to a non-Ray backend.
    """
    if name not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {name!r}")
    if address and name != "ray":
        raise ValueError(f"address is only used by the ray backend, got backend={name!r}")
    if name == "local":
        return LocalBackend(workers=workers, threads_per_job=threads_per_job, timeout=timeout,
                            max_jobs_per_worker=max_jobs_per_worker)
    if name == "serial":
        return SerialBackend(threads_per_job=threads_per_job)
    return RayBackend(address, num_cpus=workers or None, cpus_per_job=max(1, threads_per_job), artifacts=artifacts,
                      resources=resources)
