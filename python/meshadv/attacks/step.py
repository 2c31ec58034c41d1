"""One step of the attack loop: render the active targets, run the victim, differentiate the update rule's objective.

A step takes the parameters of the ``K`` active targets, renders their ``K x V`` images (mesh-major), runs the victim
once, and computes per target the adversarial loss (the criterion's loss, mean over the views), the perceptual loss
and the distortion; the update rule's ``objective`` of those is back-propagated into the parameters' ``.grad``.
:func:`serial_step` does it in the calling thread; :func:`pipelined_step` splits the images over the step workers
(:mod:`meshadv.attacks.pipeline`, which explains the graph cut) and fills ``.grad`` the same way.

Both return a :class:`StepTerms`: ``(adv, perceptual, distance, output, margins)``, which unpacks as a tuple.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, List, NamedTuple, Optional, Tuple

import torch
from torch import Tensor

from meshadv.attacks.criteria import Criterion
from meshadv.attacks.outputs import cat_outputs, output_tensors, rebuild_output, slice_output
from meshadv.attacks.pipeline import StepWorkers, split_images
from meshadv.render.setup import RenderSetup

if TYPE_CHECKING:
    from meshadv.attacks.base import MeshAttack
    from meshadv.attacks.update import UpdateRule

__all__ = ["AttackCall", "StepTerms", "serial_step", "pipelined_step", "adversarial_terms"]


@dataclass(frozen=True)
class AttackCall:
    """What one attack call works on: the mesh, the views, the victim, the render setup and the mesh's edges.

    Attributes:
        mesh: the pristine ``Mesh``.
        views: the ``ViewSet`` of the ``V`` victim views (detached).
        victim: the victim.
        setup: how the mesh is rendered.
        edges: int64 ``(E, 2)`` unique undirected edges of the mesh.
    """

    mesh: Any
    views: Any
    victim: Any
    setup: RenderSetup
    edges: Tensor


class StepTerms(NamedTuple):
    """What a step measured, per active target (``K`` of them), on the images the gradient was taken from.

    Attributes:
        adv: ``(K,)`` adversarial loss (differentiable).
        perceptual: ``(K,)`` perceptual loss (differentiable).
        distance: ``(K,)`` distortion (differentiable).
        output: the victim's output for the ``K x V`` images.
        margins: ``(K, V)`` criterion margins (detached).
    """

    adv: Tensor
    perceptual: Tensor
    distance: Tensor
    output: Any
    margins: Tensor


def adversarial_terms(attack: "MeshAttack", output: Any, criteria: List[Criterion],
                      num_views: int) -> Tuple[Tensor, Tensor]:
    """Per-target adversarial loss ``(K,)`` (differentiable; the attack's ``loss`` and ``kappa``) and per-view margins
    ``(K, V)`` (detached) of a victim output of ``K x V`` images (mesh-major)."""
    parts = [slice_output(output, a * num_views, (a + 1) * num_views) for a in range(len(criteria))]
    adv = torch.stack([c.loss(o, loss=attack.loss, kappa=attack.kappa).mean() for c, o in zip(criteria, parts)])
    with torch.no_grad():
        margins = torch.stack([c.margin(o).detach() for c, o in zip(criteria, parts)])
    return adv, margins


def serial_step(attack: "MeshAttack", p: Tensor, idx: Tensor, criteria: List[Criterion], call: AttackCall,
                views: Any, rule: "UpdateRule") -> StepTerms:
    """One step in the calling thread: forward, objective, ``backward()`` into the parameters' ``.grad``.

    Args:
        attack: the attack (its parametrisation, perceptual term and loss settings).
        p: ``(K, ...)`` the active targets' rows of the parameters (``params[idx]``, still in their graph).
        idx: int64 ``(K,)`` the active targets.
        criteria: the ``K`` bound criteria.
        call: the attack call.
        views: the step's (possibly jittered) views.
        rule: the update rule, whose ``objective`` is differentiated.
    """
    verts, colors = attack._apply(p, call.mesh, call.edges)
    images, alpha = call.setup.render(verts, call.mesh.faces, colors, views, rule.edge_gradient,
                                      visibility_gradient=rule.visibility_gradient)
    output = call.victim(images)
    adv, margins = adversarial_terms(attack, output, criteria, len(views))
    perc, dist = attack._terms(p, call.mesh, call.edges, images, alpha, len(views))
    rule.objective(adv, perc, dist, idx).backward()
    return StepTerms(adv, perc, dist, output, margins)


class _ChunkForward(NamedTuple):
    """One worker's forward pass: its images and alpha (in the render graph), the cut image leaf and the victim's
    output of it."""

    images: Tensor
    alpha: Tensor
    cut_images: Tensor
    output: Any


def _render_chunk(attack: "MeshAttack", leaf: Tensor, first: int, blocks: List[Tuple[int, int, int, int]],
                  call: AttackCall, views: Any, edge_gradient: float, num_threads: int,
                  visibility_gradient: str = "nmr") -> Tuple[Tensor, Tensor]:
    """Render one chunk's blocks ``(k0, k1, v0, v1)`` (targets ``k0..k1-1`` of the step, the first being ``first``,
    from views ``v0..v1-1``) for the chunk's parameters ``leaf`` (the rule's ``edge_gradient`` and
    ``visibility_gradient``) on the worker's own ``num_threads`` renderer threads; images and alpha concatenated in
    block order."""
    num_v = len(views)
    verts, colors = attack._apply(leaf, call.mesh, call.edges)
    parts = [call.setup.render(verts[k0 - first:k1 - first], call.mesh.faces,
                               colors if colors.dim() == 2 else colors[k0 - first:k1 - first],
                               views if (v0, v1) == (0, num_v) else views[v0:v1], edge_gradient, num_threads,
                               visibility_gradient)
             for k0, k1, v0, v1 in blocks]
    images = parts[0][0] if len(parts) == 1 else torch.cat([im for im, _ in parts])
    alpha = parts[0][1] if len(parts) == 1 else torch.cat([al for _, al in parts])
    return images, alpha


def _backward_chunk(chunk: _ChunkForward, cut_outputs: List[Optional[Tensor]], cut_alpha: Tensor) -> None:
    """Back-propagate the cotangents that the objective left on a chunk's cut output and alpha: through the victim
    into the cut images, then with the images' cotangent through the render into the chunk's parameter leaf."""
    pairs = [(t, cut.grad) for t, cut in zip(output_tensors(chunk.output), cut_outputs) if cut is not None
             and cut.grad is not None]
    if pairs:
        torch.autograd.backward([t for t, _ in pairs], [g for _, g in pairs])
    pairs = [(t, g) for t, g in ((chunk.images, chunk.cut_images.grad), (chunk.alpha, cut_alpha.grad))
             if g is not None and t.requires_grad]
    if pairs:
        torch.autograd.backward([t for t, _ in pairs], [g for _, g in pairs])


def pipelined_step(attack: "MeshAttack", params: Tensor, idx: Tensor, criteria: List[Criterion], call: AttackCall,
                   views: Any, rule: "UpdateRule", workers: StepWorkers) -> StepTerms:
    """The step of :func:`serial_step` with the images split over ``workers`` (:mod:`meshadv.attacks.pipeline`);
    same returns (``output`` detached), the parameters' ``.grad`` filled the same way.

    Args:
        params: ``(T, ...)`` all the targets' parameters (the leaf the update rule steps).
        workers: the step workers.
        attack, idx, criteria, call, views, rule: as in :func:`serial_step`.
    """
    num_v = len(views)
    chunks = split_images(len(criteria), num_v, workers.workers)
    rows = [(blocks[0][0], blocks[-1][1]) for blocks in chunks]  # the targets each chunk renders
    leaves = [params[idx[a:b]].detach().requires_grad_(True) for a, b in rows]

    def forward(c: int) -> _ChunkForward:
        images, alpha = _render_chunk(attack, leaves[c], rows[c][0], chunks[c], call, views,
                                      rule.edge_gradient, workers.threads, rule.visibility_gradient)
        x = images.detach().requires_grad_(True)
        return _ChunkForward(images, alpha, x, call.victim(x))

    fwd = workers.map(forward, list(range(len(chunks))))
    # cut at the victim's output and at alpha: their cotangents come from the objective below
    outs = [[None if t is None else t.detach().requires_grad_(t.requires_grad) for t in output_tensors(f.output)]
            for f in fwd]
    alphas = [f.alpha.detach().requires_grad_(f.alpha.requires_grad) for f in fwd]
    output = cat_outputs([rebuild_output(f.output, o) for f, o in zip(fwd, outs)])
    adv, margins = adversarial_terms(attack, output, criteria, num_v)
    p = params[idx]
    perc, dist = attack._terms(p, call.mesh, call.edges, torch.cat([f.cut_images for f in fwd]), torch.cat(alphas),
                               num_v)
    rule.objective(adv, perc, dist, idx).backward()

    def backward(c: int) -> Optional[Tensor]:
        _backward_chunk(fwd[c], outs[c], alphas[c])
        return leaves[c].grad

    grads = workers.map(backward, list(range(len(chunks))))
    _accumulate_chunk_grads(params, idx, rows, grads)
    return StepTerms(adv, perc, dist, output.detach() if isinstance(output, Tensor) else output, margins)


def _accumulate_chunk_grads(params: Tensor, idx: Tensor, rows: List[Tuple[int, int]],
                            grads: List[Optional[Tensor]]) -> None:
    """Add each chunk's leaf gradient into ``params.grad`` at its targets' rows, in chunk order."""
    with torch.no_grad():
        for (a, b), grad in zip(rows, grads):
            if grad is None:
                continue
            if params.grad is None:
                params.grad = torch.zeros_like(params)
            params.grad.index_put_((idx[a:b],), grad, accumulate=True)
