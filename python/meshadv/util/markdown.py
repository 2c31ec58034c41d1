"""Markdown tables.

Example:
    >>> print(markdown_table(["a", "b"], [[1, "x"], [2.5, None]]))
    | a | b |
    |---|---|
    | 1 | x |
    | 2.5 | – |
"""

from __future__ import annotations

from typing import Any, Sequence

__all__ = ["markdown_table"]


def _cell(value: Any) -> str:
    return "–" if value is None else str(value).replace("|", "\\|")


def markdown_table(header: Sequence[Any], rows: Sequence[Sequence[Any]]) -> str:
    """A Markdown table (no trailing newline); ``None`` cells print as ``–``, ``|`` inside cells is escaped.

    Raises:
        ValueError: a row with another number of cells than the header.
    """
    lines = ["| " + " | ".join(_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        if len(row) != len(header):
            raise ValueError(f"row {list(row)!r} has {len(row)} cells, the header {len(header)}")
        lines.append("| " + " | ".join(_cell(c) for c in row) + " |")
    return "\n".join(lines)
