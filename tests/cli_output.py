"""Reading a typer/rich CLI's output in tests."""

from __future__ import annotations

import re


def unwrapped(output: str) -> str:
    """``output`` with rich's panel borders and line wrapping removed (messages wrap when tmp paths are long)."""
    return " ".join(re.sub(r"[│╭╮╰╯─]", " ", output).split())
