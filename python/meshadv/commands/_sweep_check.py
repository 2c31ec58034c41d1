"""``meshadv sweep --dry-run`` checks: what would make every job fail, found before any job runs.

Checks each distinct victim name, mesh and target class of the expanded jobs (misspelt config keys are refused by
``meshadv.experiments.config`` itself). Nothing heavy is loaded: no weights, no meshes, only names and paths.
"""

from __future__ import annotations

from typing import Any, Dict, List, Sequence

__all__ = ["check_jobs"]


def _mesh_problem(mesh: Dict[str, Any]) -> str:
    from pathlib import Path

    from meshadv.data import DATA_ENV_VAR, shared_data_dir
    from meshadv.mesh.shapes import BUILTIN_SHAPES

    source = mesh.get("source")
    if source == "builtin":
        name = mesh.get("name")
        return "" if name in BUILTIN_SHAPES else f"built-in mesh {name!r} is not one of {', '.join(BUILTIN_SHAPES)}"
    if source == "pascal3d":
        root = shared_data_dir()
        if root is None:
            return (f"mesh {mesh.get('path')}: the shared data folder (PASCAL3D+ meshes) is not here; set "
                    f"{DATA_ENV_VAR} or place it at ../shared/data beside the checkout")
        path = root / str(mesh.get("path"))
        return "" if path.is_file() else f"mesh file {path} does not exist"
    if source == "files":
        path = Path(str(mesh.get("path")))
        return "" if path.is_file() else f"mesh file {path} does not exist"
    return f"mesh.source must be pascal3d, builtin or files, got {source!r}"


def _target_problem(target: Any, detector: bool) -> str:
    from meshadv._validate import suggest
    from meshadv.attacks.criteria import resolve_imagenet_classes
    from meshadv.victims.labels import coco_class_names

    if target is None:
        return ""
    if detector:
        names = [n for n in coco_class_names() if n]
        if str(target) in ("all", *names):
            return ""
        close = suggest(str(target), names)
        return f"{target!r} is not a COCO class" + (f"; did you mean {close!r}?" if close else "")
    try:
        resolve_imagenet_classes(target, "target")
    except ValueError as err:
        return str(err)
    return ""


def check_jobs(jobs: Sequence[Dict[str, Any]]) -> List[str]:
    """One line per problem that would fail jobs (unknown victim, missing mesh file, unknown target); ``[]`` if none.

    Args:
        jobs: expanded job specs (``meshadv.experiments.config.expand_jobs``).
    """
    import json

    from meshadv._validate import suggest
    from meshadv.commands._common import VICTIMS

    detectors = {"ssd_mobilenet_v2_coco", "yolov3"}
    problems: Dict[str, int] = {}

    def note(message: str) -> None:
        problems[message] = problems.get(message, 0) + 1

    seen_meshes: Dict[str, str] = {}
    seen_targets: Dict[tuple, str] = {}
    for job in jobs:
        victim = job.get("victim")
        if victim not in VICTIMS:
            close = suggest(str(victim), VICTIMS)
            note(f"unknown victim {victim!r}" + (f"; did you mean {close!r}?" if close else "")
                 + f" (victims: {', '.join(VICTIMS)})")
        mesh = job.get("mesh") or {}
        key = json.dumps(mesh, sort_keys=True)
        if key not in seen_meshes:
            seen_meshes[key] = _mesh_problem(mesh)
        if seen_meshes[key]:
            note(seen_meshes[key])
        tkey = (str(job.get("target")), victim in detectors)
        if tkey not in seen_targets:
            seen_targets[tkey] = _target_problem(job.get("target"), victim in detectors)
        if seen_targets[tkey]:
            note(f"target: {seen_targets[tkey]}")
    return [f"{message} ({count} job{'s' if count > 1 else ''})" for message, count in problems.items()]
