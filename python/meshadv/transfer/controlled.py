"""Controlled-parameter transfer: re-render adversarial meshes with Mitsuba 3 under the *same* camera and lights they
were attacked with, and test the victims.

* :func:`cases_from_store`: the adversarial meshes of a finished sweep with their views (:class:`TransferCase`);
  :func:`case_from_attack_folder`: the one of a saved ``meshadv attack`` result.
* :func:`controlled_transfer` renders and scores cases (one :class:`~meshadv.transfer.results.ControlledResult`
  per view); :func:`transfer_case_into` does one case of a database and saves its rows at once (resumable), and
  :func:`transfer_attack_folder` one attack folder.
* Saved renders are named after what they show,
  ``<class>_c<configuration>_to_<target>_<perturbation>_<victim>_<job id's first 8 hex digits>_v<view>.png``
  (:func:`case_name`, :func:`save_images`), and ``index.csv`` in the same folder lists every file with its full job
  id and outcome (:func:`write_image_index`).

Every Mitsuba render runs in a child process (:mod:`meshadv.transfer.mitsuba_process`), so a crash fails one
evaluation, never the sweep.
"""

from __future__ import annotations

import csv
import io
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Collection, Mapping, Optional, Sequence, Union

import torch

from meshadv import _validate
from meshadv.attacks import evaluate
from meshadv.attacks.result import load_result_record
from meshadv.experiments import ResultStore
from meshadv.experiments.config import stored_retry_stages
from meshadv.experiments.retries import superseded_retries
from meshadv.mesh import load_mesh
from meshadv.mesh.surface_mesh import SurfaceMesh
from meshadv.render import RenderSetup, ViewSet
from meshadv.transfer.benign_control import (benign_mesh_of_attack_folder, benign_mesh_of_job, benign_verdicts,
                                             load_saved_mesh)
from meshadv.transfer.mitsuba_process import MitsubaImage, MitsubaRenderError, render_scenes
from meshadv.transfer.mitsuba_spec import MeshObject, SceneSpec, scene_spec
from meshadv.transfer.results import ControlledResult, load_transfer_rows, save_transfer_rows
from meshadv.transfer.scoring import class_names, classifier_criteria, images_tensor, top1_names
from meshadv.util.atomic import write_json_atomic, write_text_atomic
from meshadv.util.png import save_png
from meshadv.victims import load_victim

__all__ = [
    "INDEX_COLUMNS", "TransferCase", "case_from_attack_folder", "case_name", "cases_from_store", "controlled_transfer",
    "evaluate_case", "mitsuba_specs_for_case", "pending_cases", "save_images", "source_class_of_record",
    "transfer_attack_folder",
    "transfer_attack_summary", "transfer_case_into", "write_image_index",
]

#: Columns of the renders' ``index.csv``.
INDEX_COLUMNS = ("file", "job_id", "victim", "true_class", "target", "perturbation", "view", "success_meshadv",
                 "success_mitsuba", "top1_meshadv", "top1_mitsuba")


@dataclass(frozen=True)
class TransferCase:
    """One adversarial mesh to transfer, with the views it was attacked under.

    Attributes:
        case_id: identifier (the sweep job id, or any string).
        mesh: the adversarial ``meshadv.mesh.Mesh``, or a ``SurfaceMesh`` (with its texture or vertex colours and
            the attack's shading) for an attack on one.
        views: ``ViewSet.to_records()`` records of the views (camera + lights).
        victim: victim name (``meshadv.victims.load_victim``).
        true_class: the class of the benign object (PASCAL3D+ name or ImageNet spec); a render is this class when
            the victim's top-1 is in its class group (:func:`~meshadv.attacks.criteria.resolve_true_class`: one
            ImageNet class of a PASCAL3D+ group stands for the whole group, a class of no group for itself alone),
            for the untargeted verdicts and the benign control alike.
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
    adversarial mesh ``adversarial.ply`` (a job that attacked a textured or vertex-coloured file: ``adversarial.obj``
    with the texture or colours, under the job's shading) and the views of its ``result.json`` in the job's folder.
    A job whose folder is missing (the database was moved to another machine, or the sweep ran on a cluster) is
    regenerated from its stored spec and seed into ``<artifact_root>/jobs/..``
    (:func:`meshadv.experiments.rebuild.ensure_artifacts`).

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
    if not Path(db_path).is_file():
        raise FileNotFoundError(f"db_path {db_path} does not exist")
    if limit is not None:
        _validate.positive_int("limit", limit)
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
    from meshadv.experiments.rebuild import ensure_artifacts

    root = Path(artifact_root) if artifact_root is not None else Path(db_path).parent
    return ensure_artifacts(db_path, row.job_id, root, row.out_dir)


def _case_from_job(row: Any, out: Path) -> Optional[TransferCase]:
    """The case of a done job from its folder ``out`` (``result.json`` and the adversarial mesh; the benign mesh from
    the job's spec), or None when the folder lacks them or the result has no views."""
    result_path = out / "result.json"
    if not result_path.is_file():
        return None
    result = json.loads(result_path.read_text())
    meshes = result.get("meshes") or [["adversarial.ply", "adversarial.obj"]]
    mesh_path = out / meshes[0][0]
    if not mesh_path.is_file() or not result.get("views"):
        return None
    spec, record = row.spec, row.record or {}
    benign = _benign_of_job(spec, record)
    obj_path = out / meshes[0][1]
    if isinstance(benign, SurfaceMesh) and obj_path.is_file():  # the texture or colours, as the job attacked them
        adversarial = load_saved_mesh(obj_path, {"shading": benign.shading})
    else:
        adversarial = load_mesh(mesh_path)
    target = spec.get("target")
    if target in ("", "untargeted", None):
        target = None
    size = result.get("config", {}).get("image_size") or spec.get("image_size") or 224
    return TransferCase(
        case_id=row.job_id,
        mesh=adversarial,
        views=tuple(result["views"]),
        victim=str(spec.get("victim", result.get("victim"))),
        true_class=str(spec.get("source_class", spec.get("mesh", {}).get("class", ""))),
        target=None if target is None else str(target),
        perturbation=str(spec.get("perturbation", result.get("perturbation", ""))),
        image_size=tuple(size) if isinstance(size, (list, tuple)) else (int(size), int(size)),
        benign_correct=None if record.get("benign_correct") is None else bool(record["benign_correct"]),
        antialias=int(result.get("config", {}).get("antialias") or 1),
        name=case_name(spec, row.job_id),
        benign_mesh=benign,
    )


def _benign_of_job(spec: dict[str, Any], record: dict[str, Any]) -> Any:
    """The benign mesh of a job (:func:`~meshadv.transfer.benign_control.benign_mesh_of_job`), or ``None`` when its
    spec's mesh cannot be loaded here (e.g. the shared data is missing): its rows then carry no benign control and
    the tables leave them out of the untargeted count."""
    try:
        return benign_mesh_of_job(spec, record)
    except (ValueError, FileNotFoundError, KeyError):
        return None


def write_image_index(image_dir: Union[str, Path], cases: Sequence[TransferCase],
                      rows: Sequence[ControlledResult]) -> Path:
    """Add the renders of ``cases`` to ``<image_dir>/index.csv`` (file name -> job id, classes, view, outcome), keeping
    the entries of earlier runs; written atomically.

    Args:
        image_dir: the folder the renders were saved in.
        cases: the transferred cases (their ``name`` and ``case_id``).
        rows: their results (one per case and view).

    Returns:
        The index path.
    """
    path = Path(image_dir) / "index.csv"
    entries = _read_index(path)
    stems = {case.case_id: case.name or case.case_id for case in cases}
    for row in rows:
        if row.case_id not in stems or row.error is not None:
            continue
        entry = _index_entry(stems[row.case_id], row)
        entries[entry["file"]] = entry
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=INDEX_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for file in sorted(entries):
        writer.writerow({k: entries[file].get(k, "") for k in INDEX_COLUMNS})
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, out.getvalue())
    return path


def _read_index(path: Path) -> dict[str, dict[str, Any]]:
    """The entries of an existing ``index.csv`` by file name (none when there is no such file)."""
    if not path.is_file():
        return {}
    with open(path, newline="", encoding="utf-8") as fh:
        return {row["file"]: row for row in csv.DictReader(fh)}


def _index_entry(stem: str, row: ControlledResult) -> dict[str, Any]:
    """The ``index.csv`` entry of the render of ``row``'s view, saved as ``<stem>_v<view>.png``."""
    file = f"{stem}_v{row.view}.png"
    return {"file": file, "job_id": row.case_id, "victim": row.victim, "true_class": row.true_class,
            "target": row.target, "perturbation": row.perturbation, "view": row.view,
            "success_meshadv": row.success_meshadv, "success_mitsuba": row.success_mitsuba,
            "top1_meshadv": row.top1_meshadv, "top1_mitsuba": row.top1_mitsuba}


def save_images(images: Sequence[MitsubaImage], out_dir: Union[str, Path], stem: str) -> list[Path]:
    """Save Mitsuba renders as 8-bit PNGs ``<stem>_v<i>.png`` in ``out_dir`` (created if missing; linear values, as
    meshadv's images) and return their paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, im in enumerate(images):
        path = out_dir / f"{stem}_v{i}.png"
        save_png(im.image, path)
        paths.append(path)
    return paths


def mitsuba_specs_for_case(case: TransferCase, *, spp: int = 64, max_depth: int = 8, seed: int = 0,
                           benign: bool = False) -> list[SceneSpec]:
    """One Mitsuba scene per view of ``case``: same camera, lights, image size and background.

    Args:
        case: the case.
        spp: samples per pixel.
        max_depth: path depth.
        seed: sampler seed of view 0 (view ``i`` gets ``seed + i``).
        benign: the scenes of the case's benign mesh instead of its adversarial one.

    Returns:
        The scene specs, in view order.

    Raises:
        ValueError: ``benign`` for a case without a benign mesh.
    """
    if benign and case.benign_mesh is None:
        raise ValueError(f"case {case.case_id} has no benign_mesh to render")
    obj = MeshObject.from_mesh(case.benign_mesh if benign else case.mesh)
    return [scene_spec(obj, rec, lights=rec, image_size=case.image_size, spp=spp, max_depth=max_depth,
                       background=case.background, seed=seed + i) for i, rec in enumerate(case.views)]


def evaluate_case(
    case: TransferCase,
    victim: Any,
    mitsuba_images: Sequence[MitsubaImage],
    benign_images: Optional[Sequence[MitsubaImage]] = None,
) -> list[ControlledResult]:
    """Evaluate one case on its meshadv renders and its Mitsuba renders (classifier victims).

    Args:
        case: the case.
        victim: a classifier victim.
        mitsuba_images: the case's Mitsuba renders, one per view (:func:`mitsuba_specs_for_case`).
        benign_images: Mitsuba's renders of the case's benign mesh, one per view (``benign=True``), or ``None``.

    Returns:
        One :class:`~meshadv.transfer.results.ControlledResult` per view: ``success_meshadv`` / ``success_mitsuba``
        (targeted when the case has a target, else untargeted), ``untargeted_meshadv`` / ``untargeted_mitsuba``, the
        top-1 labels, the Mitsuba variant and, with ``benign_images``, ``benign_correct_mitsuba`` and
        ``top1_benign_mitsuba`` (the benign control).

    Raises:
        ValueError: ``benign_images`` of another number of views.
    """
    if benign_images is not None and len(benign_images) != len(case.views):
        raise ValueError(f"benign_images has {len(benign_images)} renders for {len(case.views)} views")
    untargeted, targeted = classifier_criteria(victim, case.true_class, case.target)
    control = None if benign_images is None else benign_verdicts(victim, benign_images, untargeted)
    ours, images_ours = _meshadv_verdicts(case, victim, untargeted, targeted)
    images_theirs = images_tensor(mitsuba_images)
    theirs = _victim_verdicts(victim, images_theirs, untargeted, targeted)
    diff = (images_ours - images_theirs).abs().mean(dim=(1, 2, 3)).tolist()
    return [
        ControlledResult(
            **_identity(case, v),
            success_meshadv=ours.targeted[v],
            success_mitsuba=theirs.targeted[v],
            untargeted_meshadv=ours.untargeted[v],
            untargeted_mitsuba=theirs.untargeted[v],
            top1_meshadv=ours.top1[v],
            top1_mitsuba=theirs.top1[v],
            mean_abs_image_difference=float(diff[v]),
            variant=mitsuba_images[v].variant,
            benign_correct=case.benign_correct,
            benign_correct_mitsuba=None if control is None else control.correct[v],
            top1_benign_mitsuba=None if control is None else control.top1[v],
        )
        for v in range(len(case.views))
    ]


@dataclass(frozen=True)
class _Verdicts:
    """One renderer's verdicts on the views of a case.

    Attributes:
        untargeted: per view, the victim's top-1 is outside the true class's group.
        targeted: per view, the case's success: targeted for a targeted case, else ``untargeted``.
        top1: per view, the victim's top-1 class name.
    """

    untargeted: list[bool]
    targeted: list[bool]
    top1: list[str]


def _meshadv_verdicts(case: TransferCase, victim: Any, untargeted: Any,
                      targeted: Optional[Any]) -> tuple[_Verdicts, torch.Tensor]:
    """The verdicts on meshadv's renders of the case (its image size, background and the attack's supersampling,
    scored as the attack scores them) and those renders ``(V, 3, H, W)``."""
    views = ViewSet.from_records(list(case.views))
    criteria = [untargeted] if targeted is None else [untargeted, targeted]
    setup = RenderSetup(image_size=case.image_size, background=case.background, antialias=case.antialias)
    scored = evaluate(case.mesh, views, victim, criteria, setup=setup)
    un = [bool(x) for x in (scored.margins[0] > 0).tolist()]
    success = un if targeted is None else [bool(x) for x in (scored.margins[1] > 0).tolist()]
    return _Verdicts(un, success, class_names(victim, scored.top1[0].tolist())), scored.images[0]


def _victim_verdicts(victim: Any, images: torch.Tensor, untargeted: Any, targeted: Optional[Any]) -> _Verdicts:
    """The verdicts of ``victim`` on ``images`` ``(V, 3, H, W)`` (Mitsuba's renders)."""
    with torch.no_grad():
        logits = victim(images)
    un = [bool(x) for x in untargeted.is_adversarial(logits).tolist()]
    success = un if targeted is None else [bool(x) for x in targeted.is_adversarial(logits).tolist()]
    return _Verdicts(un, success, top1_names(victim, logits))


def _identity(case: TransferCase, view: int) -> dict[str, Any]:
    """The fields that name a result row: the case, its victim, classes, perturbation and the view."""
    return {"case_id": case.case_id, "victim": case.victim, "true_class": case.true_class,
            "target": case.target or "", "perturbation": case.perturbation, "view": view}


def controlled_transfer(
    cases: Sequence[TransferCase],
    *,
    spp: int = 64,
    max_depth: int = 8,
    variant: Optional[str] = None,
    timeout: float = 1800.0,
    victim_loader: Optional[Callable[[str], Any]] = None,
    image_dir: Optional[Union[str, Path]] = None,
    on_error: str = "record",
) -> list[ControlledResult]:
    """Re-render each case with Mitsuba under its own camera and lights and test the victims (Table 3 / Fig. 5).

    A case with a ``benign_mesh`` (every case of :func:`cases_from_store` and of :func:`case_from_attack_folder`) has
    its benign mesh rendered too, under the same views: the control of untargeted transfer
    (:mod:`meshadv.transfer.benign_control`).

    Args:
        cases: the adversarial meshes (see :func:`cases_from_store`).
        spp: Mitsuba samples per pixel.
        max_depth: path depth (>= 3 adds interreflection; 2 is direct light with shadows only).
        variant: Mitsuba variant (default: the best that works).
        timeout: seconds per case.
        victim_loader: ``name -> victim`` (default ``meshadv.victims.load_victim``); victims are loaded once.
        image_dir: when given, Mitsuba renders are saved there as ``<name>_v<view>.png`` (``TransferCase.name``,
            else its ``case_id``), the benign control's as ``<name>_benign_v<view>.png``.
        on_error: ``"record"`` keeps going and records a result with an ``error`` for a failed render; ``"raise"``
            re-raises.

    Returns:
        One :class:`~meshadv.transfer.results.ControlledResult` per (case, view) (see :func:`evaluate_case`); a
        failed render gives results with ``error`` set and no success.

    Raises:
        TypeError: a case is not a :class:`~meshadv.transfer.controlled.TransferCase`, ``victim_loader`` is not
            callable, or ``spp``, ``max_depth`` or ``timeout`` has the wrong type.
        ValueError: unknown ``on_error``, ``spp < 1``, ``max_depth`` neither ``>= 1`` nor ``-1``, or ``timeout <= 0``.
        MitsubaRenderError: a render failed and ``on_error == "raise"``.
    """
    cases = list(cases)
    _check_transfer_options(cases, spp, max_depth, timeout, victim_loader, on_error)
    if victim_loader is None:
        victim_loader = load_victim
    victims: dict[str, Any] = {}
    rows: list[ControlledResult] = []
    for case in cases:
        specs = mitsuba_specs_for_case(case, spp=spp, max_depth=max_depth)
        if case.benign_mesh is not None:  # the benign control, in the same child process
            specs += mitsuba_specs_for_case(case, spp=spp, max_depth=max_depth, benign=True)
        try:
            rendered = render_scenes(specs, variant=variant, timeout=timeout)
        except MitsubaRenderError as exc:
            if on_error == "raise":
                raise
            rows.extend(_failed(case, exc))
            continue
        views = len(case.views)
        images, benign = rendered[:views], (rendered[views:] if case.benign_mesh is not None else None)
        if case.victim not in victims:
            victims[case.victim] = victim_loader(case.victim)
        rows.extend(evaluate_case(case, victims[case.victim], images, benign))
        if image_dir is not None:
            stem = case.name or case.case_id
            save_images(images, Path(image_dir), stem)
            if benign is not None:
                save_images(benign, Path(image_dir), f"{stem}_benign")
    return rows


def _check_transfer_options(cases: Sequence[Any], spp: Any, max_depth: Any, timeout: Any, victim_loader: Any,
                            on_error: Any) -> None:
    """Raise naming the first bad argument of :func:`controlled_transfer`, before any case is rendered."""
    for i, case in enumerate(cases):
        if not isinstance(case, TransferCase):
            raise TypeError(f"cases[{i}] must be a TransferCase, got {type(case).__name__}")
    _validate.positive_int("spp", spp)
    if _validate.integer("max_depth", max_depth) < 1 and max_depth != -1:
        raise ValueError(f"max_depth must be >= 1 (or -1 for unlimited), got {max_depth}")
    _validate.positive_float("timeout", timeout)
    if victim_loader is not None and not callable(victim_loader):
        raise TypeError(f"victim_loader must be a callable or None, got {type(victim_loader).__name__}")
    if on_error not in ("record", "raise"):
        raise ValueError(f"on_error must be 'record' or 'raise', got {on_error!r}")


def _failed(case: TransferCase, error: MitsubaRenderError) -> list[ControlledResult]:
    """One result per view of ``case`` whose Mitsuba render failed: no successes, ``error`` says why."""
    return [
        ControlledResult(**_identity(case, v), success_meshadv=None, success_mitsuba=None, error=str(error))
        for v in range(len(case.views))
    ]


def pending_cases(db_path: Union[str, Path], *, experiment: str = "controlled", only_successful: bool = True,
                  limit: Optional[int] = None) -> tuple[set[str], list[TransferCase]]:
    """What a resumable controlled transfer of a sweep's database still has to do.

    Args:
        db_path: the sweep's ``results.db``.
        experiment: the transfer run's name in the database.
        only_successful: only attacks that succeeded in meshadv.
        limit: at most this many cases to do.

    Returns:
        ``(done, todo)``: the case ids whose rows the database holds without an error, and the cases left (their
        artefacts regenerated from the stored specs where missing).
    """
    done = {r["case_id"] for r in load_transfer_rows(db_path, experiment=experiment, kind="controlled")
            if r.get("error") is None}
    return done, cases_from_store(db_path, only_successful=only_successful, skip=done, limit=limit)


def transfer_case_into(db_path: Union[str, Path], case: TransferCase, *, experiment: str = "controlled",
                       spp: int = 64, max_depth: int = 8, variant: Optional[str] = None,
                       image_dir: Optional[Union[str, Path]] = None) -> list[ControlledResult]:
    """Transfer one case (:func:`controlled_transfer`) and save its rows into ``db_path`` at once (and its renders'
    entries into ``image_dir``'s index), so an interrupted run loses no finished case.

    Returns:
        The case's rows, one per view.
    """
    rows = controlled_transfer([case], spp=spp, max_depth=max_depth, variant=variant, image_dir=image_dir)
    save_transfer_rows(db_path, [row.to_record() for row in rows], experiment=experiment, kind="controlled")
    if image_dir is not None:
        write_image_index(image_dir, [case], rows)
    return rows


def case_from_attack_folder(folder: Union[str, Path]) -> TransferCase:
    """The :class:`TransferCase` of a saved ``meshadv attack`` result: its first adversarial mesh (a textured or
    vertex-coloured one with its texture or colours and the attack's shading), its views, victim, classes and setup.

    The benign object's class is :func:`source_class_of_record`'s (the class the attack's benign check checked,
    else the untargeted attack's true class, else the PASCAL3D+ folder of the input mesh, else the victim's pristine
    top-1 on the first view), judged as its class group; the benign mesh (the control rendered by Mitsuba too) is
    the folder's ``benign.ply``, else the input mesh the record names, loaded again.

    Raises:
        FileNotFoundError: ``folder`` holds no ``result.json`` or its mesh is missing.
        ValueError: the result is not a classifier attack.
    """
    record = load_result_record(folder)
    if not record.get("original_top1_names"):
        raise ValueError(f"{folder}: only classifier attacks can be transferred this way (no top-1 in result.json)")
    ply, obj = record["meshes"][0][:2]
    # a textured or vertex-coloured result: its OBJ (texture PNG or vertex colours) beside its GLB
    surface = Path(obj).with_suffix(".glb").name in (record.get("files") or [])
    mesh_file = Path(folder) / (obj if surface else ply)
    if not mesh_file.is_file():
        raise FileNotFoundError(f"{mesh_file} is missing: re-run the attack or copy the whole output folder")
    config = record.get("config") or {}
    criterion = record["criteria"][0]
    adversarial = load_saved_mesh(mesh_file, record)
    return TransferCase(
        case_id="mitsuba",  # the renders are saved as mitsuba_v<view>.png beside result.json
        mesh=adversarial,
        views=tuple(record["views"]),
        victim=record["victim"],
        true_class=source_class_of_record(record),
        target=criterion.get("target_class"),
        perturbation=record.get("perturbation", ""),
        image_size=tuple(config.get("image_size") or (224, 224)),
        background=tuple(config.get("background") or (1.0, 1.0, 1.0)),
        benign_correct=None,
        antialias=int(config.get("antialias") or 1),
        benign_mesh=benign_mesh_of_attack_folder(Path(folder), record, int(adversarial.vertices.shape[0])),
    )


def source_class_of_record(record: Mapping[str, Any]) -> str:
    """The class the benign object of a saved classifier attack (its ``result.json`` ``record``) is: the source
    class its benign check checked (``input.source_class``: ``--source``, ``--untargeted``'s class or the PASCAL3D+
    folder), else an untargeted criterion's true class, else the PASCAL3D+ class of the input mesh's folder, else the
    victim's top-1 on the benign mesh's first view. Untargeted verdicts read it as its class group
    (:func:`~meshadv.attacks.criteria.resolve_true_class`), so a top-1 of ``"airliner"`` stands for the aeroplane.

    Raises:
        ValueError: the record names none of them (not a classifier attack).
    """
    from meshadv.attacks.benign import source_class_of_path
    from meshadv.data import PASCAL3D_CLASSES

    entry = record.get("input") or {}
    if entry.get("source_class"):
        return str(entry["source_class"])
    for criterion in record.get("criteria") or []:
        if criterion.get("true_class") is not None:
            return str(criterion["true_class"])
    from_folder = source_class_of_path(entry.get("path"), PASCAL3D_CLASSES)
    if from_folder is not None:
        return from_folder
    top1 = record.get("original_top1_names") or []
    if not top1:
        raise ValueError("the result names no source class and no benign top-1 (not a classifier attack)")
    return str(top1[0])


def transfer_attack_folder(folder: Union[str, Path], *, spp: int = 64, max_depth: int = 8,
                           variant: Optional[str] = None,
                           victim_loader: Optional[Callable[[str], Any]] = None) -> list[ControlledResult]:
    """Render ``folder``'s adversarial mesh with Mitsuba under the attack's views and test the victim.

    Writes ``transfer.json`` (one record per view, see :func:`evaluate_case`) and the Mitsuba renders
    ``mitsuba_v<view>.png`` (adversarial) and ``mitsuba_benign_v<view>.png`` into ``folder``.

    Returns:
        One :class:`~meshadv.transfer.results.ControlledResult` per view.

    Raises:
        FileNotFoundError / ValueError: see :func:`case_from_attack_folder`.
        ModuleNotFoundError: Mitsuba 3 is not installed (``pip install 'meshadv[transfer]'``).
    """
    import mitsuba  # noqa: F401  (a clear ModuleNotFoundError before any work)

    case = case_from_attack_folder(folder)
    rows = controlled_transfer([case], spp=spp, max_depth=max_depth, variant=variant, victim_loader=victim_loader,
                               image_dir=folder, on_error="raise")
    write_json_atomic({"folder": str(Path(folder).resolve()), "spp": spp, "max_depth": max_depth,
                       "rows": [row.to_record() for row in rows]}, Path(folder) / "transfer.json")
    return rows


def transfer_attack_summary(rows: Sequence[ControlledResult]) -> str:
    """One line on a transferred attack's views: targeted success in Mitsuba (targeted attacks), and the untargeted
    transfer counted only on the views whose benign Mitsuba render is right (the benign control)."""
    control = [r for r in rows if r.benign_correct_mitsuba]
    untargeted = sum(bool(r.untargeted_mitsuba) for r in control)
    targeted = (f"targeted transfer on {sum(bool(r.success_mitsuba) for r in rows)}/{len(rows)} views; "
                if rows and rows[0].target else "")
    return (f"{targeted}untargeted transfer on {untargeted}/{len(control)} views whose benign Mitsuba render is "
            f"right ({len(rows) - len(control)} left out: the benign mesh is not its class there either)")
