"""Which images a perceptual study shows: successful attacks, benign controls and attention checks.

:func:`select_stimuli` reads a sweep's results database (:class:`~meshadv.experiments.store.ResultStore`) and returns
one :class:`Stimulus` per image. Each stimulus is a two-alternative forced choice (2AFC) between the object's true
class and the attack's target class, as in the MeshAdv user study:

- ``adversarial``: the adversarial render of every successful (``done``, ``success``), not skipped job, view 0;
- ``control``: the benign render of a seeded sample of those jobs (the correct answer is the true class, too);
- ``attention``: an obvious picture (the class name written large), whose correct answer is known; participants who
  fail one are dropped by the analysis.

Renders are found as :mod:`meshadv.experiments.report` finds them (the record's ``artifacts`` relative to the job's
``out_dir``). When a render is missing but the job's meshes are there, it is rendered again from the stored mesh and
the spec's first view (needs the native renderer); when both are missing, :class:`MissingRenderError` says which job
and which files.
"""

from __future__ import annotations

import random
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple, Union

from meshadv.experiments.store import JobRow, ResultStore

__all__ = ["Stimulus", "MissingRenderError", "select_stimuli", "job_render", "attention_image", "KINDS"]

#: The kinds of stimulus.
KINDS = ("adversarial", "control", "attention")


class MissingRenderError(FileNotFoundError):
    """A job's render is missing and cannot be made again (its mesh or spec is missing too)."""


@dataclass(frozen=True)
class Stimulus:
    """One image of the study and its two answers.

    Attributes:
        image_id: unique id, also the image's file stem in the exported folder.
        kind: one of :data:`KINDS`.
        true_class: the correct answer (the object's class; for attention checks, the written word).
        target: the other answer (the attack's target class; for attention checks, a distractor).
        victim: the attacked model (``""`` for attention checks).
        perturbation: ``shape`` or ``texture`` (``""`` for attention checks).
        distance: the attack's distance (Laplacian loss for shape, face-colour RMSE for texture); ``None`` for
            controls and attention checks.
        job_id: the sweep job the image comes from (``""`` for attention checks).
        source: the image file the export copies (or writes, for attention checks).
    """

    image_id: str
    kind: str
    true_class: str
    target: str
    victim: str
    perturbation: str
    distance: Optional[float]
    job_id: str
    source: str

    def to_record(self) -> Dict[str, Any]:
        """The stimulus as a JSON-able dict (without the local ``source`` path)."""
        rec = asdict(self)
        rec.pop("source")
        return rec


def _artifact(row: JobRow, key: str) -> Optional[Path]:
    """The path of the record's artefact ``key`` (first entry of a list), whether or not it exists."""
    value = (row.record or {}).get("artifacts", {}).get(key)
    if isinstance(value, list):
        value = value[0] if value else None
    if not value or row.out_dir is None:
        return None
    return Path(row.out_dir) / str(value)


def _job_mesh_artifact(row: JobRow, which: str) -> Optional[Path]:
    """The mesh file a job's ``which`` render is drawn from: a job that attacked a textured or vertex-coloured file
    (its record's ``mesh_shading``) its OBJ with the texture or colours, else its per-face PLY."""
    if (row.record or {}).get("mesh_shading"):
        surface = _artifact(row, "benign_surface" if which == "benign" else "adversarial_obj")
        if surface is not None and surface.is_file():
            return surface
    return _artifact(row, f"{which}_mesh")


def _rerender(row: JobRow, mesh_path: Path, out_png: Path) -> Path:
    """Render ``mesh_path`` from the job's first view as the attack job did (white background; an OBJ with a texture
    or vertex colours under the record's ``mesh_shading``) into ``out_png``."""
    from dataclasses import replace

    import torch

    from meshadv.mesh import load_mesh
    from meshadv.mesh.surface_mesh import load_surface_mesh
    from meshadv.render import RenderSetup, ViewSet
    from meshadv.render.surface_reflectance import reflectance_of
    from meshadv.util.png import save_png

    shading = (row.record or {}).get("mesh_shading")
    if shading and mesh_path.suffix.lower() == ".obj":
        mesh = replace(load_surface_mesh(mesh_path), shading=str(shading))
    else:
        mesh = load_mesh(mesh_path)
    views = ViewSet.from_records(row.spec["views"][:1])
    size = int(row.spec.get("image_size", 224))
    antialias = int(row.spec.get("attack", {}).get("antialias", 1))
    with torch.no_grad():
        images, _ = RenderSetup(image_size=size, antialias=antialias).render(
            mesh.vertices.unsqueeze(0), mesh.faces, reflectance_of(mesh), views)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    save_png(images[0], out_png)
    return out_png


def job_render(row: JobRow, which: str, cache_dir: Optional[Path] = None,
               db_path: Optional[Union[str, Path]] = None) -> Path:
    """The PNG of a job's benign or adversarial render (view 0), rendered again from its mesh when missing.

    With ``db_path``, a job whose folder is not on this machine gets it back next to the database
    (``<database folder>/jobs/..``), rebuilt from the perturbation the database keeps or regenerated from the stored
    spec and seed (:func:`meshadv.experiments.rebuild.ensure_artifacts`, which says which in one line).

    Args:
        row: a ``done`` job row.
        which: ``"benign"`` or ``"adversarial"``.
        cache_dir: where a render made again is written (default: the job's ``out_dir``).
        db_path: the job's results database (``None``: only the files on this machine are used).

    Returns:
        The PNG path.

    Raises:
        ValueError: ``which`` is not benign/adversarial.
        MissingRenderError: neither the render nor the mesh (or the spec's views) is there, and no ``db_path``.
    """
    if which not in ("benign", "adversarial"):
        raise ValueError(f"which must be 'benign' or 'adversarial', got {which!r}")
    png = _artifact(row, f"{which}_images")
    if png is not None and png.is_file():
        return png
    mesh = _job_mesh_artifact(row, which)
    if (mesh is None or not mesh.is_file()) and db_path is not None:
        from dataclasses import replace

        from meshadv.experiments.rebuild import ensure_artifacts

        folder = ensure_artifacts(db_path, row.job_id, Path(db_path).parent, row.out_dir)
        return job_render(replace(row, out_dir=str(folder)), which, cache_dir)
    if mesh is None or not mesh.is_file() or not row.spec.get("views"):
        raise MissingRenderError(
            f"job {row.job_id}: the {which} render ({png or 'not recorded'}) is missing and so is its mesh "
            f"({mesh or 'not recorded'}) or the spec's views; copy the sweep's output folder (out_dir "
            f"{row.out_dir!r}) next to the database or rerun the job")
    folder = Path(cache_dir) if cache_dir is not None else Path(row.out_dir or ".")
    return _rerender(row, mesh, folder / f"{row.job_id}_{which}_v0.png")


def attention_image(word: str, path: Union[str, Path], size: int = 224) -> Path:
    """Write an attention-check picture: ``word`` written large and centred on white.

    Args:
        word: the word (the correct answer).
        path: the PNG to write.
        size: side in pixels.

    Returns:
        ``path``.
    """
    from PIL import Image, ImageDraw, ImageFont

    image = Image.new("RGB", (size, size), (255, 255, 255))
    draw = ImageDraw.Draw(image)
    font_size = max(8, size // 4)
    font = ImageFont.load_default(size=font_size)
    while font_size > 8 and draw.textlength(word.upper(), font=font) > 0.85 * size:  # shrink until it fits
        font_size -= 2
        font = ImageFont.load_default(size=font_size)
    draw.text((size / 2, size / 2), word.upper(), fill=(0, 0, 0), font=font, anchor="mm")
    from meshadv.util.png import save_png

    return save_png(image, path)


def _successful(rows: List[JobRow]) -> List[JobRow]:
    return [r for r in rows if r.state == "done" and r.record is not None and r.record.get("success")
            and not r.record.get("skipped") and r.spec.get("target") and r.spec.get("source_class")]


def select_stimuli(db_path: Union[str, Path], work_dir: Union[str, Path], *, controls: int = 0,
                   attention_checks: int = 0, seed: int = 0, max_images: Optional[int] = None) -> List[Stimulus]:
    """The study's images from a sweep's results database.

    Args:
        db_path: the results database.
        work_dir: folder for renders made here (attention pictures, renders made again).
        controls: number of benign controls (a seeded sample of the successful jobs' benign renders; at most one
            per job).
        attention_checks: number of attention-check pictures.
        seed: seed of the samples (attacks, controls) and the attention checks' words.
        max_images: show at most this many adversarial images (a seeded sample of the successful attacks, kept in
            database order); ``None`` shows them all.

    Returns:
        The stimuli: adversarial ones in database order, then controls, then attention checks.

    Raises:
        FileNotFoundError: no database at ``db_path``.
        ValueError: no successful attack in the database, a negative count, ``max_images < 1``, or more controls
            than attacks shown.
        MissingRenderError: a render can neither be found nor made again.
    """
    db = Path(db_path)
    if not db.is_file():
        raise FileNotFoundError(f"results database {db} does not exist")
    if controls < 0 or attention_checks < 0:
        raise ValueError(f"controls and attention_checks must be >= 0, got {controls} and {attention_checks}")
    if max_images is not None and max_images < 1:
        raise ValueError(f"max_images must be >= 1 or None, got {max_images}")
    with ResultStore(db, read_only=True) as store:
        rows = _successful(store.rows("done"))
    if not rows:
        raise ValueError(f"results database {db} holds no successful attack (done, success, not skipped)")
    rng = random.Random(seed)
    if max_images is not None and max_images < len(rows):
        keep = set(rng.sample(range(len(rows)), max_images))
        rows = [r for i, r in enumerate(rows) if i in keep]
    if controls > len(rows):
        raise ValueError(f"controls must be <= the number of successful attacks ({len(rows)}), got {controls}")
    work = Path(work_dir)
    out: List[Stimulus] = []
    for row in rows:
        out.append(_stimulus(row, "adversarial", job_render(row, "adversarial", work, db)))
    for row in rng.sample(rows, controls):
        out.append(_stimulus(row, "control", job_render(row, "benign", work, db)))
    classes = sorted({r.spec["source_class"] for r in rows} | {r.spec["target"] for r in rows})
    from PIL import Image

    with Image.open(out[0].source) as first:
        side = max(first.size)  # attention pictures as large as the renders
    for i in range(attention_checks):
        word, other = _attention_pair(classes, rng)
        path = attention_image(word, work / f"attention_{i}.png", size=side)
        out.append(Stimulus(f"attention_{i}", "attention", word, other, "", "", None, "", str(path)))
    return out


def _attention_pair(classes: List[str], rng: random.Random) -> Tuple[str, str]:
    if len(classes) >= 2:
        word, other = rng.sample(classes, 2)
        return word, other
    return classes[0], "none of these"


def _stimulus(row: JobRow, kind: str, path: Path) -> Stimulus:
    record = row.record or {}
    distance = record.get("distance") if kind == "adversarial" else None
    return Stimulus(
        image_id=f"{'adv' if kind == 'adversarial' else 'ctl'}_{row.job_id}",
        kind=kind,
        true_class=str(row.spec["source_class"]),
        target=str(row.spec["target"]),
        victim=str(row.spec.get("victim", "")),
        perturbation=str(row.spec.get("perturbation", "")),
        distance=None if distance is None else float(distance),
        job_id=row.job_id,
        source=str(path),
    )
