"""The benign control of a transfer: the benign mesh rendered by Mitsuba under the same views as the adversarial one.

An untargeted transfer only means something where the victim gets the benign object right *in Mitsuba's render*:
an object the victim already misclassifies there is "fooled" without any attack. So every controlled transfer
renders the benign mesh too (``mitsuba_specs_for_case(case, benign=True)`` in :mod:`meshadv.transfer.controlled`),
scores it (:func:`benign_verdicts`), and the tables count untargeted transfer only on views whose benign Mitsuba
render is right (:func:`meshadv.transfer.results.transfer_table`).

The benign mesh of a case comes from its attack: :func:`benign_mesh_of_attack_folder` (``meshadv attack`` /
``demo`` output: the saved ``benign.obj`` of a textured or vertex-coloured mesh, else ``benign.ply``, else the input
mesh loaded again as the attack loaded it) and
:func:`benign_mesh_of_job` (a sweep job: its spec's mesh, loaded and preprocessed as the job did).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence

import torch

from meshadv.transfer.mitsuba_process import MitsubaImage
from meshadv.transfer.scoring import images_tensor, top1_names

__all__ = ["BENIGN_FILE", "BENIGN_SURFACE_FILE", "BenignVerdicts", "benign_mesh_of_attack_folder",
           "benign_mesh_of_job", "benign_verdicts", "load_saved_mesh"]

#: The benign (normalised) mesh ``meshadv attack`` and ``meshadv demo`` save beside the adversarial one.
BENIGN_FILE = "benign.ply"
#: The benign mesh with its texture or vertex colours (OBJ), saved beside :data:`BENIGN_FILE` when it has them.
BENIGN_SURFACE_FILE = "benign.obj"


def load_saved_mesh(path: Path, record: Mapping[str, Any]) -> Any:
    """A mesh file of a saved attack as the attack rendered it: an OBJ with a texture or vertex colours as a
    ``SurfaceMesh`` under the record's ``shading``, else its per-face mesh (``load_mesh``).

    Raises:
        MeshLoadError: the file or its texture cannot be read (the message names the file and field).
    """
    from meshadv.mesh import load_mesh
    from meshadv.mesh.surface_mesh import load_surface_mesh

    if path.suffix.lower() == ".obj":
        surface = load_surface_mesh(path)
        if surface.texture is not None or surface.vertex_colors is not None:
            return replace(surface, shading=str(record.get("shading") or "flat"))
    return load_mesh(path)


@dataclass(frozen=True)
class BenignVerdicts:
    """The victim on Mitsuba's renders of the benign mesh, per view.

    Attributes:
        correct: the victim's top-1 is in the true class's group (not untargeted-adversarial).
        top1: the victim's top-1 class names.
    """

    correct: List[bool]
    top1: List[str]


def benign_verdicts(victim: Any, images: Sequence[MitsubaImage], untargeted: Any) -> BenignVerdicts:
    """Score Mitsuba's benign renders: per view, whether the victim's top-1 is in the true class group of the bound
    ``untargeted`` criterion (a benign warplane render of an aeroplane is right), and its top-1 name."""
    with torch.no_grad():
        logits = victim(images_tensor(images))
    wrong = untargeted.is_adversarial(logits).tolist()
    return BenignVerdicts([not bool(w) for w in wrong], top1_names(victim, logits))


def benign_mesh_of_attack_folder(folder: Path, record: Mapping[str, Any], num_vertices: int) -> Any:
    """The benign mesh of a saved attack: ``folder/benign.obj`` (a textured or vertex-coloured mesh, under the
    record's shading), else ``folder/benign.ply``, else the input the record names (``input``: the command-line mesh
    and its up axis), loaded again as the attack loaded it.

    Args:
        folder: the attack's output folder.
        record: its ``result.json``.
        num_vertices: the adversarial mesh's vertex count (the benign one must match it).

    Raises:
        FileNotFoundError: neither is available.
        ValueError: the mesh found has another vertex count (the attack changed the mesh first, e.g. the demo's
            subdivision, and ``benign.ply`` is missing).
    """
    surface, path = Path(folder) / BENIGN_SURFACE_FILE, Path(folder) / BENIGN_FILE
    if surface.is_file():
        mesh = load_saved_mesh(surface, record)
    elif path.is_file():
        mesh = load_saved_mesh(path, record)
    else:
        entry = record.get("input") or {}
        if not entry.get("mesh"):
            raise FileNotFoundError(f"{folder} holds no {BENIGN_FILE} and its result.json names no input mesh: the "
                                    "benign control cannot be rendered; re-run the attack")
        mesh = _input_mesh(entry)
    if int(mesh.vertices.shape[0]) != int(num_vertices):
        raise ValueError(f"{folder}: the benign mesh has {mesh.vertices.shape[0]} vertices, the adversarial one "
                         f"{num_vertices}; re-run the attack so that it saves {BENIGN_FILE}")
    return mesh


def _input_mesh(entry: Mapping[str, Any]) -> Any:
    """The normalised mesh of a record's ``input`` entry: a file (normalised with its recorded up axis), a
    ``builtin:NAME`` shape or ``default``, as ``meshadv attack`` loads them."""
    from meshadv.mesh import builtin_mesh, load_mesh, normalize_mesh
    from meshadv.mesh.shapes import default_mesh

    label = str(entry["mesh"])
    if entry.get("path"):
        return normalize_mesh(load_mesh(Path(entry["path"])), z_up=bool(entry.get("z_up")))[0]
    if label.startswith("builtin:"):
        return builtin_mesh(label.split(":", 1)[1])
    if label == "default":
        return default_mesh()
    raise FileNotFoundError(f"input mesh {label!r} of the record cannot be loaded again")


def benign_mesh_of_job(spec: Dict[str, Any], record: Optional[Mapping[str, Any]] = None) -> Any:
    """The benign mesh of a sweep job: its spec's ``mesh`` loaded as the job of its finished ``record`` loaded it
    (:func:`meshadv.experiments.jobs.load_job_mesh`, a textured file's ``SurfaceMesh`` when the record says
    ``mesh_surface``; without a record, the per-face mesh)."""
    from meshadv.experiments.jobs import load_job_mesh
    from meshadv.experiments.regenerate import recorded_mesh_spec

    if record is None:
        return load_job_mesh(spec["mesh"])
    return load_job_mesh(recorded_mesh_spec(spec, record), spec.get("perturbation"))
