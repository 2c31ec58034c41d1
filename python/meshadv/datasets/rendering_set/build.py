"""Building (or resuming) a rendering set: check the inputs, open or start the file, then, class by class and batch by
batch, sample candidates, render them, judge them with every victim and keep those all victims get right."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Optional, Union

import numpy as np

from meshadv.datasets.rendering_set.judging import Judge, resolve_victims
from meshadv.datasets.rendering_set.mesh_paths import stored_mesh_path
from meshadv.datasets.rendering_set.rendering import load_set_mesh, render_mesh_views
from meshadv.datasets.rendering_set.sampling import RenderingSetConfig, candidate_seed, sample_view
from meshadv.datasets.rendering_set.set_file import PathLike, content_identity, load_rendering_set, new_document
from meshadv.util.atomic import write_json_atomic
from meshadv.victims.victim import Victim
from meshadv.victims.labels import PASCAL3D_CLASSES, PASCAL3D_TO_IMAGENET, imagenet_class_names

if TYPE_CHECKING:
    from meshadv.mesh import Mesh

__all__ = ["build_rendering_set"]

#: ``progress(class_name, class_stats)``, called after each batch.
Progress = Callable[[str, dict[str, Any]], None]


def build_rendering_set(
    mesh_paths_by_class: Mapping[str, Sequence[PathLike]],
    victims: Sequence[Union[str, Victim]],
    per_class: int = 72,
    seed: int = 0,
    out_path: PathLike = "rendering_set.json",
    *,
    config: Optional[RenderingSetConfig] = None,
    batch_size: int = 16,
    mesh_root: Optional[PathLike] = None,
    progress: Optional[Progress] = None,
) -> dict[str, Any]:
    """Build (or resume) the rendering set and write it to ``out_path`` (atomically, after every batch).

    Args:
        mesh_paths_by_class: PASCAL3D+ class name -> mesh files of that class.
        victims: victim names (loaded with :func:`~meshadv.victims.load_victim`) or victim objects.
        per_class: kept renderings wanted per class (the paper: 72).
        seed: master seed.
        out_path: the JSON file; if it exists with the same configuration the run resumes from it.
        config: sampling / rendering options (default :class:`RenderingSetConfig`).
        batch_size: candidates rendered and classified together.
        mesh_root: when given, mesh paths are stored relative to this folder (every mesh must lie inside it), so the
            file is portable between machines; resolve them with
            :func:`~meshadv.datasets.rendering_set.rendering_mesh_path`.
        progress: called as ``progress(class_name, class_stats)`` after each batch.

    Returns:
        The document written to ``out_path`` (see :mod:`meshadv.datasets.rendering_set`).

    Raises:
        ValueError: unknown class, no meshes for a class, ``per_class`` / ``batch_size`` < 1, bad victims, a mesh
            outside ``mesh_root``, or an existing ``out_path`` written with a different configuration.
        FileNotFoundError: a mesh file does not exist.
    """
    plan = _plan(mesh_paths_by_class, victims, per_class, seed, config or RenderingSetConfig(), batch_size, mesh_root)
    out_path = Path(out_path)
    doc = _open_document(out_path, plan)
    if doc["complete"] and not any(plan.wants_more(s) for s in doc["classes"].values()):
        return doc
    doc["complete"] = False
    imagenet_names = imagenet_class_names()
    judges = [Judge(v, plan.config.detector_threshold, imagenet_names) for v in plan.victims]
    for class_index, cls in enumerate(PASCAL3D_CLASSES):
        if cls in plan.meshes_by_class:
            _fill_class(doc, out_path, plan, judges, class_index, cls, progress)
    doc["complete"] = True
    write_json_atomic(doc, out_path, indent=1)
    return doc


@dataclass(frozen=True)
class _Plan:
    """The checked inputs of a build.

    Attributes:
        meshes_by_class: class -> mesh files as given (strings). stored_by_class: the same paths as the file stores
            them. victims: the victim objects. per_class, seed, config, batch_size: as given to the build.
    """

    meshes_by_class: dict[str, list[str]]
    stored_by_class: dict[str, list[str]]
    victims: list[Victim]
    per_class: int
    seed: int
    config: RenderingSetConfig
    batch_size: int

    @property
    def victim_names(self) -> list[str]:
        """The victims' names, in the given order."""
        return [v.name for v in self.victims]

    @property
    def max_candidates(self) -> int:
        """Candidates tried per class before it counts as exhausted."""
        return self.config.max_candidates_per_class or 50 * self.per_class

    def config_json(self) -> dict[str, Any]:
        """The document's ``"config"`` entry."""
        return {
            "per_class": int(self.per_class),
            "seed": int(self.seed),
            "victims": self.victim_names,
            "meshes": self.stored_by_class,
            "sampling": self.config.to_json(),
        }

    def wants_more(self, stats: Mapping[str, Any]) -> bool:
        """Whether a class with these stats still lacks renderings and has candidates left to try."""
        return stats["kept"] < self.per_class and stats["next_candidate"] < self.max_candidates


def _plan(
    mesh_paths_by_class: Mapping[str, Sequence[PathLike]],
    victims: Sequence[Union[str, Victim]],
    per_class: int,
    seed: int,
    config: RenderingSetConfig,
    batch_size: int,
    mesh_root: Optional[PathLike],
) -> _Plan:
    """Check the arguments of :func:`build_rendering_set` (in this order) and load the victims."""
    if per_class < 1:
        raise ValueError(f"per_class must be >= 1, got {per_class}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    if not mesh_paths_by_class:
        raise ValueError("mesh_paths_by_class must name at least one class")
    root = Path(mesh_root).resolve() if mesh_root is not None else None
    if root is not None and not root.is_dir():
        raise FileNotFoundError(f"mesh_root {mesh_root} is not a folder")
    meshes_by_class: dict[str, list[str]] = {}
    stored_by_class: dict[str, list[str]] = {}
    for cls, paths in mesh_paths_by_class.items():
        meshes_by_class[cls] = _checked_mesh_files(cls, paths)
        stored_by_class[cls] = [stored_mesh_path(p, root) for p in meshes_by_class[cls]]
    return _Plan(meshes_by_class, stored_by_class, resolve_victims(victims), per_class, seed, config, batch_size)


def _checked_mesh_files(cls: str, paths: Sequence[PathLike]) -> list[str]:
    """The mesh files of class ``cls`` as strings, after checking the class is known and every file exists."""
    if cls not in PASCAL3D_TO_IMAGENET:
        raise ValueError(f"mesh_paths_by_class: unknown class {cls!r}; classes: {', '.join(PASCAL3D_CLASSES)}")
    files = [str(p) for p in paths]
    if not files:
        raise ValueError(f"mesh_paths_by_class[{cls!r}] is empty")
    for p in files:
        if not Path(p).is_file():
            raise FileNotFoundError(f"mesh_paths_by_class[{cls!r}]: mesh file {p} does not exist")
    return files


def _open_document(out_path: Path, plan: _Plan) -> dict[str, Any]:
    """The document to continue: the one at ``out_path`` when it has the same configuration, else a new one.

    Raises:
        ValueError: ``out_path`` holds a set with a different configuration.
    """
    config_json = plan.config_json()
    if not out_path.exists():
        out_path.parent.mkdir(parents=True, exist_ok=True)
        return new_document(config_json, list(plan.meshes_by_class), plan.victim_names)
    doc = load_rendering_set(out_path)
    if content_identity(doc["config"]) != content_identity(config_json):
        raise ValueError(
            f"out_path {out_path} holds a rendering set with a different configuration; "
            "remove it or choose another out_path"
        )
    # the candidate budget only says when to give up: a larger one continues exhausted classes
    doc["config"]["sampling"]["max_candidates_per_class"] = plan.config.max_candidates_per_class
    return doc


@dataclass(frozen=True)
class _Verdict:
    """A judged candidate: its view record, each victim's pass, each victim's prediction, and its seed."""

    view: dict[str, Any]
    passed: list[bool]
    predictions: dict[str, str]
    seed: int


def _fill_class(
    doc: dict[str, Any],
    out_path: Path,
    plan: _Plan,
    judges: Sequence[Judge],
    class_index: int,
    cls: str,
    progress: Optional[Progress],
) -> None:
    """Try batches of class ``cls`` until it has ``per_class`` renderings or its budget is spent, writing the file
    after every batch."""
    stats = doc["classes"][cls]
    if not plan.wants_more(stats):
        stats["exhausted"] = stats["kept"] < plan.per_class
        return
    meshes = [load_set_mesh(path, plan.config) for path in plan.meshes_by_class[cls]]
    while plan.wants_more(stats):
        start = stats["next_candidate"]
        candidates = list(range(start, min(start + plan.batch_size, plan.max_candidates)))
        verdicts = _judge_candidates(plan, judges, meshes, class_index, cls, candidates)
        _record_in_order(doc, plan, cls, candidates, verdicts)
        stats["pass_rate"] = {k: n / stats["tried"] for k, n in stats["passed"].items()}
        stats["exhausted"] = stats["kept"] < plan.per_class and stats["next_candidate"] >= plan.max_candidates
        write_json_atomic(doc, out_path, indent=1)
        if progress is not None:
            progress(cls, stats)


def _judge_candidates(
    plan: _Plan,
    judges: Sequence[Judge],
    meshes: Sequence[tuple[Mesh, np.ndarray]],
    class_index: int,
    cls: str,
    candidates: Sequence[int],
) -> dict[int, _Verdict]:
    """Sample, render and judge ``candidates`` of class ``cls``, one render call per mesh (candidate ``c`` uses mesh
    ``c mod M``)."""
    from meshadv.render import ViewSet

    by_mesh: dict[int, list[int]] = {}
    for cand in candidates:
        by_mesh.setdefault(cand % len(meshes), []).append(cand)
    verdicts: dict[int, _Verdict] = {}
    for mesh_index, cands in by_mesh.items():
        mesh, verts_np = meshes[mesh_index]
        seeds = [candidate_seed(plan.seed, class_index, c) for c in cands]
        views = [sample_view(np.random.default_rng(s), verts_np, plan.config) for s in seeds]
        images = render_mesh_views(mesh, ViewSet.from_records(views), plan.config)
        judged = [judge(images, cls) for judge in judges]
        for j, cand in enumerate(cands):
            passed = [v[0][j] for v in judged]
            predictions = {name: v[1][j] for name, v in zip(plan.victim_names, judged)}
            verdicts[cand] = _Verdict(views[j], passed, predictions, seeds[j])
    return verdicts


def _record_in_order(
    doc: dict[str, Any], plan: _Plan, cls: str, candidates: Sequence[int], verdicts: Mapping[int, _Verdict]
) -> None:
    """Count the candidates in candidate order and keep those every victim passed, stopping at ``per_class`` kept (so
    the set does not depend on batching)."""
    stats = doc["classes"][cls]
    stored = plan.stored_by_class[cls]
    for cand in candidates:
        verdict = verdicts[cand]
        stats["tried"] += 1
        stats["next_candidate"] = cand + 1
        for name, ok in zip(plan.victim_names, verdict.passed):
            stats["passed"][name] += int(ok)
        if all(verdict.passed):
            stats["passed"]["all"] += 1
            stats["kept"] += 1
            doc["renderings"].append(
                {
                    "class": cls,
                    "mesh": stored[cand % len(stored)],
                    "mesh_index": cand % len(stored),
                    "candidate": cand,
                    "seed": verdict.seed,
                    "view": verdict.view,
                    "predictions": verdict.predictions,
                }
            )
            if stats["kept"] >= plan.per_class:
                break
