"""The rendering-set file: its format and version, the packaged set, reading one, and a new empty document."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Union

from meshadv.util.json_file import read_json

__all__ = [
    "FORMAT",
    "VERSION",
    "PACKAGED_FILE",
    "PathLike",
    "content_identity",
    "load_rendering_set",
    "new_document",
    "packaged_rendering_set_path",
]

FORMAT = "meshadv-rendering-set"
VERSION = 1
#: File name of the rendering set shipped in ``meshadv/datasets/data`` (EfficientNet-Lite0 and -Lite2, 72 per class).
PACKAGED_FILE = "pascal3d_renderings_v1.json"

#: A file path as a string or a :class:`~pathlib.Path`.
PathLike = Union[str, Path]


def packaged_rendering_set_path() -> Path:
    """Path of the rendering set shipped with meshadv (its mesh paths are relative to the shared data folder).

    Raises:
        FileNotFoundError: this installation does not include it.
    """
    from importlib import resources

    path = Path(str(resources.files("meshadv.datasets").joinpath("data").joinpath(PACKAGED_FILE)))
    if not path.is_file():
        raise FileNotFoundError(f"the packaged rendering set {path} is missing from this installation")
    return path


def load_rendering_set(path: PathLike) -> dict[str, Any]:
    """Read a rendering-set file and check its format and version.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: not a rendering-set file, or an unsupported version.
    """
    doc = read_json(Path(path), "path")
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"path {path} is not a {FORMAT} file")
    if doc.get("version") != VERSION:
        raise ValueError(f"path {path} has version {doc.get('version')}, this meshadv reads version {VERSION}")
    return doc


def content_identity(config_json: Mapping[str, Any]) -> dict[str, Any]:
    """The part of a set's configuration that decides its content (everything but the candidate budget)."""
    sampling = {k: v for k, v in config_json["sampling"].items() if k != "max_candidates_per_class"}
    return {**config_json, "sampling": sampling}


def new_document(config_json: dict[str, Any], classes: Sequence[str], victim_names: Sequence[str]) -> dict[str, Any]:
    """An empty, incomplete rendering-set document: no candidate tried yet for any of ``classes``.

    Args:
        config_json: the set's ``"config"`` entry.
        classes: the classes of the set, in the order the file lists them.
        victim_names: the victims' names (each gets a pass count, as does ``"all"``).
    """
    zero = {name: 0 for name in [*victim_names, "all"]}
    return {
        "format": FORMAT,
        "version": VERSION,
        "complete": False,
        "config": config_json,
        "classes": {
            c: {
                "next_candidate": 0,
                "tried": 0,
                "kept": 0,
                "passed": dict(zero),
                "pass_rate": {k: None for k in zero},
                "exhausted": False,
            }
            for c in classes
        },
        "renderings": [],
    }
