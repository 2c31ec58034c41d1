"""Thread policy: CPU thread pools that cooperate with each other and with other programs on the machine.

meshadv runs two thread pools one after the other in every attack step: the Rust renderer's rayon pool and torch's
intra-op OpenMP pool (the victim). By default GNU OpenMP keeps its threads *spinning* after each parallel region;
on a machine where other programs also want the cores, a spinning or descheduled thread stalls every barrier, and
a victim call can take tens of times longer than on one thread. This module:

- sets ``OMP_WAIT_POLICY=PASSIVE`` (GNU OpenMP) and ``KMP_BLOCKTIME=0`` (Intel OpenMP) so idle OpenMP threads sleep
  instead of spinning. These are read once, when torch loads its OpenMP runtime: they must be set **before
  ``import torch``**. The ``meshadv`` command does so first thing; in your own Python code call
  :func:`prepare_environment` (or export the two variables) before importing torch;
- gives both pools the same size, ``--threads N`` (default: the CPUs this process may run on), through
  ``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS`` / ``OPENBLAS_NUM_THREADS`` / ``RAYON_NUM_THREADS`` (read when each pool
  starts) and ``torch.set_num_threads`` (effective at once). The renderer's ``num_threads=0`` means rayon's global
  pool, sized by ``RAYON_NUM_THREADS``.

Determinism: the renderer's results are bit-identical for any thread count, but torch's CPU kernels (convolutions
among them) split their reductions by thread count, so logits and gradients differ in the last bits between thread
counts and an attack's trajectory can drift apart over many steps. The same ``--seed`` and the same ``--threads``
on the same machine and torch build reproduce a run exactly; the default thread count depends only on the CPUs
available to the process, never on the current load.

Imports nothing of meshadv (a leaf module) and does not import torch.

Example:
    >>> from meshadv import threads
    >>> threads.prepare_environment()   # before `import torch`
    >>> n = threads.apply_threads(2)    # torch and the renderer on 2 threads
"""

from __future__ import annotations

import os
import sys
from typing import Optional

from meshadv._validate import MAX_THREADS, positive_int

__all__ = [
    "THREADS_ENV_VAR",
    "THREAD_COUNT_VARS",
    "WAIT_POLICY_VARS",
    "available_cpus",
    "default_threads",
    "prepare_environment",
    "apply_threads",
]

#: Environment variable giving the default thread count (what ``--threads`` overrides).
THREADS_ENV_VAR = "MESHADV_THREADS"
#: Variables that size the OpenMP, MKL, OpenBLAS and rayon pools when each starts.
THREAD_COUNT_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "RAYON_NUM_THREADS")
#: Variables that make idle OpenMP threads sleep instead of spin (GNU and Intel runtimes); read when torch loads.
WAIT_POLICY_VARS = {"OMP_WAIT_POLICY": "PASSIVE", "KMP_BLOCKTIME": "0"}


def available_cpus() -> int:
    """The number of CPUs this process may run on (its affinity mask, else ``os.cpu_count()``), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def default_threads() -> int:
    """The default thread count: ``$MESHADV_THREADS`` when set, else :func:`available_cpus`.

    Raises:
        ValueError: ``$MESHADV_THREADS`` is not an integer >= 1.
    """
    text = os.environ.get(THREADS_ENV_VAR, "").strip()
    if not text:
        return available_cpus()
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or value < 1:
        raise ValueError(f"{THREADS_ENV_VAR} must be an integer >= 1, got {text!r}")
    return value


def prepare_environment(threads: Optional[int] = None) -> int:
    """Set the OpenMP wait policy and the pools' sizes in the environment; call it before ``import torch``.

    The wait-policy variables are only set where the user has not set them. The thread-count variables are set
    to ``threads`` when it is given, else filled in (where unset) with :func:`default_threads`.

    Args:
        threads: threads per pool (>= 1), or ``None`` for the default.

    Returns:
        The thread count written to the environment.

    Raises:
        TypeError: ``threads`` is not an integer.
        ValueError: ``threads`` is not in ``[1, MAX_THREADS]``.
    """
    count = default_threads() if threads is None else positive_int("threads", threads, high=MAX_THREADS)
    for var, value in WAIT_POLICY_VARS.items():
        os.environ.setdefault(var, value)
    for var in THREAD_COUNT_VARS:
        if threads is None:
            os.environ.setdefault(var, str(count))
        else:
            os.environ[var] = str(count)
    return count


def apply_threads(threads: Optional[int] = None) -> int:
    """Size torch's intra-op pool and the renderer's pool to ``threads`` (default :func:`default_threads`).

    Sets the environment as :func:`prepare_environment` does and calls ``torch.set_num_threads`` when torch is
    imported (the wait policy only takes effect if torch was not imported yet). The renderer's default pool reads
    ``RAYON_NUM_THREADS`` when it starts, i.e. at the first render of the process.

    Args:
        threads: threads per pool (>= 1), or ``None`` for the default.

    Returns:
        The thread count in use.

    Raises:
        TypeError: ``threads`` is not an integer.
        ValueError: ``threads`` is not in ``[1, MAX_THREADS]``.
    """
    count = prepare_environment(threads)
    if threads is None:
        # The environment may already hold a count (the user's OMP_NUM_THREADS): torch should agree with it.
        try:
            count = max(1, int(os.environ["OMP_NUM_THREADS"]))
        except ValueError:
            pass
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(count)
    return count
