"""The resumable sweep runner, generic over the job function.

:func:`run_sweep` inserts the jobs into the results database (existing ids are kept), re-queues the ``running`` rows a
killed run left behind, then keeps ``backend.capacity`` jobs in flight, in the order given, until every job is done or
has failed ``max_attempts`` times. Only the given jobs run and are counted: other jobs the database holds (another
part of the sweep, ``meshadv sweep --only``) wait for a run that names them. The driver is the only writer: each
outcome is written in one transaction as it arrives, after the job has put its artefacts in place. Kill the driver
at any moment and run it again: finished jobs are skipped, interrupted ones run again, nothing is recorded twice.

Example:
    >>> from meshadv.experiments import ResultStore, SerialBackend, run_sweep
    >>> store = ResultStore("/tmp/results.db")                                   # doctest: +SKIP
    >>> summary = run_sweep(store, jobs, "meshadv.experiments.jobs:run_attack_job",
    ...                     out_root="runs/x", backend=SerialBackend())          # doctest: +SKIP
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, Iterable, List, Optional, Union

from meshadv.experiments.artifacts import deliver
from meshadv.experiments.backends import Backend, LocalBackend
from meshadv.experiments.progress import Progress
from meshadv.experiments.spec import JobFn, job_id, job_ref, resolve_job
from meshadv.experiments.store import ResultStore, driver_lock, job_out_dir
from meshadv.experiments.worker import StepReport

__all__ = ["SweepSummary", "run_sweep", "PrepareSpecs", "CHECKPOINT_EVERY"]

#: The runner copies the write-ahead log into the ``.db`` file after this many attempts (and at the end), so a copy of
#: the ``.db`` file alone (e.g. committed to git) misses at most this many recent results, which then run again.
CHECKPOINT_EVERY = 8


@dataclass(frozen=True)
class SweepSummary:
    """Counts at the end of :func:`run_sweep`.

    Attributes:
        total: jobs in the database.
        done: finished jobs; successes: finished jobs whose record says ``success``.
        failed: jobs that exhausted their attempts (``state == 'failed'``).
        ran: attempts started by this call; skipped: jobs already done when it started; requeued: ``running``
            rows of a killed run put back to ``pending``.
        not_started: jobs left waiting because ``stop_starting`` said so (0 when the run went to the end).
    """

    total: int
    done: int
    successes: int
    failed: int
    ran: int
    skipped: int
    requeued: int
    not_started: int = 0


#: ``prepare_specs(store, specs) -> (spec -> spec)``: what a job's specs become before they run.
PrepareSpecs = Callable[[ResultStore, List[Dict[str, Any]]], Callable[[Dict[str, Any]], Dict[str, Any]]]


def run_sweep(
    store: ResultStore,
    jobs: Iterable[Dict[str, Any]],
    job: Union[str, JobFn],
    *,
    out_root: Union[str, Path],
    backend: Optional[Backend] = None,
    max_attempts: int = 2,
    progress: bool = True,
    on_outcome: Optional[Callable[[str, bool], None]] = None,
    planned_steps: Optional[Callable[[Dict[str, Any]], Optional[int]]] = None,
    on_steps: Optional[Callable[[StepReport], None]] = None,
    stop_starting: Optional[Callable[[], bool]] = None,
    prepare_specs: Optional[PrepareSpecs] = None,
) -> SweepSummary:
    """Run every job of ``jobs`` that is not done yet, in their order, resumably.

    Before the queued jobs run, ``prepare_specs`` (by default the job function's ``prepare_specs`` attribute, if
    it has one) maps each stored spec to the spec submitted: the attack job
    (:func:`meshadv.experiments.jobs.run_attack_job`) fills in the database's pinned defaults
    (:func:`meshadv.experiments.jobs.pin_defaults`), so a sweep resumed after a default changed still runs its
    remaining jobs as it ran the first ones.

    Args:
        store: the results database.
        jobs: job specs (JSON-able dicts); ids are hashes of their canonical form.
        job: the job function (module-level) or its reference ``"package.module:function"``; called as
            ``job(spec, out_dir) -> record`` in a worker.
        out_root: root folder of the job artefact folders (:func:`job_out_dir`); made absolute. Backends whose
            workers do not share it (Ray) return the artefacts with the outcome and the driver writes them here, or
            upload them to a URL that is then recorded instead.
        backend: where jobs run; default a :class:`LocalBackend` over every core (closed at the end).
        max_attempts: attempts per job, >= 1 (a crash or exception counts one; a killed run's attempt does not).
        progress: show the progress bars on stderr (jobs done, successes, failures, ETA; steps run out of the most
            the jobs can run, moving per step where the backend forwards the jobs' step reports:
            :mod:`meshadv.experiments.progress`).
        on_outcome: called in the driver after each attempt is recorded, with the job id and whether it succeeded.
        planned_steps: the most steps a job spec can run (``None``: unknown), for the step bar's total; e.g.
            :func:`meshadv.experiments.jobs.planned_steps` for the attack job.
        on_steps: called in the driver (from a backend thread) with every step report of a running job.
        stop_starting: asked before each job is started; once it returns true no job starts any more, the running
            ones finish and are recorded, and the rest stay for the next run (e.g. a batch slot running out:
            ``meshadv sweep --stop-starting-after``, SIGUSR1).
        prepare_specs: ``prepare_specs(store, queued_specs)`` returns the function applied to every spec before
            it is submitted (default: the job function's ``prepare_specs`` attribute; none: specs run as stored).

    Returns:
        The :class:`SweepSummary`.

    Raises:
        ValueError: ``max_attempts < 1`` or a bad job reference.
        RuntimeError: another driver holds this database.
    """
    if max_attempts < 1:
        raise ValueError(f"max_attempts must be >= 1, got {max_attempts}")
    ref = job_ref(job)
    out_root = Path(out_root).resolve()  # workers (Ray, spawned processes) may run in another directory
    own_backend = backend is None
    specs = list(jobs)
    ids = list(dict.fromkeys(job_id(s) for s in specs))  # this sweep's jobs, in its order
    with driver_lock(store.path):
        store.add_jobs(specs)
        requeued = store.requeue_running()
        skipped = store.counts(ids)["done"]
        be = backend if backend is not None else LocalBackend()
        runnable = set(store.runnable(max_attempts))
        queue = [jid for jid in ids if jid in runnable]
        if prepare_specs is None:
            prepare_specs = getattr(resolve_job(ref), "prepare_specs", None)
        prepare = None if prepare_specs is None or not queue else prepare_specs(store, [store.spec(j) for j in queue])
        counts = store.counts(ids)
        planned = {jid: planned_steps(store.spec(jid)) for jid in queue} if planned_steps is not None else None
        bar = Progress(total=counts["total"], done=counts["done"], successes=counts["successes"],
                       failed=0, enabled=progress, planned=planned)

        def _steps(report: StepReport) -> None:
            bar.step(report)
            if on_steps is not None:
                on_steps(report)

        previous_sink = be.on_steps
        be.on_steps = _steps
        in_flight: Dict[Any, str] = {}
        ran = finished = 0
        stopped = False
        try:
            while (queue and not stopped) or in_flight:
                while queue and not stopped and len(in_flight) < be.capacity:
                    if stop_starting is not None and stop_starting():
                        stopped = True
                        break
                    jid = queue.pop(0)
                    store.mark_running(jid)
                    out_dir = job_out_dir(out_root, jid)
                    spec = store.spec(jid) if prepare is None else prepare(store.spec(jid))
                    handle = be.submit(ref, jid, spec, os.fspath(out_dir))
                    in_flight[handle] = jid
                    ran += 1
                for handle, outcome in be.wait(list(in_flight)):
                    jid = in_flight.pop(handle)
                    if outcome.ok and outcome.record is not None:
                        location = deliver(outcome, job_out_dir(out_root, jid))  # artefacts in place first
                        store.mark_done(jid, outcome.record, location)
                        bar.job_finished(jid)
                        bar.update(done=1, successes=int(bool(outcome.record.get("success"))))
                    else:
                        store.mark_failed(jid, outcome.error or "unknown error")
                        retry = store.attempts(jid) < max_attempts
                        bar.job_finished(jid, retry=retry)
                        if retry:
                            queue.append(jid)
                        else:
                            bar.update(failed=1)
                    if on_outcome is not None:
                        on_outcome(jid, outcome.ok)
                    finished += 1
                    if finished % CHECKPOINT_EVERY == 0:
                        store.checkpoint()  # the .db file alone stays a resumable copy of the sweep
        finally:
            be.on_steps = previous_sink
            store.checkpoint()
            bar.close()
            if own_backend:
                be.close()
        counts = store.counts(ids)
    return SweepSummary(
        total=counts["total"],
        done=counts["done"],
        successes=counts["successes"],
        failed=counts["failed"],
        ran=ran,
        skipped=skipped,
        requeued=requeued,
        not_started=len(queue) if stopped else 0,
    )
