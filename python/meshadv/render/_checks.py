"""Small argument checks shared by the render modules."""

from __future__ import annotations

from typing import Any


def require_instance(value: Any, cls: type, name: str) -> None:
    """Raise ``ValueError`` naming ``name`` when ``value`` is not an instance of ``cls``.

    The project rule is that bad user input raises ``ValueError`` naming the argument (also for wrong types).
    """
    if not isinstance(value, cls):
        raise ValueError(f"{name} must be a {cls.__name__}, got {type(value).__name__}")  # noqa: TRY004
