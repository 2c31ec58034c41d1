"""The pass-rate table of a rendering set: per class, how often each victim (and all together) got a candidate right."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from meshadv.util.markdown import markdown_table

__all__ = ["pass_rate_table"]


def pass_rate_table(doc: Mapping[str, Any], *, markdown: bool = False) -> str:
    """A table of the pass rate per class and victim (and of all victims together).

    Args:
        doc: a rendering-set document.
        markdown: a Markdown table instead of aligned plain text.
    """
    victims = list(doc["config"]["victims"])
    header = ["class", "kept", "tried", *victims, "all"]
    rows = [header]
    for cls, stats in doc["classes"].items():
        rates = stats["pass_rate"]
        rows.append(
            [cls, str(stats["kept"]), str(stats["tried"])]
            + ["-" if rates[k] is None else f"{100 * rates[k]:.1f}%" for k in [*victims, "all"]]
        )
    if markdown:
        return markdown_table(header, rows[1:])
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    return "\n".join("  ".join(cell.ljust(w) for cell, w in zip(row, widths)) for row in rows)
