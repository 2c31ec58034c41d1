"""Transfer cases: the adversarial meshes of a finished sweep with the views they were attacked under
(:func:`cases_from_store`), and the readable file stem of their renders (:func:`case_name`)."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Collection, Optional, Union

from meshadv import _validate

__all__ = ["TransferCase", "case_name", "cases_from_store"]


@dataclass(frozen=True)
class TransferCase:
    """One adversarial mesh to transfer, with the views it was attacked under.

    Attributes:
        case_id: identifier (the sweep job id, or any string).
        mesh: the adversarial ``meshadv.mesh.Mesh``.
        views: ``ViewSet.to_records()`` records of the views (camera + lights).
        victim: victim name (``meshadv.victims.load_victim``).
        true_class: the class of the benign object (PASCAL3D+ name or ImageNet spec).
        target: the target class of a targeted attack, or None for an untargeted one.
        perturbation: ``"shape"`` or ``"texture"``.
        image_size: (H, W) of the renders.
        background: RGB background of the renders.
        benign_correct: whether the victim classified the benign render correctly (from the sweep), if known.
        antialias: meshadv's supersampling factor for the reference render (the attack's own, so that
            ``success_meshadv`` is the attack's success).
        name: file stem of the case's saved renders (``<name>_v<view>.png``); ``""``: the ``case_id``.
        benign_mesh: the benign mesh the attack started from, rendered by Mitsuba too as the control of untargeted
            transfer (:mod:`meshadv.transfer.benign_control`); ``None``: no control (the rows say so).
    """

    case_id: str
    mesh: Any
    views: tuple[dict[str, Any], ...]
    victim: str
    true_class: str
    target: Optional[str] = None
    perturbation: str = ""
    image_size: tuple[int, int] = (224, 224)
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    benign_correct: Optional[bool] = None
    antialias: int = 1
    name: str = ""
    benign_mesh: Any = None

    def __post_init__(self) -> None:
        if not self.views:
            raise ValueError("views must hold at least one view record")
        object.__setattr__(self, "views", tuple(self.views))
        size = self.image_size
        size = (int(size), int(size)) if isinstance(size, (int, float)) else (int(size[0]), int(size[1]))
        object.__setattr__(self, "image_size", size)


def _slug(text: str) -> str:
    """``text`` as a file-name part: runs of characters other than letters, digits, ``.``, ``_`` and ``-`` become
    ``-`` (``"studio couch"`` -> ``"studio-couch"``)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "-", str(text)).strip("-.") or "x"


def case_name(spec: dict[str, Any], job_id: str) -> str:
    """A readable, unique file stem for the renders of a sweep job:
    ``<class>_c<configuration>_to_<target>_<perturbation>_<victim>_<job id[:8]>`` (``untargeted`` without a target;
    the short id keeps names unique).

    Example:
        >>> case_name({"source_class": "aeroplane", "config_index": 0, "target": "bicycle",
        ...            "perturbation": "shape", "victim": "efficientnet_lite0"}, "4bdd3c57b6a0d378")
        'aeroplane_c0_to_bicycle_shape_efficientnet_lite0_4bdd3c57'
    """
    source = spec.get("source_class") or spec.get("mesh", {}).get("class") or "object"
    target = spec.get("target") or "untargeted"
    parts = [_slug(source), f"c{spec.get('config_index', 0)}", "to", _slug(target),
             _slug(spec.get("perturbation") or "attack"), _slug(spec.get("victim") or "victim"), _slug(job_id[:8])]
    return "_".join(parts)


def cases_from_store(
    db_path: Union[str, Path], *, limit: Optional[int] = None, only_successful: bool = True,
    skip: Collection[str] = (), artifact_root: Optional[Union[str, Path]] = None, regenerate: bool = True,
) -> list[TransferCase]:
    """Collect the adversarial meshes of a finished sweep (single-view attack jobs) as transfer cases.

    Reads the ``jobs`` table of the sweep database (``meshadv.experiments.ResultStore``); for each done job, the
    adversarial mesh ``adversarial.ply`` and the views of its ``result.json`` in the job's folder. A job whose folder
    is missing (the database was moved to another machine, or the sweep ran on a cluster) is regenerated from its
    stored spec and seed into ``<artifact_root>/jobs/..`` (:func:`meshadv.experiments.regenerate.ensure_artifacts`).

    Args:
        db_path: the sweep's ``results.db``.
        limit: at most this many cases.
        only_successful: keep only attacks that succeeded in meshadv (as the paper does).
        skip: job ids to leave out (e.g. those already transferred). Retries of stages the sweep's config no longer
            has are left out too (:func:`meshadv.experiments.retries.superseded_retries`).
        artifact_root: root of regenerated artefact folders (default: the database's folder).
        regenerate: regenerate missing artefacts (else such jobs are left out).

    Returns:
        The cases, in database order.

    Raises:
        FileNotFoundError: ``db_path`` does not exist.
        TypeError: ``limit`` is not an int (or None), or ``skip`` is a single string.
        ValueError: ``limit < 1``.
    """
    from meshadv.experiments import ResultStore
    from meshadv.experiments.retries import superseded_retries
    from meshadv.experiments.sweep_file import stored_retry_stages

    if not Path(db_path).is_file():
        raise FileNotFoundError(f"db_path {db_path} does not exist")
    if limit is not None:
        _validate.positive_int("limit", limit)  # 0 used to give one case
    if isinstance(skip, (str, bytes)):
        raise TypeError("skip must be a collection of job ids, got a single string")
    cases: list[TransferCase] = []
    with ResultStore(db_path, read_only=True) as store:  # only read: a kill leaves no "open" mark behind
        rows = store.rows()
        stages = stored_retry_stages(store.get_meta("config_text"))
    skip = {*skip, *superseded_retries(stages, rows)}  # retries of stages the config no longer has
    rows = [row for row in rows if row.state == "done"]
    for row in rows:
        if not _wanted(row, skip, only_successful):
            continue
        out = Path(row.out_dir or "")
        if regenerate and not (out / "result.json").is_file():
            out = _regenerated(db_path, row, artifact_root)
        case = _case_from_job(row, out)
        if case is None:
            continue
        cases.append(case)
        if limit is not None and len(cases) >= limit:
            break
    return cases


def _wanted(row: Any, skip: Collection[str], only_successful: bool) -> bool:
    """Whether a done job of the sweep is a case: a single-view attack, not skipped, not in ``skip``, and
    successful in meshadv when ``only_successful``."""
    spec, record = row.spec, row.record or {}
    if spec.get("kind", "single") != "single" or record.get("skipped") or row.job_id in skip:
        return False
    return not (only_successful and not record.get("success"))


def _regenerated(db_path: Union[str, Path], row: Any, artifact_root: Optional[Union[str, Path]]) -> Path:
    """The job's artefact folder regenerated from its stored spec and seed under ``artifact_root`` (default: the
    database's folder)."""
    from meshadv.experiments.regenerate import ensure_artifacts

    root = Path(artifact_root) if artifact_root is not None else Path(db_path).parent
    return ensure_artifacts(db_path, row.job_id, root, row.out_dir)


def _case_from_job(row: Any, out: Path) -> Optional[TransferCase]:
    """The case of a done job from its folder ``out`` (``result.json`` and the adversarial mesh; the benign mesh from
    the job's spec), or None when the folder lacks them or the result has no views."""
    from meshadv.mesh import load_mesh

    result_path = out / "result.json"
    if not result_path.is_file():
        return None
    result = json.loads(result_path.read_text())
    meshes = result.get("meshes") or [["adversarial.ply", "adversarial.obj"]]
    mesh_path = out / meshes[0][0]
    if not mesh_path.is_file() or not result.get("views"):
        return None
    spec, record = row.spec, row.record or {}
    target = spec.get("target")
    if target in ("", "untargeted", None):
        target = None
    size = result.get("config", {}).get("image_size") or spec.get("image_size") or 224
    return TransferCase(
        case_id=row.job_id,
        mesh=load_mesh(mesh_path),
        views=tuple(result["views"]),
        victim=str(spec.get("victim", result.get("victim"))),
        true_class=str(spec.get("source_class", spec.get("mesh", {}).get("class", ""))),
        target=None if target is None else str(target),
        perturbation=str(spec.get("perturbation", result.get("perturbation", ""))),
        image_size=tuple(size) if isinstance(size, (list, tuple)) else (int(size), int(size)),
        benign_correct=None if record.get("benign_correct") is None else bool(record["benign_correct"]),
        antialias=int(result.get("config", {}).get("antialias") or 1),
        name=case_name(spec, row.job_id),
        benign_mesh=_benign_of_job(spec),
    )


def _benign_of_job(spec: dict[str, Any]) -> Any:
    """The benign mesh of a job (:func:`~meshadv.transfer.benign_control.benign_mesh_of_job`), or ``None`` when its
    spec's mesh cannot be loaded here (e.g. the shared data is missing): its rows then carry no benign control and
    the tables leave them out of the untargeted count."""
    from meshadv.transfer.benign_control import benign_mesh_of_job

    try:
        return benign_mesh_of_job(spec)
    except (ValueError, FileNotFoundError, KeyError):
        return None
