"""The sweep progress bars (tqdm, on stderr): jobs done out of total with successes, failures, rate and ETA, and
under it the optimiser steps the jobs have run out of the most they can run, fed step by step by the workers'
:class:`~meshadv.experiments.worker.StepReport` objects.

The step total is the sum of the runnable jobs' planned steps (``run_sweep``'s ``planned_steps``; unknown: the bar
counts without a total). A job that stops early (early stopping, a skipped benign render, a failure given up on)
adds the steps it will not run when it finishes, so the bar ends full; a failed attempt that will be retried adds
the steps it ran to the total, since they run again. Jobs whose backend does not report steps (Ray) move the bar
when they finish. Written to a file or pipe rather than a terminal, the bars redraw at most every
:data:`LOG_INTERVAL` seconds, so a logged sweep's log stays short.
"""

from __future__ import annotations

import sys
import threading
from typing import Any, Dict, Mapping, Optional

__all__ = ["Progress", "LOG_INTERVAL"]

#: Seconds between redraws when stderr is not a terminal (a log file).
LOG_INTERVAL = 30.0


class Progress:
    """Progress bars over the jobs of a sweep and their steps; the counts are kept even when disabled.

    Args:
        total: jobs in the sweep.
        done: jobs already done (a resumed sweep starts there).
        successes: successful jobs among those done.
        failed: jobs that exhausted their attempts.
        enabled: draw the bars.
        planned: the most steps of each job still to run (``None`` where unknown); the step bar's total is their sum
            when every one is known. ``None``: no plan, the bar counts without a total.

    Attributes:
        steps_done: steps counted so far (reported, plus those finished jobs did not need).
        steps_total: the step bar's total (``None``: unknown).
    """

    def __init__(self, total: int, done: int = 0, successes: int = 0, failed: int = 0, enabled: bool = True,
                 planned: Optional[Mapping[str, Optional[int]]] = None) -> None:
        self.total = total
        self.done = done
        self.successes = successes
        self.failed = failed
        self._planned: Dict[str, Optional[int]] = dict(planned or {})
        known = [n for n in self._planned.values() if n is not None]
        self.steps_total: Optional[int] = (sum(known) if planned is not None and len(known) == len(self._planned)
                                           else None)
        self.steps_done = 0
        self._seen: Dict[str, int] = {}
        self._lock = threading.Lock()
        self._bar: Optional[Any] = None
        self._steps: Optional[Any] = None
        if enabled:
            from tqdm.auto import tqdm

            interval = 0.1 if sys.stderr.isatty() else LOG_INTERVAL
            self._bar = tqdm(total=total, initial=done + failed, unit="job", dynamic_ncols=True, desc="sweep",
                             position=0, mininterval=interval)
            self._steps = tqdm(total=self.steps_total, unit="step", dynamic_ncols=True, desc="steps", position=1,
                               mininterval=interval)
            self._refresh()

    def _refresh(self) -> None:
        if self._bar is not None:
            self._bar.set_postfix(success=self.successes, failed=self.failed, refresh=False)

    def _add_steps(self, count: int) -> None:
        """Count ``count`` more steps, growing the total when the counts pass it (lock held)."""
        if count <= 0:
            return
        self.steps_done += count
        grow = self.steps_total is not None and self.steps_done > self.steps_total
        if grow:
            self.steps_total = self.steps_done
        if self._steps is not None:
            if grow:
                self._steps.total = self.steps_total
            self._steps.update(count)

    def step(self, report: Any) -> None:
        """Count a running job's :class:`~meshadv.experiments.worker.StepReport` (thread-safe)."""
        with self._lock:
            if self._planned.get(report.job_id) is None and report.planned is not None:
                self._planned[report.job_id] = report.planned
            seen = self._seen.get(report.job_id, 0)
            self._seen[report.job_id] = max(seen, report.done)
            self._add_steps(report.done - seen)

    def job_finished(self, job_id: str, retry: bool = False) -> None:
        """A job's attempt ended: with ``retry`` its steps run again (the total grows by them), else the steps it
        did not run are counted (thread-safe)."""
        with self._lock:
            seen = self._seen.pop(job_id, 0)
            if retry:
                if self.steps_total is not None and seen:
                    self.steps_total += seen
                    if self._steps is not None:
                        self._steps.total = self.steps_total
                        self._steps.refresh()
                return
            self._add_steps((self._planned.get(job_id) or 0) - seen)

    def update(self, done: int = 0, successes: int = 0, failed: int = 0) -> None:
        """Count finished jobs (done or given up on) and successes."""
        self.done += done
        self.successes += successes
        self.failed += failed
        if self._bar is not None:
            self._refresh()
            self._bar.update(done + failed)

    def close(self) -> None:
        """Close the bars."""
        for bar in (self._steps, self._bar):
            if bar is not None:
                bar.close()
        self._bar = self._steps = None
