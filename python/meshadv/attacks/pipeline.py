"""Pipelined attack steps: a step's targets split into chunks that worker threads render and pass through the
victim concurrently.

An attack step is render forward -> victim forward -> victim input gradient -> render backward, and its images are
independent. With ``step_workers=W`` (``W >= 2``) the step's ``T x V`` images are split into ``W`` contiguous chunks
(:func:`split_images`: ranges of targets, or of one target's views when there are fewer targets than workers); each
worker thread renders its chunk and runs the victim on it, so one chunk's render overlaps another's victim and the
renderer's work no longer adds to the victim's on a machine with as many cores as workers. The autograd graph is cut
at the images and at the victim's output:

1. each worker: ``leaf = params[chunk's targets]`` (a fresh leaf), ``images = render(leaf)``, ``x = images.detach()``
   (requires grad), ``out = victim(x)``;
2. the calling thread concatenates the chunks' ``x`` and (cut) ``out``, computes the criteria, the perceptual and
   distance terms and the update rule's objective, and back-propagates it: that fills the parameters' gradient from
   the perceptual / distance terms and the cotangents of every ``x`` (perceptual terms of images) and ``out``;
3. each worker back-propagates its ``out`` cotangent through the victim into ``x.grad`` and then ``x.grad`` through
   its render into ``leaf.grad``;
4. the calling thread adds each chunk's ``leaf.grad`` into ``params.grad`` in chunk order (rows of one target split
   by views are summed in that order).

So the gradient is the unchunked step's except that the victim sees batches of ``T V / W`` images and runs on
``threads // W`` torch threads: its float rounding may differ in the last bits, as with another ``--threads``; a run
is reproducible for the same ``step_workers`` and thread count (chunks are fixed by the active targets, never by
timing). Each worker sets its own torch thread count (OpenMP's is per thread), the calling thread's is untouched,
and renders on a pool of its own with as many threads (rather than all workers on rayon's global pool, where one
worker's render waited for another's: 7-10% slower steps with 2 workers on 2 cores); the images do not depend on
it. An exception in a worker is re-raised in the
calling thread after every worker has finished its task; Ctrl-C (delivered to the calling thread) waits for the
workers' current tasks and then propagates, so the attack stops between steps as without workers.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import Any, Callable, List, Optional, Sequence, Tuple, TypeVar

import torch

from meshadv.attacks.outputs import cat_outputs, output_tensors, rebuild_output  # re-exported (their old home)

__all__ = ["StepWorkers", "split_chunks", "split_images", "output_tensors", "rebuild_output", "cat_outputs"]

#: How long the calling thread blocks at a time while it waits for the workers. A signal that arrives just before
#: a thread blocks on a lock is only handled once the lock wait returns (CPython checks for pending signals between
#: bytecodes), so an unbounded wait could hold a Ctrl-C until every task finished: measured with the Ctrl-C test's
#: tasks, 23 of 200 interrupts were handled only when the tasks gave up waiting for them.
_POLL_SECONDS = 0.05

_T = TypeVar("_T")
_R = TypeVar("_R")


def split_chunks(count: int, parts: int) -> List[Tuple[int, int]]:
    """``min(parts, count)`` contiguous ``[start, stop)`` ranges covering ``range(count)``, sizes differing by <= 1
    (the larger first).

    Raises:
        ValueError: ``count < 0`` or ``parts < 1``.
    """
    if count < 0 or parts < 1:
        raise ValueError(f"count must be >= 0 and parts >= 1, got count={count}, parts={parts}")
    parts = max(1, min(parts, count))
    base, extra = divmod(count, parts)
    out, start = [], 0
    for i in range(parts):
        stop = start + base + (1 if i < extra else 0)
        out.append((start, stop))
        start = stop
    return out if count else []


def split_images(num_targets: int, num_views: int, parts: int) -> List[List[Tuple[int, int, int, int]]]:
    """The ``num_targets x num_views`` images of a step (mesh-major: image ``k * V + v``) as contiguous chunks, each a
    list of blocks ``(k0, k1, v0, v1)``: targets ``k0..k1-1`` seen from views ``v0..v1-1``, either whole targets
    (every view) or a view range of one target.

    With ``K >= parts`` the chunks are ``parts`` ranges of whole targets (:func:`split_chunks`): each target's
    gradient then comes from one render, as in the serial step, and rounds the same way. With fewer targets than
    parts the ``K * V`` images are split into ``min(parts, K * V)`` ranges of sizes differing by <= 1, cutting
    targets into view ranges (one target with several views is split by views).

    Raises:
        ValueError: a count ``< 1``.
    """
    if num_targets < 1 or num_views < 1 or parts < 1:
        raise ValueError(f"counts must be >= 1, got targets={num_targets}, views={num_views}, parts={parts}")
    if num_targets >= parts:
        return [[(a, b, 0, num_views)] for a, b in split_chunks(num_targets, parts)]
    chunks = []
    for start, stop in split_chunks(num_targets * num_views, parts):
        blocks, pos = [], start
        while pos < stop:
            k, v = divmod(pos, num_views)
            whole = (stop - pos) // num_views if v == 0 else 0
            if whole:
                blocks.append((k, k + whole, 0, num_views))
                pos += whole * num_views
            else:
                end = min(stop, (k + 1) * num_views)
                blocks.append((k, k + 1, v, end - k * num_views))
                pos = end
        chunks.append(blocks)
    return chunks


class _TaskGate:
    """Counts the running tasks of one :meth:`StepWorkers.map` call; once closed, tasks that had not started skip
    their work and :meth:`close_and_wait` returns when the started ones have finished."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._running = 0
        self._closed = False

    def run(self, fn: Callable[[_T], _R], item: _T) -> Optional[_R]:
        """``fn(item)`` unless the gate is closed (then ``None``: the call was abandoned)."""
        with self._cond:
            if self._closed:
                return None
            self._running += 1
        try:
            return fn(item)
        finally:
            with self._cond:
                self._running -= 1
                self._cond.notify_all()

    def close_and_wait(self) -> None:
        """No task starts from now on; wait for the running ones."""
        with self._cond:
            self._closed = True
            while self._running:
                self._cond.wait()


class StepWorkers:
    """``workers`` threads that run the chunks of pipelined attack steps (see the module docstring).

    Args:
        workers: number of threads, ``>= 1``.
        threads: threads of each worker: its torch intra-op threads (set in the worker, where OpenMP keeps it per
            thread) and its renderer threads (a rayon pool of the worker's own, so the workers' renders neither share
            one pool nor queue behind each other: benchmarks/RESULTS.md, "Attack step split").

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, workers: int, threads: int) -> None:
        if workers < 1 or threads < 1:
            raise ValueError(f"workers and threads must be >= 1, got {workers}, {threads}")
        self.workers = int(workers)
        self.threads = int(threads)
        self._main_threads = torch.get_num_threads()
        self._lock = threading.Lock()
        self._pool: Optional[ThreadPoolExecutor] = ThreadPoolExecutor(
            max_workers=self.workers, thread_name_prefix="meshadv-step", initializer=self._init_worker)

    def _init_worker(self) -> None:
        # torch.set_num_threads sets the calling thread's OpenMP count and the process-wide default that threads
        # starting later take; the calling thread's own count and the default are restored in close().
        with self._lock:
            torch.set_num_threads(self.threads)

    def map(self, fn: Callable[[_T], _R], items: Sequence[_T]) -> List[_R]:
        """``[fn(item) for item in items]`` run on the workers; returns in the order of ``items``.

        Every task has finished when this returns or raises: the first exception of a task (in ``items`` order) is
        re-raised here, and an exception of the calling thread itself (``KeyboardInterrupt``) waits for the tasks
        already started, lets the others skip their work and propagates. The calling thread waits in slices of
        ``_POLL_SECONDS``, so a Ctrl-C is handled within that time even while the tasks run.

        Raises:
            RuntimeError: the workers were closed.
        """
        if self._pool is None:
            raise RuntimeError("StepWorkers is closed")
        gate = _TaskGate()
        futures: List[Future] = []
        try:
            for item in items:
                futures.append(self._pool.submit(gate.run, fn, item))
            while wait(futures, timeout=_POLL_SECONDS).not_done:
                pass
        except BaseException:
            # An interrupt can land anywhere here, even inside submit() after a task was queued but before its
            # future came back; the gate, not the futures, knows which tasks started.
            gate.close_and_wait()
            raise
        return [future.result() for future in futures]

    def close(self) -> None:
        """Stop the threads and restore the process-wide torch thread default."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
            torch.set_num_threads(self._main_threads)

    def __enter__(self) -> "StepWorkers":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
