"""A finished attack job's artefact folder rebuilt from what the results database keeps: the perturbation itself.

The attack job's record lists its artefacts (``benign.ply``, ``benign_v{j}.png``, the adversarial PLY and OBJ,
``after_v{j}.png``, ``result.json``); the database keeps the job's perturbation
(:class:`~meshadv.experiments.perturbation.Perturbation`) beside the record. :func:`rebuild_job` loads the benign mesh
again from the spec (:func:`~meshadv.experiments.jobs.load_job_mesh`), applies the perturbation, renders the spec's
views with its render setup and writes every listed artefact, ``result.json`` (the stored record) last, so the
folder is complete exactly when its marker is there. No attack runs: the mesh is the one the tables counted (to
float16 rounding of the change), on any machine.

Example:
    >>> folder = rebuild_job("results.db", row, "out/jobs/9e/9eb66d8948f76ffd")   # doctest: +SKIP
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Callable, Dict, Optional, Union

from meshadv.experiments.store import JobRow, ResultStore, job_out_dir

__all__ = ["rebuild_job", "stored_perturbation", "rebuilt_or_regenerated", "regeneration_warning", "say_on_stderr",
           "ensure_artifacts"]


def stored_perturbation(db_path: Union[str, Path], job: str) -> Optional[tuple]:
    """``(perturbation, source)`` the database keeps for ``job``, or ``None``."""
    with ResultStore(db_path, read_only=True) as store:
        return store.perturbation(job)


def rebuild_job(db_path: Union[str, Path], row: JobRow, target: Union[str, Path]) -> Optional[Path]:
    """Write the artefacts of finished job ``row`` into ``target`` from its stored perturbation.

    Args:
        db_path: the results database. row: a ``done`` attack job row. target: the folder to write (created).

    Returns:
        ``target``, or ``None`` when the database keeps no perturbation for the job (or the job was skipped).

    Raises:
        FileNotFoundError: the job's mesh is not on this machine (shared data missing).
        ValueError: the perturbation does not fit the mesh the spec loads (another mesh).
    """
    import torch

    from meshadv.experiments.jobs import load_job_mesh
    from meshadv.experiments.regenerate import recorded_mesh_spec
    from meshadv.mesh.surface_mesh import save_any_mesh
    from meshadv.render import ViewSet
    from meshadv.render.surface_reflectance import reflectance_of
    from meshadv.render.setup import RenderSetup, split_setup_options
    from meshadv.util.atomic import write_text_atomic
    from meshadv.util.png import save_png

    record = row.record or {}
    if record.get("skipped"):
        return None
    kept = stored_perturbation(db_path, row.job_id)
    if kept is None:
        return None
    packed, _source = kept
    spec = row.spec
    benign = load_job_mesh(recorded_mesh_spec(spec, record), spec.get("perturbation"))
    adversarial = packed.apply(benign)
    setup_options, _ = split_setup_options(dict(spec.get("attack", {})))
    setup = RenderSetup(image_size=int(spec.get("image_size", 224)), **setup_options)
    views = ViewSet.from_records(spec["views"])
    out = Path(target)
    out.mkdir(parents=True, exist_ok=True)
    arts = record.get("artifacts") or {}
    meshes = {"benign_mesh": benign, "benign_surface": benign, "adversarial_mesh": adversarial,
              "adversarial_obj": adversarial}
    for key, name in {"benign_mesh": "benign.ply", **arts}.items():
        if key in meshes and name:
            save_any_mesh(meshes[key], out / str(name))
    with torch.no_grad():
        for key, mesh in (("benign_images", benign), ("adversarial_images", adversarial)):
            names = arts.get(key) or []
            if not names:
                continue
            images, _ = setup.render(mesh.vertices.unsqueeze(0), mesh.faces, reflectance_of(mesh), views)
            for j, name in enumerate(names[: images.shape[0]]):
                save_png(images[j], out / str(name))
    write_text_atomic(out / str(arts.get("result", "result.json")), json.dumps(_result_of(spec, record), indent=2))
    return out


def _result_of(spec: Dict[str, Any], record: Dict[str, Any]) -> Dict[str, Any]:
    """A rebuilt folder's ``result.json``: the keys of an attack's own (:meth:`meshadv.attacks.AttackResult.
    to_record`) that the stored spec and record give, for one target, marked as rebuilt."""
    arts = record.get("artifacts") or {}
    return {
        "rebuilt_from": "the perturbation kept in the results database",
        "perturbation": spec.get("perturbation"),
        "victim": spec.get("victim"),
        "succeeded": [bool(record.get("success"))],
        "distances": [record.get("distances") or {}],
        "steps": record.get("steps"),
        "steps_to_success": [record.get("steps_to_success")],
        "top1_names": [record.get("adversarial_top1")],
        "original_top1_names": record.get("benign_top1"),
        "views": list(spec.get("views") or []),
        "eval_views": list(spec.get("eval_views") or []) or None,
        "config": record.get("attack_config"),
        "meshes": [[arts.get("adversarial_mesh"), arts.get("adversarial_obj")]],
        "num_vertices": record.get("num_vertices"),
        "num_faces": record.get("num_faces"),
    }


def say_on_stderr(message: str) -> None:
    """Print one line on standard error (how the resolvers below say what they did)."""
    print(message, file=sys.stderr, flush=True)


def regeneration_warning(done: Any) -> Optional[str]:
    """One line saying that a regeneration (:class:`~meshadv.experiments.regenerate.Regenerated`) did not reproduce
    the stored record, with why it may not (:func:`~meshadv.experiments.regenerate.compute_note`); ``None`` when it
    did."""
    from meshadv.experiments.regenerate import compute_note

    if done.stored is None or done.matches:
        return None
    return (f"job {done.job_id}: the regenerated attack differs from the stored record ("
            + "; ".join(done.differences) + "): its mesh is not the one the tables counted; "
            + compute_note(done.stored))


def rebuilt_or_regenerated(db_path: Union[str, Path], row: JobRow, target: Union[str, Path], *,
                           regenerate: bool = True, threads: int = 0, assume: Optional[Dict[str, Any]] = None,
                           say: Callable[[str], None] = say_on_stderr) -> Optional[Path]:
    """Write finished job ``row``'s artefacts into ``target``: from its stored perturbation (:func:`rebuild_job`),
    else, when ``regenerate``, by running the job again from its stored spec and seed
    (:func:`~meshadv.experiments.regenerate.regenerate_job`). Each says so in one line through ``say``, and a
    regeneration that does not reproduce the stored record says that too (:func:`regeneration_warning`).

    Returns:
        ``target``, or ``None`` when there is no perturbation and ``regenerate`` is false.
    """
    folder = rebuild_job(db_path, row, target)
    if folder is not None:
        say(f"job {row.job_id}: artefacts rebuilt from the perturbation kept in the database, into {folder}")
        return folder
    if not regenerate:
        return None
    from meshadv.experiments.regenerate import regenerate_job

    say(f"job {row.job_id}: the database keeps no perturbation of this job; regenerating it from its stored spec "
        f"and seed into {target}")
    done = regenerate_job(db_path, row.job_id, target, threads=threads, assume=assume)
    warning = regeneration_warning(done)
    if warning is not None:
        say(warning)
    return done.out_dir


def ensure_artifacts(db_path: Union[str, Path], job: str, artifact_root: Union[str, Path],
                     stored_out_dir: Optional[str] = None, marker: str = "result.json") -> Path:
    """The artefact folder of a finished job: its stored folder or ``<artifact_root>/jobs/..`` when either holds
    ``marker``, else rebuilt there from the perturbation the database keeps, else regenerated there from the stored
    spec and seed (:func:`rebuilt_or_regenerated`, which says which in one line).

    Args:
        db_path: the results database.
        job: the full job id.
        artifact_root: where rebuilt artefacts go (``job_out_dir(artifact_root, job)``), e.g. the database's folder.
        stored_out_dir: the folder the database records for the job (absent on another machine, perhaps).
        marker: the file that proves a folder complete (the attack job writes ``result.json`` last).

    Returns:
        A folder holding the job's artefacts.
    """
    for folder in (stored_out_dir, job_out_dir(artifact_root, job)):
        if folder and (Path(folder) / marker).is_file():
            return Path(folder)
    with ResultStore(db_path, read_only=True) as store:
        row = next((r for r in store.rows("done") if r.job_id == job), None)
    if row is None:
        raise KeyError(f"job {job!r} is not a finished job of {db_path}")
    folder = rebuilt_or_regenerated(db_path, row, job_out_dir(artifact_root, job))
    assert folder is not None  # regenerate=True
    return folder
