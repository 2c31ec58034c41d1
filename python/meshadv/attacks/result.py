"""The result of a mesh attack and its atomic on-disk form.

:class:`AttackResult` holds one adversarial mesh per target, the success of every (target, view) pair measured on the
final meshes re-rendered from scratch, the distances, final scores, loss history, step count and wall time.
:meth:`AttackResult.save` writes::

    out_dir/
      adversarial.ply, adversarial.obj (+ .mtl)       one target; several: adversarial_t{i}.ply / .obj
      before_v{j}.png                                 pristine renders of the victim views
      after_v{j}.png                                  adversarial renders (several targets: after_t{i}_v{j}.png)
      result.json                                     the record (written last)

Every file is first written into a private temporary folder inside ``out_dir`` and then moved into place with
``os.replace`` (atomic on one file system); an earlier ``result.json`` is removed first and the new one moved last,
so a folder with a ``result.json`` always holds a complete result, also when a save into a used folder is killed.
:func:`load_result_record` reads the record back.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple, Union

import torch
from torch import Tensor

from meshadv.util.atomic import write_json_atomic
from meshadv.util.png import save_png

__all__ = ["AttackResult", "load_result_record", "RESULT_FILE", "enough_views", "held_out_sentence",
           "held_out_verdict", "perceptibility_line"]

#: Name of the JSON record inside a result folder.
RESULT_FILE = "result.json"

#: Slack of the ``success_fraction`` comparison, so a fraction that equals it up to float rounding counts.
_FRACTION_SLACK = 1e-9


def enough_views(fraction: Any, success_fraction: float) -> Any:
    """Whether ``fraction`` (a float or a tensor of fractions of adversarial views) reaches ``success_fraction``:
    ``fraction >= success_fraction - 1e-9``, a bool or a bool tensor like ``fraction``."""
    return fraction >= success_fraction - _FRACTION_SLACK


def held_out_verdict(held_out_success: Optional[Tensor], fraction: Optional[float], num_targets: int) -> Tensor:
    """The held-out part of a verdict: bool ``(T,)``, each target holds on at least ``fraction`` of its held-out
    views.

    Args:
        held_out_success: bool ``(T, V_held)``: the target holds on each held-out view, or ``None`` for none.
        fraction: ``None`` (no held-out verdict: all true) or the fraction in ``(0, 1]`` the target needs (with no
            held-out views to judge on: all false).
        num_targets: ``T``.

    Example:
        >>> held_out_verdict(torch.tensor([[True] * 4 + [False], [True] * 3 + [False] * 2]), 0.8, 2).tolist()
        [True, False]
    """
    if fraction is None:
        return torch.ones(num_targets, dtype=torch.bool)
    if held_out_success is None or held_out_success.shape[-1] == 0:
        return torch.zeros(num_targets, dtype=torch.bool)
    return enough_views(held_out_success.float().mean(dim=-1), fraction)


def held_out_sentence(held: int, total: int, fraction: Optional[float]) -> str:
    """The held-out verdict of one target in words: ``"held-out views (never optimised on): the target holds on
    4/5 (80%); SUCCESS needs >= 80%"`` (``fraction`` ``None``: "not part of the verdict")."""
    share = 100 * held / max(total, 1)
    line = f"held-out views (never optimised on): the target holds on {held}/{total} ({share:.0f}%)"
    if fraction is None:
        return line + "; not part of the verdict"
    return line + f"; SUCCESS needs >= {100 * fraction:.0f}%"


def _json_float(value: float) -> Optional[float]:
    """A float for JSON (``None`` for nan / inf)."""
    value = float(value)
    return value if math.isfinite(value) else None


def _get(distances: Dict[str, Any], name: str) -> float:
    """``distances[name]`` as a float (``nan`` when absent or ``None``)."""
    value = distances.get(name)
    return math.nan if value is None else float(value)


def perceptibility_line(distances: Dict[str, Any]) -> str:
    """The perceptibility measures of one target's ``distances`` on one line, the way a person reads them:
    ``"move max 1.2% p95 0.4% of the diagonal, normals mean 2.1 p95 8.3 deg, edge strain p95 0.031 max 0.4,
    colours p95 0, SSIM held-out mean 0.98 min 0.95"`` (``nan`` for a measure the record lacks)."""
    return (f"move max {100 * _get(distances, 'max_displacement'):.3g}% p95 "
            f"{100 * _get(distances, 'p95_displacement'):.3g}% of the diagonal, normals mean "
            f"{_get(distances, 'normal_change_mean_deg'):.3g} p95 {_get(distances, 'normal_change_p95_deg'):.3g} "
            f"deg, edge strain p95 {_get(distances, 'edge_strain_p95'):.3g} max "
            f"{_get(distances, 'edge_strain_max'):.3g}, colours p95 "
            f"{_get(distances, 'color_change_p95'):.3g}, SSIM held-out mean "
            f"{_get(distances, 'ssim_held_out_mean'):.3g} min {_get(distances, 'ssim_held_out_min'):.3g}")


def load_result_record(out_dir: Union[str, Path]) -> Dict[str, Any]:
    """Read the ``result.json`` record of a saved result.

    Raises:
        FileNotFoundError: no record in ``out_dir``.
    """
    path = Path(out_dir) / RESULT_FILE
    if not path.is_file():
        raise FileNotFoundError(f"out_dir {out_dir} holds no {RESULT_FILE}")
    return json.loads(path.read_text(encoding="utf-8"))


@dataclass(frozen=True)
class AttackResult:
    """Outcome of a shape or texture attack on ``T`` targets over ``V`` victim views.

    Attributes:
        original: the pristine mesh.
        adversarial: ``T`` adversarial meshes (the least-distorted successful one per target, else the best attempt).
        perturbation: ``"shape"`` or ``"texture"``.
        criteria: JSON records of the ``T`` bound criteria.
        success: bool ``(T, V)``: adversarial on each victim view, re-rendered from the final mesh.
        scores: ``(T, V)`` criterion score of each final render (target probability / best detection score).
        original_scores: ``(T, V)`` the same score on the pristine renders.
        margins: ``(T, V)`` criterion margins of the final renders (positive = adversarial).
        top1: int64 ``(T, V)`` top-1 classes of the final renders (classifiers) or ``None``.
        original_top1: int64 ``(V,)`` top-1 classes of the pristine renders (classifiers) or ``None``.
        eval_success: bool ``(T, V_eval)`` on the held-out views, or ``None``.
        eval_scores: ``(T, V_eval)`` or ``None``.
        distances: one dict per target: ``laplacian_sum``, ``laplacian_pair_mean``, ``color_rmse``, ...
            (``attacks.distances.mesh_distances``) and the perceptibility measures (``max_displacement``,
            ``p95_displacement``, ``normal_change_*_deg``, ``color_change_p95``, ``ssim_held_out_*``;
            ``meshadv.perceptibility.measures``).
        lambdas: the ``lambda`` that produced each kept mesh (``nan`` when no round succeeded).
        loss_history: one JSON-able dict per optimiser step (round, step, per-target loss, adversarial and
            perceptual terms, distance, worst-view margin; ``None`` for targets no longer optimised).
        steps: total optimiser steps over all rounds.
        steps_to_success: per target, the total step count at which the criterion first held (or ``None``).
        time_to_success: per target, seconds from the start until then (or ``None``).
        wall_time: seconds for the whole attack.
        interrupted: True when the attack was stopped by Ctrl-C (the result is the best found so far).
        success_fraction: fraction of views that must be adversarial for a target to count as attacked.
        original_images: ``(V, 3, H, W)`` pristine renders.
        images: ``(T, V, 3, H, W)`` final adversarial renders.
        view_records: JSON records of the victim views; ``eval_view_records`` of the held-out views.
        config: the attack's hyper-parameters.
        victim: the victim's name.
        class_names: the victim's class names (to label ``top1``), may be empty.
        perceptibility_cap: the record of the attack's perceptibility cap
            (``meshadv.perceptibility.PerceptibilityCap.to_record``), or ``None`` for none: a target whose final mesh
            lies outside it has not succeeded, whatever its views say.
        held_out_fraction: ``None`` (the verdict of the victim views alone), or the fraction of the held-out views
            (``eval_success``) a target must also hold on to have succeeded.
    """

    original: Any
    adversarial: Tuple[Any, ...]
    perturbation: str
    criteria: Tuple[Dict[str, Any], ...]
    success: Tensor
    scores: Tensor
    original_scores: Tensor
    margins: Tensor
    top1: Optional[Tensor]
    original_top1: Optional[Tensor]
    eval_success: Optional[Tensor]
    eval_scores: Optional[Tensor]
    distances: Tuple[Dict[str, float], ...]
    lambdas: Tuple[float, ...]
    loss_history: Tuple[Dict[str, Any], ...]
    steps: int
    steps_to_success: Tuple[Optional[int], ...]
    time_to_success: Tuple[Optional[float], ...]
    wall_time: float
    interrupted: bool
    success_fraction: float
    original_images: Tensor
    images: Tensor
    view_records: Tuple[Dict[str, Any], ...]
    eval_view_records: Optional[Tuple[Dict[str, Any], ...]]
    config: Dict[str, Any]
    victim: str
    class_names: Tuple[str, ...] = field(default=(), repr=False)
    perceptibility_cap: Optional[Dict[str, Any]] = None
    held_out_fraction: Optional[float] = None

    @property
    def num_targets(self) -> int:
        """Number of targets ``T``."""
        return len(self.adversarial)

    @property
    def mesh(self) -> Any:
        """The adversarial mesh of the first (often only) target."""
        return self.adversarial[0]

    @property
    def success_rate(self) -> Tensor:
        """Fraction of victim views that are adversarial, per target ``(T,)``."""
        return self.success.float().mean(dim=1)

    @property
    def inside_cap(self) -> Tensor:
        """bool ``(T,)``: each target's final mesh lies inside the perceptibility cap (all true without one)."""
        if self.perceptibility_cap is None:
            return torch.ones(self.num_targets, dtype=torch.bool)
        from meshadv.perceptibility.cap import PerceptibilityCap

        cap = PerceptibilityCap.from_record(self.perceptibility_cap)
        return torch.tensor([bool(cap.admits(d)) for d in self.distances], dtype=torch.bool)

    def cap_violations(self, target: int) -> List[str]:
        """The ceilings of the perceptibility cap that target ``target``'s final mesh exceeds (empty without a cap)."""
        if self.perceptibility_cap is None:
            return []
        from meshadv.perceptibility.cap import PerceptibilityCap

        return PerceptibilityCap.from_record(self.perceptibility_cap).violations(self.distances[target])

    @property
    def held_out_rate(self) -> Optional[Tensor]:
        """Fraction of the held-out views on which each target holds, ``(T,)``, or ``None`` without held-out
        views."""
        return None if self.eval_success is None else self.eval_success.float().mean(dim=1)

    @property
    def holds_held_out(self) -> Tensor:
        """bool ``(T,)``: the target holds on at least ``held_out_fraction`` of the held-out views (all true without
        a held-out verdict; all false when one is asked for and there are no held-out views)."""
        return held_out_verdict(self.eval_success, self.held_out_fraction, self.num_targets)

    @property
    def succeeded(self) -> Tensor:
        """bool ``(T,)``: the target holds on at least ``success_fraction`` of the victim views, on at least
        ``held_out_fraction`` of the held-out views (when asked for), and its mesh lies inside the perceptibility
        cap."""
        return enough_views(self.success_rate, self.success_fraction) & self.inside_cap & self.holds_held_out

    def _name(self, idx: int) -> str:
        return self.class_names[idx] if 0 <= idx < len(self.class_names) else str(idx)

    def summary(self) -> str:
        """A few human-readable lines: per target, success, distances and top-1 labels."""
        cap = "none" if self.perceptibility_cap is None else ", ".join(
            f"{k} <= {v:g}" for k, v in self.perceptibility_cap.items() if v is not None) or "none"
        lines = [f"{self.perturbation} attack on {self.victim}: {self.steps} steps in {self.wall_time:.1f} s"
                 + (" (interrupted)" if self.interrupted else "") + f"; perceptibility cap: {cap}"]
        for t, crit in enumerate(self.criteria):
            d = self.distances[t]
            status = "SUCCESS" if bool(self.succeeded[t]) else "failed"
            outside = self.cap_violations(t)
            if outside:
                status += f" (outside the perceptibility cap: {'; '.join(outside)})"
            views_hold = bool(enough_views(self.success_rate[t], self.success_fraction))
            if views_hold and not bool(self.holds_held_out[t]):  # the held-out views are why it failed
                status += f" (held-out views: fewer than {100 * float(self.held_out_fraction or 0):.0f}% hold)"
            line = (f"  {crit.get('label', '?')}: {status} on {int(self.success[t].sum())}/{self.success.shape[1]} "
                    f"views; {perceptibility_line(d)}; laplacian_pair_mean={_get(d, 'laplacian_pair_mean'):.4g} "
                    f"laplacian_sum={_get(d, 'laplacian_sum'):.4g} rmse={_get(d, 'color_rmse'):.4g}")
            if "texel_rmse" in d:
                line += f" texel_rmse={d['texel_rmse']:.4g} texture_tv={d['texture_tv']:.4g}"
            if self.eval_success is not None:
                line += (f"; held-out views (never optimised on) {int(self.eval_success[t].sum())}/"
                         f"{self.eval_success.shape[1]}")
                if self.held_out_fraction is not None:
                    line += f" (SUCCESS needs >= {100 * self.held_out_fraction:.0f}%)"
            lines.append(line)
            if self.top1 is not None:
                lines.append("    top-1: " + ", ".join(self._name(int(i)) for i in self.top1[t].tolist()))
        return "\n".join(lines)

    def mesh_filenames(self, target: int) -> Tuple[str, str]:
        """File names ``(ply, obj)`` of target ``target``'s adversarial mesh inside a saved result."""
        stem = "adversarial" if self.num_targets == 1 else f"adversarial_t{target}"
        return f"{stem}.ply", f"{stem}.obj"

    def to_record(self) -> Dict[str, Any]:
        """The JSON-able record written as ``result.json`` (no images, no mesh data)."""
        def names(t: Optional[Tensor]) -> Optional[List]:
            if t is None:
                return None
            return [[self._name(int(i)) for i in row] for row in t.reshape(-1, t.shape[-1]).tolist()]

        return {
            "perturbation": self.perturbation,
            "shading": getattr(self.original, "shading", "flat"),
            "victim": self.victim,
            "criteria": list(self.criteria),
            "succeeded": [bool(s) for s in self.succeeded.tolist()],
            "perceptibility_cap": self.perceptibility_cap,
            "inside_cap": [bool(s) for s in self.inside_cap.tolist()],
            "success": self.success.tolist(),
            "success_rate": self.success_rate.tolist(),
            "success_fraction": self.success_fraction,
            "scores": self.scores.tolist(),
            "original_scores": self.original_scores.tolist(),
            "margins": self.margins.tolist(),
            "top1": None if self.top1 is None else self.top1.tolist(),
            "top1_names": names(self.top1),
            "original_top1": None if self.original_top1 is None else self.original_top1.tolist(),
            "original_top1_names": None if self.original_top1 is None else names(self.original_top1.unsqueeze(0))[0],
            "eval_success": None if self.eval_success is None else self.eval_success.tolist(),
            "held_out_rate": None if self.held_out_rate is None else self.held_out_rate.tolist(),
            "held_out_fraction": self.held_out_fraction,
            "holds_held_out": [bool(s) for s in self.holds_held_out.tolist()],
            "eval_scores": None if self.eval_scores is None else self.eval_scores.tolist(),
            "distances": [{k: _json_float(v) for k, v in d.items()} for d in self.distances],
            "lambdas": [_json_float(v) for v in self.lambdas],
            "steps": self.steps,
            "steps_to_success": list(self.steps_to_success),
            "time_to_success": [None if v is None else float(v) for v in self.time_to_success],
            "wall_time": self.wall_time,
            "interrupted": self.interrupted,
            "views": list(self.view_records),
            "eval_views": None if self.eval_view_records is None else list(self.eval_view_records),
            "config": self.config,
            "meshes": [list(self.mesh_filenames(t)) for t in range(self.num_targets)],
            "num_vertices": int(self.original.vertices.shape[0]),
            "num_faces": int(self.original.faces.shape[0]),
            "loss_history": list(self.loss_history),
        }

    def _write_meshes(self, folder: Path) -> None:
        """Every target's adversarial mesh as PLY and OBJ (:meth:`mesh_filenames`) into ``folder``; a SurfaceMesh
        (textured or vertex-coloured) also as GLB, its OBJ with an MTL and the texture PNG or with its vertex
        colours (``v x y z r g b``), its PLY with the vertex colours (else per face)."""
        from meshadv.mesh.surface_mesh import SurfaceMesh, save_any_mesh

        for t, mesh in enumerate(self.adversarial):
            ply, obj = self.mesh_filenames(t)
            save_any_mesh(mesh, folder / obj)
            if isinstance(mesh, SurfaceMesh):
                save_any_mesh(mesh, folder / Path(obj).with_suffix(".glb").name)
            save_any_mesh(mesh, folder / ply)

    def _write_images(self, folder: Path) -> None:
        """The pristine and adversarial renders of every view as PNG into ``folder``."""
        for v in range(self.original_images.shape[0]):
            save_png(self.original_images[v], folder / f"before_v{v}.png")
            for t in range(self.num_targets):
                name = f"after_v{v}.png" if self.num_targets == 1 else f"after_t{t}_v{v}.png"
                save_png(self.images[t, v], folder / name)

    def save(self, out_dir: Union[str, Path], *, images: bool = True) -> Path:
        """Write meshes (PLY and OBJ), PNG renders and ``result.json`` into ``out_dir`` atomically.

        Args:
            out_dir: folder to write into (created if needed; existing files of the same names are replaced).
            images: also write the before / after PNG renders.

        Returns:
            The path of ``result.json``.

        Raises:
            ValueError: ``out_dir`` exists and is not a folder.
        """
        out = Path(out_dir)
        if out.exists() and not out.is_dir():
            raise ValueError(f"out_dir {out} exists and is not a folder")
        out.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=".staging-", dir=str(out)))
        try:
            written: List[str] = []
            self._write_meshes(staging)
            if images:
                self._write_images(staging)
            # an earlier result's record goes first: a kill while the new files replace the old ones leaves a folder
            # without result.json (incomplete), never an old record beside new meshes
            (out / RESULT_FILE).unlink(missing_ok=True)
            for path in sorted(staging.iterdir()):
                os.replace(path, out / path.name)
                written.append(path.name)
            record = self.to_record()
            record["files"] = sorted(written) + [RESULT_FILE]
            write_json_atomic(record, out / RESULT_FILE)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        return out / RESULT_FILE
