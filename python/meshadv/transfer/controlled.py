"""Controlled-parameter transfer: re-render a sweep's adversarial meshes with Mitsuba 3 and test the victims.

Every adversarial mesh is re-rendered under the *same* camera and lights it was attacked with (the paper's Table 3
and Fig. 5). Every Mitsuba render runs in a child process (:mod:`meshadv.transfer.render`), so a crash fails one
evaluation, never the sweep.

Saved renders are named after what they show, ``<class>_c<configuration>_to_<target>_<perturbation>_<victim>_<job id's
first 8 hex digits>_v<view>.png`` (:func:`case_name`), and ``index.csv`` in the same folder lists every file with its
full job id and outcome (:func:`write_image_index`).
"""

from __future__ import annotations

import csv
import io
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Collection, Optional, Sequence, Union

import torch

from meshadv.transfer._scoring import class_names, images_tensor, top1_names
from meshadv.transfer.render import MitsubaImage, MitsubaRenderError, render_scenes
from meshadv.transfer.results import ControlledResult
from meshadv.transfer.spec import MeshObject, MitsubaCamera, MitsubaLights, SceneSpec

__all__ = [
    "ControlledResult",
    "TransferCase",
    "case_name",
    "write_image_index",
    "cases_from_store",
    "controlled_transfer",
    "evaluate_case",
    "mitsuba_specs_for_case",
    "save_images",
]


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


#: Columns of the renders' ``index.csv``.
INDEX_COLUMNS = ("file", "job_id", "victim", "true_class", "target", "perturbation", "view", "success_meshadv",
                 "success_mitsuba", "top1_meshadv", "top1_mitsuba")


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
    from meshadv.util.atomic import write_text_atomic

    path = Path(image_dir) / "index.csv"
    entries: dict[str, dict[str, Any]] = {}
    if path.is_file():
        with open(path, newline="", encoding="utf-8") as fh:
            entries = {row["file"]: row for row in csv.DictReader(fh)}
    stems = {case.case_id: case.name or case.case_id for case in cases}
    for row in rows:
        if row.case_id not in stems or row.error is not None:
            continue
        file = f"{stems[row.case_id]}_v{row.view}.png"
        entries[file] = {"file": file, "job_id": row.case_id, "victim": row.victim, "true_class": row.true_class,
                         "target": row.target, "perturbation": row.perturbation, "view": row.view,
                         "success_meshadv": row.success_meshadv, "success_mitsuba": row.success_mitsuba,
                         "top1_meshadv": row.top1_meshadv, "top1_mitsuba": row.top1_mitsuba}
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=INDEX_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for file in sorted(entries):
        writer.writerow({k: entries[file].get(k, "") for k in INDEX_COLUMNS})
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, out.getvalue())
    return path


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
        skip: job ids to leave out (e.g. those already transferred).
        artifact_root: root of regenerated artefact folders (default: the database's folder).
        regenerate: regenerate missing artefacts (else such jobs are left out).

    Returns:
        The cases, in database order.

    Raises:
        FileNotFoundError: ``db_path`` does not exist.
    """
    from meshadv.experiments import ResultStore
    from meshadv.mesh import load_mesh

    if not Path(db_path).is_file():
        raise FileNotFoundError(f"db_path {db_path} does not exist")
    cases: list[TransferCase] = []
    with ResultStore(db_path) as store:
        rows = store.rows("done")
    for row in rows:
        spec, record = row.spec, row.record or {}
        if spec.get("kind", "single") != "single" or record.get("skipped") or row.job_id in skip:
            continue
        if only_successful and not record.get("success"):
            continue
        out = Path(row.out_dir or "")
        if regenerate and not (out / "result.json").is_file():
            from meshadv.experiments.regenerate import ensure_artifacts

            root = Path(artifact_root) if artifact_root is not None else Path(db_path).parent
            out = ensure_artifacts(db_path, row.job_id, root, row.out_dir)
        result_path = out / "result.json"
        if not result_path.is_file():
            continue
        result = json.loads(result_path.read_text())
        meshes = result.get("meshes") or [["adversarial.ply", "adversarial.obj"]]
        mesh_path = out / meshes[0][0]
        if not mesh_path.is_file() or not result.get("views"):
            continue
        target = spec.get("target")
        if target in ("", "untargeted", None):
            target = None
        size = result.get("config", {}).get("image_size") or spec.get("image_size") or 224
        cases.append(
            TransferCase(
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
            )
        )
        if limit is not None and len(cases) >= limit:
            break
    return cases


def mitsuba_specs_for_case(case: TransferCase, *, spp: int = 64, max_depth: int = 8, seed: int = 0) -> list[SceneSpec]:
    """One Mitsuba scene per view of ``case``: same camera, lights, image size and background."""
    obj = MeshObject.from_mesh(case.mesh)
    return [
        SceneSpec(
            objects=(obj,),
            camera=MitsubaCamera.from_record(rec),
            lights=MitsubaLights.from_record(rec),
            image_size=case.image_size,
            spp=spp,
            max_depth=max_depth,
            background=case.background,
            seed=seed + i,
        )
        for i, rec in enumerate(case.views)
    ]


def _criteria(case: TransferCase, victim: Any) -> tuple[Any, Optional[Any]]:
    """The case's untargeted criterion and, for a targeted case, its targeted one, bound to ``victim``."""
    from meshadv.attacks import Misclassification, TargetedMisclassification

    untargeted = Misclassification(case.true_class).bind(victim)
    targeted = TargetedMisclassification(case.target).bind(victim) if case.target else None
    return untargeted, targeted


def evaluate_case(
    case: TransferCase,
    victim: Any,
    mitsuba_images: Sequence[MitsubaImage],
) -> list[ControlledResult]:
    """Evaluate one case on its meshadv renders and its Mitsuba renders (classifier victims).

    Returns:
        One :class:`~meshadv.transfer.results.ControlledResult` per view: ``success_meshadv`` / ``success_mitsuba``
        (targeted when the case has a target, else untargeted), ``untargeted_meshadv`` / ``untargeted_mitsuba``, the
        top-1 labels and the Mitsuba variant.
    """
    from meshadv.attacks import evaluate
    from meshadv.render import RenderSetup, ViewSet

    views = ViewSet.from_records(list(case.views))
    untargeted, targeted = _criteria(case, victim)
    criteria = [untargeted] if targeted is None else [untargeted, targeted]
    setup = RenderSetup(image_size=case.image_size, background=case.background, antialias=case.antialias)
    scored = evaluate(case.mesh, views, victim, criteria, setup=setup)  # meshadv's side, as the attack scores it
    ours = scored.images[0]
    with torch.no_grad():
        theirs = images_tensor(mitsuba_images)
        logits_theirs = victim(theirs)
    un_ours = (scored.margins[0] > 0).tolist()
    un_theirs = untargeted.is_adversarial(logits_theirs).tolist()
    if targeted is not None:
        t_ours = (scored.margins[1] > 0).tolist()
        t_theirs = targeted.is_adversarial(logits_theirs).tolist()
    else:
        t_ours, t_theirs = un_ours, un_theirs
    top_ours = class_names(victim, scored.top1[0].tolist())
    top_theirs = top1_names(victim, logits_theirs)
    diff = (ours - theirs).abs().mean(dim=(1, 2, 3)).tolist()
    return [
        ControlledResult(
            case_id=case.case_id,
            victim=case.victim,
            true_class=case.true_class,
            target=case.target or "",
            perturbation=case.perturbation,
            view=v,
            success_meshadv=bool(t_ours[v]),
            success_mitsuba=bool(t_theirs[v]),
            untargeted_meshadv=bool(un_ours[v]),
            untargeted_mitsuba=bool(un_theirs[v]),
            top1_meshadv=top_ours[v],
            top1_mitsuba=top_theirs[v],
            mean_abs_image_difference=float(diff[v]),
            variant=mitsuba_images[v].variant,
            benign_correct=case.benign_correct,
        )
        for v in range(len(case.views))
    ]


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

    Args:
        cases: the adversarial meshes (see :func:`cases_from_store`).
        spp: Mitsuba samples per pixel.
        max_depth: path depth (>= 3 adds interreflection; 2 is direct light with shadows only).
        variant: Mitsuba variant (default: the best that works).
        timeout: seconds per case.
        victim_loader: ``name -> victim`` (default ``meshadv.victims.load_victim``); victims are loaded once.
        image_dir: when given, Mitsuba renders are saved there as ``<name>_v<view>.png`` (``TransferCase.name``,
            else its ``case_id``).
        on_error: ``"record"`` keeps going and records a result with an ``error`` for a failed render; ``"raise"``
            re-raises.

    Returns:
        One :class:`~meshadv.transfer.results.ControlledResult` per (case, view) (see :func:`evaluate_case`); a
        failed render gives results with ``error`` set and no success.

    Raises:
        ValueError: unknown ``on_error``.
        MitsubaRenderError: a render failed and ``on_error == "raise"``.
    """
    if on_error not in ("record", "raise"):
        raise ValueError(f"on_error must be 'record' or 'raise', got {on_error!r}")
    if victim_loader is None:
        from meshadv.victims import load_victim

        victim_loader = load_victim
    victims: dict[str, Any] = {}
    rows: list[ControlledResult] = []
    for case in cases:
        try:
            images = render_scenes(mitsuba_specs_for_case(case, spp=spp, max_depth=max_depth), variant=variant,
                                   timeout=timeout)
        except MitsubaRenderError as exc:
            if on_error == "raise":
                raise
            rows.extend(
                ControlledResult(case_id=case.case_id, victim=case.victim, true_class=case.true_class,
                                 target=case.target or "", perturbation=case.perturbation, view=v,
                                 success_meshadv=None, success_mitsuba=None, error=str(exc))
                for v in range(len(case.views))
            )
            continue
        if case.victim not in victims:
            victims[case.victim] = victim_loader(case.victim)
        rows.extend(evaluate_case(case, victims[case.victim], images))
        if image_dir is not None:
            save_images(images, Path(image_dir), case.name or case.case_id)
    return rows


def save_images(images: Sequence[MitsubaImage], out_dir: Path, stem: str) -> list[Path]:
    """Save Mitsuba renders as 8-bit PNGs ``<stem>_v<i>.png`` (linear values, as meshadv's images)."""
    from meshadv.util.png import save_png

    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, im in enumerate(images):
        path = out_dir / f"{stem}_v{i}.png"
        save_png(im.image, path)
        paths.append(path)
    return paths
