"""Reading a JSON file with errors that name what the file is and where it is.

Example:
    >>> import tempfile, pathlib
    >>> file = pathlib.Path(tempfile.mkdtemp()) / "x.json"
    >>> _ = file.write_text('{"a": 1}')
    >>> read_json(file, "settings file")
    {'a': 1}
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

__all__ = ["read_json"]


def read_json(path: Path, what: str) -> Any:
    """The JSON value stored in the file ``path`` (UTF-8).

    Args:
        path: the file.
        what: how the messages call the file, e.g. ``"assumed-defaults file"`` or an argument's name.

    Raises:
        FileNotFoundError: ``path`` is not a file (``"<what> <path> does not exist"``).
        ValueError: the file is not valid JSON (``"<what> <path> is not JSON: <parser's message>"``).
    """
    if not path.is_file():
        raise FileNotFoundError(f"{what} {path} does not exist")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{what} {path} is not JSON: {exc}") from exc
