"""Running one job in a worker: resolve the job function, run it, turn any exception into an :class:`Outcome`.

This is what every backend calls on its worker side (a spawned process, a Ray task or the driver itself). The job
function has the signature ``run_job(spec: dict, out_dir: Path) -> dict`` and must put its artefacts in place (written
atomically) before returning its JSON-able record.

A job reports its progress step by step with :func:`report_steps` (an attack passes :func:`attack_step_callback` as
its ``callback``); :func:`execute` forwards each report to the backend's ``step_sink`` as a :class:`StepReport`, and
the backend to the driver's progress bar. Outside a sweep (no sink) reporting is a no-op.
"""

from __future__ import annotations

import json
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, Optional

from meshadv.experiments.spec import canonical, resolve_job

__all__ = ["Outcome", "StepReport", "attack_step_callback", "execute", "report_steps", "set_thread_limits"]


@dataclass(frozen=True)
class StepReport:
    """A job's progress, sent from its worker to the driver while it runs.

    Attributes:
        job_id: the job.
        done: optimiser steps this attempt has run so far.
        planned: the most steps it can run (``None``: unknown); early stopping ends a job before.
    """

    job_id: str
    done: int
    planned: Optional[int]


#: The current job's reporter (set by :func:`execute` while a job runs in this process with a sink).
_REPORTER: Optional[Callable[[int, Optional[int]], None]] = None


def report_steps(done: int, planned: Optional[int] = None) -> None:
    """Report that the running job has done ``done`` steps of at most ``planned``; a no-op outside a sweep worker."""
    if _REPORTER is not None:
        _REPORTER(int(done), None if planned is None else int(planned))


def attack_step_callback(info: Any) -> None:
    """An attack ``callback`` that reports every step (``StepInfo.total_step`` of ``rounds x steps``)."""
    report_steps(info.total_step, info.rounds * info.steps)

@dataclass(frozen=True)
class Outcome:
    """What came back from one attempt of one job.

    Attributes:
        job_id: the job.
        ok: ``True`` when the job function returned a record.
        record: the JSON-able record (``None`` when not ok).
        error: the traceback or crash reason (``None`` when ok).
        seconds: wall time of the attempt.
        artifacts: the job folder's files (relative path -> bytes) when the job ran away from the driver's file
            system and its artefacts travel back with the outcome (:mod:`meshadv.experiments.artifacts`).
        location: where the artefacts were uploaded (a URL) instead; ``None`` when they are in the job's folder.
    """

    job_id: str
    ok: bool
    record: Optional[Dict[str, Any]]
    error: Optional[str]
    seconds: float
    artifacts: Optional[Dict[str, bytes]] = None
    location: Optional[str] = None


def set_thread_limits(threads: int) -> None:
    """Limit the intra-op threads of this process (OpenMP/MKL/BLAS, rayon, and torch when already imported), with
    idle OpenMP threads sleeping rather than spinning (:func:`meshadv.threads.apply_threads`).

    Args:
        threads: threads per job (>= 1), so that parallel jobs do not oversubscribe the cores.
    """
    from meshadv.threads import apply_threads

    apply_threads(threads)


def execute(job_ref: str, job_id: str, spec: Dict[str, Any], out_dir: str, threads: int = 0,
            step_sink: Optional[Callable[[StepReport], None]] = None) -> Outcome:
    """Run one job and never raise: exceptions become a failed :class:`Outcome` carrying the traceback.

    Args:
        job_ref: ``"package.module:function"`` of the job function.
        job_id: the job's id (echoed in the outcome).
        spec: the job spec.
        out_dir: the job's artefact folder (created here).
        threads: threads per job (0 leaves the process default).
        step_sink: receives a :class:`StepReport` whenever the job calls :func:`report_steps` (an exception it
            raises fails the job); ``None``: reports are dropped.

    Returns:
        The outcome.
    """
    global _REPORTER
    start = time.perf_counter()
    previous = _REPORTER
    if step_sink is not None:
        def _reporter(done: int, planned: Optional[int]) -> None:
            step_sink(StepReport(job_id, done, planned))

        _REPORTER = _reporter
    try:
        if threads:
            set_thread_limits(threads)
        fn = resolve_job(job_ref)
        path = Path(out_dir)
        path.mkdir(parents=True, exist_ok=True)
        record = fn(spec, path)
        if not isinstance(record, dict):
            raise TypeError(f"job function {job_ref} returned {type(record).__name__}, expected a dict record")
        record = canonical(record)
        json.dumps(record)
        return Outcome(job_id, True, record, None, time.perf_counter() - start)
    except Exception:  # noqa: BLE001 - a job's failure of any kind is recorded, never propagated
        return Outcome(job_id, False, None, traceback.format_exc(), time.perf_counter() - start)
    finally:
        _REPORTER = previous
