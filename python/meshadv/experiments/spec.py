"""Job specifications: canonical JSON form and the deterministic job id.

A *job* is a plain JSON-able ``dict`` (strings, numbers, booleans, lists, dicts). Its id is the first 16 hex digits of
the SHA-256 of its canonical JSON (sorted keys, no spaces, floats rounded to 9 significant digits), so the same job
expanded twice, on any machine, gets the same id and is never run twice.

Example:
    >>> job_id({"victim": "efficientnet_lite0", "seed": 0}) == job_id({"seed": 0, "victim": "efficientnet_lite0"})
    True
"""

from __future__ import annotations

import hashlib
import json
import math
from typing import Any, Callable, Dict, Union

__all__ = ["canonical", "canonical_json", "job_id", "job_ref", "resolve_job"]

JobFn = Callable[[Dict[str, Any], Any], Dict[str, Any]]


def canonical(value: Any) -> Any:
    """Return ``value`` as canonical JSON-able data (tuples to lists, floats rounded, keys as strings).

    Args:
        value: nested dicts / lists / tuples of str, int, float, bool or None.

    Returns:
        An equal structure made only of dict, list, str, int, float, bool and None.

    Raises:
        ValueError: a value is not JSON-able (e.g. a tensor or an object) or a float is not finite.
    """
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"job spec values must be finite, got {value!r}")
        return float(f"{value:.9g}")
    if isinstance(value, dict):
        return {str(k): canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [canonical(v) for v in value]
    if hasattr(value, "item") and callable(value.item):  # numpy / torch scalars
        return canonical(value.item())
    raise ValueError(f"job spec values must be JSON-able, got {type(value).__name__}: {value!r}")


def canonical_json(spec: Dict[str, Any]) -> str:
    """Serialise a job spec canonically (sorted keys, compact separators, rounded floats).

    Args:
        spec: the job spec.

    Returns:
        The canonical JSON text.
    """
    if not isinstance(spec, dict):
        raise ValueError(f"spec must be a dict, got {type(spec).__name__}")
    return json.dumps(canonical(spec), sort_keys=True, separators=(",", ":"))


def job_id(spec: Dict[str, Any]) -> str:
    """Deterministic id of a job: 16 hex digits of the SHA-256 of its canonical JSON.

    Args:
        spec: the job spec.

    Returns:
        The job id.
    """
    return hashlib.sha256(canonical_json(spec).encode("utf-8")).hexdigest()[:16]


def job_ref(job: Union[str, JobFn]) -> str:
    """Return the importable reference ``"package.module:function"`` of a job function.

    Jobs run in other processes (spawned workers, Ray workers), so the function travels by name.

    Args:
        job: a reference string or a module-level function.

    Returns:
        The reference string.

    Raises:
        ValueError: ``job`` is a lambda, a nested function or a malformed reference.
    """
    if isinstance(job, str):
        module, sep, name = job.partition(":")
        if not sep or not module or not name:
            raise ValueError(f"job must look like 'package.module:function', got {job!r}")
        return job
    qualname = getattr(job, "__qualname__", "")
    module = getattr(job, "__module__", None)
    if not callable(job) or not module or not qualname or "<" in qualname or module == "__main__":
        raise ValueError(f"job must be a module-level function importable by worker processes, got {job!r}")
    return f"{module}:{qualname}"


def resolve_job(ref: str) -> JobFn:
    """Import the job function named by ``ref`` (``"package.module:function"``).

    Args:
        ref: the reference.

    Returns:
        The function.

    Raises:
        ValueError: the module or function does not exist.
    """
    import importlib

    module_name, _, name = job_ref(ref).partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise ValueError(f"job {ref!r}: cannot import module {module_name!r}: {err}") from err
    obj: Any = module
    for part in name.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            raise ValueError(f"job {ref!r}: module {module_name!r} has no attribute {name!r}")
    if not callable(obj):
        raise ValueError(f"job {ref!r} is not callable")
    return obj
