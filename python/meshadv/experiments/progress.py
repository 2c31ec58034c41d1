"""The sweep progress bar: jobs done out of total, successes, failures, rate and ETA (tqdm, on stderr)."""

from __future__ import annotations

from typing import Optional

__all__ = ["Progress"]


class Progress:
    """A progress bar over the jobs of a sweep; a no-op when disabled.

    Args:
        total: jobs in the sweep.
        done: jobs already done (a resumed sweep starts there).
        successes: successful jobs among those done.
        failed: jobs that exhausted their attempts.
        enabled: draw the bar.
    """

    def __init__(self, total: int, done: int = 0, successes: int = 0, failed: int = 0, enabled: bool = True) -> None:
        self.total = total
        self.done = done
        self.successes = successes
        self.failed = failed
        self._bar: Optional[object] = None
        if enabled:
            from tqdm.auto import tqdm

            self._bar = tqdm(total=total, initial=done + failed, unit="job", dynamic_ncols=True, desc="sweep")
            self._refresh()

    def _refresh(self) -> None:
        if self._bar is not None:
            self._bar.set_postfix(success=self.successes, failed=self.failed, refresh=False)

    def update(self, done: int = 0, successes: int = 0, failed: int = 0) -> None:
        """Count finished jobs (done or given up on) and successes."""
        self.done += done
        self.successes += successes
        self.failed += failed
        if self._bar is not None:
            self._refresh()
            self._bar.update(done + failed)

    def close(self) -> None:
        """Close the bar."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
