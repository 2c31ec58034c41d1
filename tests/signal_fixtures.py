"""Stop a real ``meshadv`` subprocess with SIGTERM once it has reached a given point (the interrupt tests)."""

from __future__ import annotations

import signal
import subprocess
import time
from typing import Callable, Tuple


def terminate_when(proc: subprocess.Popen, ready: Callable[[], bool], *, timeout: float = 120.0,
                   exit_timeout: float = 120.0, poll: float = 0.05) -> Tuple[str, str]:
    """Poll ``ready()`` while ``proc`` runs; once it holds, send SIGTERM and return ``(stdout, stderr)`` after
    ``proc`` has exited (``""`` for a stream not piped). ``proc`` is killed if anything goes wrong.

    Raises:
        AssertionError: ``proc`` exited, or ``timeout`` seconds passed, before ``ready()`` held.
    """
    try:
        deadline = time.monotonic() + timeout
        while True:
            if proc.poll() is not None:
                out, err = proc.communicate()
                raise AssertionError(f"the process exited ({proc.returncode}) before it could be interrupted: "
                                     f"{(err or out or '')[-2000:]}")
            if ready():
                break
            if time.monotonic() > deadline:
                raise AssertionError(f"the process did not reach the point to interrupt within {timeout} s")
            time.sleep(poll)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=exit_timeout)
        return out or "", err or ""
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
