"""The data behind the report's figures: which attacks the 7x7 grids and the flow figures (the paper's Figs. 2 and 3)
show, and their artefacts (:mod:`meshadv.experiments.figures` draws them)."""

from __future__ import annotations

import hashlib
import json
from collections import defaultdict
from pathlib import Path
from typing import Any, Dict, List, Optional, Set, Tuple

import numpy as np

from meshadv.experiments.artifact_source import ArtifactSource, artifact_path
from meshadv.experiments.store import JobRow
from meshadv.experiments.tables import instance_key, victim_label
from meshadv.util.png import add_png_text, png_text, save_png

__all__ = ["GridChoice", "grid_cells", "grid_choice", "grid_stamp", "flow_figures", "flow_stamp", "is_current",
           "slug_of", "PAPER_FLOW_EXAMPLE", "FIGURE_DRAWING_VERSION", "STAMP_KEY", "CORRELATIONS_KEY", "CELL_CACHE_PX"]


def slug_of(text: str) -> str:
    """``text`` with every character but letters, digits, ``-`` and ``_`` replaced by ``_`` (a file-name part)."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in text)


#: Bump when the figures' drawing changes, so that stamps no longer match figures drawn before.
FIGURE_DRAWING_VERSION = 1
#: PNG text key under which a figure records what it was drawn from (:func:`grid_stamp`, :func:`flow_stamp`).
STAMP_KEY = "meshadv-stamp"
#: PNG text key of the flow / curvature correlations, kept in the curvature figure so that a kept figure has them.
CORRELATIONS_KEY = "meshadv-correlations"


def _stamp(kind: str, content: Any) -> str:
    """A hash of what a figure of ``kind`` is drawn from."""
    text = json.dumps({"kind": kind, "version": FIGURE_DRAWING_VERSION, "content": content}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def is_current(paths: List[Path], stamp: str) -> bool:
    """Whether every PNG of ``paths`` exists and records ``stamp``."""
    return all(png_text(p).get(STAMP_KEY) == stamp for p in paths)


#: What :func:`grid_choice` returns: per source class the chosen instance's jobs, and the classes in order.
GridChoice = Tuple[Dict[str, List[JobRow]], List[str]]


def grid_choice(rows: List[JobRow]) -> GridChoice:
    """Per source class, the jobs of the instance with the most successful targets (from the records alone), and
    the classes in the grid's order."""
    by_instance: Dict[Tuple[Any, ...], List[JobRow]] = defaultdict(list)
    for row in rows:
        by_instance[instance_key(row.spec)].append(row)
    best: Dict[str, List[JobRow]] = {}
    for inst_rows in by_instance.values():
        src = inst_rows[0].spec["source_class"]
        score = sum(bool(r.record.get("success")) for r in inst_rows)
        if src not in best or score > sum(bool(r.record.get("success")) for r in best[src]):
            best[src] = inst_rows
    from meshadv.data import PASCAL3D_CLASSES

    classes = sorted({r.spec["source_class"] for r in rows} | {r.spec["target"] for r in rows},
                     key=lambda c: (PASCAL3D_CLASSES.index(c) if c in PASCAL3D_CLASSES else 99, c))
    return best, classes


def grid_stamp(choice: GridChoice, title: str) -> str:
    """What a grid is drawn from: the jobs :func:`grid_choice` chose with their outcomes, the classes and the title,
    hashed. A grid whose PNG records the same stamp need not be drawn again (nor its jobs' artefacts
    regenerated)."""
    best, classes = choice
    chosen = sorted((r.job_id, bool(r.record.get("success"))) for inst_rows in best.values() for r in inst_rows)
    return _stamp("grid", {"classes": classes, "title": title, "jobs": chosen})


#: Largest side, in pixels, of the grid-cell renders kept in a report's cell cache (a grid cell is drawn at 160 px).
CELL_CACHE_PX = 160


def _cell(row: JobRow, key: str, source: Optional[ArtifactSource], cache: Optional[Path]) -> Optional[Path]:
    """The render ``key`` (``benign_images`` / ``adversarial_images``, first view) of ``row`` for a grid cell: from
    ``cache`` when it holds it (no artefact needed), else the artefact (regenerated when ``source`` regenerates),
    then kept in ``cache`` at :data:`CELL_CACHE_PX`."""
    cached = None if cache is None else cache / f"{row.job_id}_{key}.png"
    if cached is not None and cached.is_file():
        return cached
    path = artifact_path(row, key, 0, source)
    if path is None or cached is None:
        return path
    from PIL import Image

    with Image.open(path) as img:
        thumb = img.convert("RGB")
        thumb.thumbnail((CELL_CACHE_PX, CELL_CACHE_PX))
    return save_png(thumb, cached)


def grid_cells(rows: List[JobRow], source: Optional[ArtifactSource] = None, cache: Optional[Path] = None,
               choice: Optional[GridChoice] = None,
               ) -> Tuple[Dict[Tuple[str, str], Path], List[str], Set[Tuple[str, str]]]:
    """The renders of :func:`grid_choice`'s instances (``choice`` when the caller has it), the classes and the
    ``(source, target)`` cells whose attack failed. Only the chosen instances' jobs are looked up: in ``cache``
    first (a folder of the report where every cell render found is kept small, so that a later report from the
    database alone can draw the grid again), then in ``source`` (regenerated when it regenerates)."""
    best, classes = choice if choice is not None else grid_choice(rows)
    cells: Dict[Tuple[str, str], Path] = {}
    failed: Set[Tuple[str, str]] = set()
    for src, inst_rows in best.items():
        for r in inst_rows:
            benign = _cell(r, "benign_images", source, cache) if (src, src) not in cells else None
            if benign is not None:
                cells[(src, src)] = benign
            adv = _cell(r, "adversarial_images", source, cache)
            if adv is not None:
                cells[(src, r.spec["target"])] = adv
                if not r.record.get("success"):
                    failed.add((src, r.spec["target"]))
    return cells, classes, failed


def _load_pair(row: JobRow, source: Optional[ArtifactSource] = None,
               ) -> Optional[Tuple[np.ndarray, np.ndarray, np.ndarray]]:
    import trimesh

    benign, adv = artifact_path(row, "benign_mesh", 0, source), artifact_path(row, "adversarial_mesh", 0, source)
    if benign is None or adv is None:
        return None
    a = trimesh.load(benign, process=False, force="mesh")
    b = trimesh.load(adv, process=False, force="mesh")
    if a.vertices.shape != b.vertices.shape:
        return None
    return np.asarray(a.vertices), np.asarray(b.vertices), np.asarray(a.faces)


def _curvature(vertices: np.ndarray, faces: np.ndarray) -> Optional[np.ndarray]:
    try:
        import torch

        from meshadv.mesh import Mesh, mean_curvature

        mesh = Mesh(torch.as_tensor(vertices, dtype=torch.float32), torch.as_tensor(faces, dtype=torch.int64),
                    torch.full((len(faces), 3), 0.7))
        return mean_curvature(mesh).detach().cpu().numpy().astype(np.float64)
    except Exception:  # noqa: BLE001 - fall back to the figures module's own estimate
        return None


#: The example of the paper's Fig. 3 (flow directions on an aeroplane attacked towards "bicycle"): the flow figures
#: show this attack when a victim has a successful one, else the attack chosen by :func:`_flow_order`.
PAPER_FLOW_EXAMPLE = ("aeroplane", "bicycle")


def _flow_order(row: JobRow) -> Tuple[Any, ...]:
    """Sort key of the flow figures' candidates: the paper's example first, then a successful attack on the densest
    mesh with the largest flow (the clearest picture of the flow field)."""
    rec = row.record or {}
    paper = (row.spec.get("source_class"), row.spec.get("target")) == PAPER_FLOW_EXAMPLE and bool(rec.get("success"))
    return (not paper, not rec.get("success"), -(rec.get("num_vertices") or 0),
            -((rec.get("distances") or {}).get("max_displacement") or 0.0), row.job_id)


def _flow_pair(rows: List[JobRow], source: ArtifactSource,
               ) -> Optional[Tuple[JobRow, Tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """The first candidate (in :func:`_flow_order`) whose meshes are on this machine; else the first one,
    regenerated when ``source`` regenerates (one job, not every candidate)."""
    ordered = sorted(rows, key=_flow_order)
    for row in ordered:
        if source.folder(row, regenerate=False) is not None:
            pair = _load_pair(row, source)
            if pair is not None:
                return row, pair
    if ordered and source.root is not None:
        pair = _load_pair(ordered[0], source)
        if pair is not None:
            return ordered[0], pair
    return None


def flow_stamp(row: JobRow, victim: str) -> str:
    """What the flow figures of ``victim`` are drawn from when they show ``row``'s attack, hashed."""
    return _stamp("flow", {"victim": victim, "job": row.job_id, "success": bool(row.record.get("success"))})


def _flow_paths(fig_dir: Path, victim: str) -> List[Path]:
    """The flow heatmaps, quiver plot and curvature scatter of ``victim``, in that order."""
    slug = slug_of(victim)
    return [fig_dir / f"flow_heatmap_{slug}.png", fig_dir / f"flow_quiver_{slug}.png",
            fig_dir / f"curvature_{slug}.png"]


def flow_figures(rows: List[JobRow], fig_dir: Path, source: Optional[ArtifactSource] = None, *,
                 redraw: bool = False) -> Tuple[List[Path], Dict[str, Dict[str, Any]]]:
    """Flow heatmaps (rendered and canonical view), quiver plot and flow vs curvature of one shape attack per victim
    (the paper's Fig. 3); returns the figures written and, per victim, the flow / curvature correlations. Figures
    already in ``fig_dir`` that record the first candidate's :func:`flow_stamp` are kept (with the correlations they
    record) unless ``redraw``."""
    from meshadv.experiments import figures

    if source is None:
        source = ArtifactSource(Path("."), None)
    written: List[Path] = []
    correlations: Dict[str, Dict[str, Any]] = {}
    by_victim: Dict[str, List[JobRow]] = defaultdict(list)
    for row in rows:
        if row.spec.get("perturbation") == "shape" and not row.record.get("skipped"):
            by_victim[victim_label(row.spec)].append(row)
    for victim, vrows in sorted(by_victim.items()):
        paths = _flow_paths(fig_dir, victim)
        first = min(vrows, key=_flow_order)
        texts = [png_text(p) for p in paths]
        stamp = flow_stamp(first, victim)
        if not redraw and CORRELATIONS_KEY in texts[2] and all(t.get(STAMP_KEY) == stamp for t in texts):
            written.extend(paths)
            correlations[victim] = json.loads(texts[2][CORRELATIONS_KEY])
            continue
        found = _flow_pair(vrows, source)
        if found is None:
            continue
        row, (v, va, f) = found
        view = row.spec["views"][0]
        label = f"{victim}: {row.spec['source_class']} → {row.spec['target']}" + (
            "" if row.record.get("success") else " (attack failed)")
        figures.flow_heatmaps(v, va, f, paths[0], view=view, title=label)
        figures.flow_quiver(v, va, f, paths[1], title=f"{label}: flow directions")
        _, corr = figures.curvature_scatter(v, va, f, paths[2], curvature=_curvature(v, f),
                                            eye=figures.camera_eye(view), title=label)
        correlations[victim] = {**corr, "job_id": row.job_id}
        stamp = flow_stamp(row, victim)
        for path in paths:
            add_png_text(path, {STAMP_KEY: stamp, **({CORRELATIONS_KEY: json.dumps(correlations[victim])}
                                                     if path == paths[2] else {})})
        written.extend(paths)
    return written, correlations
