"""The ``--cap`` option of the attack commands: its help text (without importing torch) and its parsing.

:data:`CAP_HELP` spells out :data:`meshadv.perceptibility.DEFAULT_CAP` for ``--help`` (a test keeps the two equal).
"""

from __future__ import annotations

from typing import Any, Optional

__all__ = ["CAP_HELP", "parse_cap"]

#: :data:`meshadv.perceptibility.DEFAULT_CAP` in words, for help texts.
CAP_HELP = "largest vertex move 2% of the bounding-box diagonal, 95% of the surface turning by at most 25 degrees, " \
           "95% of the edge length stretched or squeezed by at most 8.5%, " \
           "no edge's length changed by more than 100% (an edge shorter than 0.25% of the diagonal: by more than " \
           "0.25% of the diagonal), " \
           "95% of the surface changing colour by at most 0.05"


def parse_cap(text: str) -> Optional[Any]:
    """The ``PerceptibilityCap`` of a ``--cap`` value (``None`` for ``none``).

    Raises:
        ValueError: a value :meth:`~meshadv.perceptibility.PerceptibilityCap.parse` refuses.
    """
    from meshadv.perceptibility import as_cap

    try:
        return as_cap(str(text))
    except ValueError as exc:
        raise ValueError(f"--cap: {exc}") from None
