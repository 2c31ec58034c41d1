"""How far an adversarial mesh is from its pristine version in terms a person sees: moves, turns and recolouring.

* :func:`vertex_moves` -- the largest and the 95th-percentile vertex move, as fractions of the pristine mesh's
  bounding-box diagonal (``max_displacement``, ``p95_displacement``). A torn wing shows up in the largest move.
* :func:`normal_changes` -- the angle, in degrees, between each face's normal before and after the attack, summarised
  over the surface: weighted by the pristine face areas, the mean (``normal_change_mean_deg``) and the 95th percentile
  (``normal_change_p95_deg``: the angle that 95% of the surface area turns by at most). A crumpled or folded surface
  shows up here even when its vertices move little.

* :func:`edge_strains` -- the relative change of each edge's length, ``|l' / l - 1|``, weighted by the pristine
  edge lengths: the 95th percentile (``edge_strain_p95``). A thin part broken into fragments, or a surface dented in
  a fold, stretches and squeezes its edges even where its faces turn little; a smooth small bend keeps them. The
  largest strain of any edge (``edge_strain_max``, each edge counted at least :data:`EDGE_STRAIN_FLOOR` of the
  diagonal long) shows a thin part torn open: the short edges across a wing's thickness stretched many times over.

* :func:`color_changes` -- the change of each face's RGB colour (Euclidean, in ``[0, sqrt(3)]``), weighted by the
  pristine face areas: the 95th percentile (``color_change_p95``). A texture attack's bright specks show up here even
  when the colour RMSE over all faces is small.

All accept a batch of adversarial meshes (``(K, N, 3)`` vertices) and return ``(K,)`` tensors, so the attack loop can
check every step of every target; :func:`surface_measures` them as plain floats for one mesh pair.

Example:
    >>> import torch
    >>> v = torch.tensor([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); f = torch.tensor([[0, 1, 2]])
    >>> moved = v.clone(); moved[2, 2] = 1.0                        # lift one corner by 1: the face turns 45 degrees
    >>> round(float(normal_changes(moved, v, f)["normal_change_mean_deg"]), 3)
    45.0
"""

from __future__ import annotations

import math
from typing import Dict

import torch
from torch import Tensor

from meshadv.mesh.adjacency import vertex_edges
from meshadv.mesh.structure import bbox_diagonal

__all__ = ["vertex_moves", "face_normal_turns", "normal_changes", "edge_strains", "color_changes", "surface_measures",
           "SURFACE_MEASURES", "PERCENTILE", "EDGE_STRAIN_FLOOR"]

#: The percentile of the ``p95_*`` measures.
PERCENTILE = 0.95

#: The shortest length, as a fraction of the bounding-box diagonal, that ``edge_strain_max`` divides an edge's change
#: by: remeshing and CAD files leave slivers a thousandth of that long, which an invisible move stretches many times.
EDGE_STRAIN_FLOOR = 0.0025

#: One line per measure, for tables and reports.
SURFACE_MEASURES = {
    "max_displacement": "largest vertex move / bounding-box diagonal",
    "p95_displacement": "95th-percentile vertex move / bounding-box diagonal",
    "normal_change_mean_deg": "area-weighted mean change of the face normals, degrees",
    "normal_change_p95_deg": "area-weighted 95th-percentile change of the face normals, degrees",
    "edge_strain_p95": "edge-length-weighted 95th-percentile relative change of the edge lengths |l'/l - 1|",
    "edge_strain_max": "largest change of an edge's length |l' - l| / max(l, 0.25% of the diagonal)",
    "color_change_p95": "area-weighted 95th-percentile change of the face colours (RGB distance, 0 to sqrt 3)",
}


def _batched(vertices_adv: Tensor, vertices: Tensor) -> Tensor:
    """``vertices_adv`` as ``(K, N, 3)``, checked against the pristine ``(N, 3)``."""
    if vertices.dim() != 2 or vertices.shape[1] != 3 or vertices.shape[0] == 0:
        raise ValueError(f"vertices must have shape (N, 3) with N > 0, got {tuple(vertices.shape)}")
    batch = vertices_adv.unsqueeze(0) if vertices_adv.dim() == 2 else vertices_adv
    if batch.dim() != 3 or batch.shape[1:] != vertices.shape:
        raise ValueError(f"vertices_adv must have shape (N, 3) or (K, N, 3) with N = {vertices.shape[0]}, "
                         f"got {tuple(vertices_adv.shape)}")
    return batch


def vertex_moves(vertices_adv: Tensor, vertices: Tensor) -> Dict[str, Tensor]:
    """The largest and 95th-percentile vertex move relative to the pristine bounding-box diagonal.

    The percentile is ``torch.quantile``'s (linear interpolation between the sorted moves of the ``N`` vertices).

    Args:
        vertices_adv: ``(N, 3)`` or ``(K, N, 3)`` adversarial vertices.
        vertices: ``(N, 3)`` pristine vertices (not all at one point).

    Returns:
        ``{"max_displacement": (K,), "p95_displacement": (K,)}`` (fractions; ``K = 1`` for one mesh).

    Raises:
        ValueError: bad shapes, or a pristine mesh of zero extent.

    Example:
        >>> v = torch.tensor([[0., 0, 0], [3, 4, 0]])                   # diagonal 5
        >>> moved = v + torch.tensor([[0., 0, 1], [0, 0, 0]])
        >>> [round(float(x), 6) for x in vertex_moves(moved, v).values()]  # 1/5; between 0 and 1/5 at 95%
        [0.2, 0.19]
    """
    batch = _batched(vertices_adv, vertices)
    diagonal = float(bbox_diagonal(vertices))
    if not diagonal > 0:
        raise ValueError("vertices span a bounding box of zero extent: moves relative to it are undefined")
    moves = (batch - vertices).norm(dim=-1).float() / diagonal
    return {"max_displacement": moves.max(dim=1).values,
            "p95_displacement": torch.quantile(moves, PERCENTILE, dim=1)}


def _face_cross(vertices: Tensor, faces: Tensor) -> Tensor:
    """Unnormalised face normals ``(..., M, 3)`` (twice the area, along the normal of the winding)."""
    a, b, c = (vertices[..., faces[:, i], :] for i in range(3))
    return torch.cross(b - a, c - a, dim=-1)


def _weighted_upper(values: Tensor, weights: Tensor) -> Tensor:
    """Per row of ``values`` ``(K, M)``, the smallest value such that the entries at most it hold at least
    :data:`PERCENTILE` of the total of ``weights`` ``(M,)`` (a weighted lower quantile, no interpolation)."""
    order = torch.argsort(values, dim=1)
    ordered = torch.gather(values, 1, order)
    cumulative = torch.cumsum(weights[order], dim=1) / weights.sum()
    # a hair of slack, so float sums that land just below the percentile still count
    wanted = torch.full((values.shape[0], 1), PERCENTILE - 1e-12, dtype=cumulative.dtype)
    index = torch.searchsorted(cumulative.contiguous(), wanted).clamp(max=values.shape[1] - 1)
    return torch.gather(ordered, 1, index).squeeze(1)


def _check_faces(faces: Tensor) -> Tensor:
    if faces.dim() != 2 or faces.shape[1] != 3 or faces.shape[0] == 0:
        raise ValueError(f"faces must have shape (M, 3) with M > 0, got {tuple(faces.shape)}")
    return faces.long()


def _areas(vertices: Tensor, faces: Tensor) -> Tensor:
    """Pristine face weights (twice the areas), float64 ``(M,)``.

    Raises:
        ValueError: every face has zero area."""
    weights = _face_cross(vertices.double(), faces).norm(dim=-1)
    if not float(weights.sum()) > 0:
        raise ValueError("every face has zero area: an area-weighted measure is undefined")
    return weights


def face_normal_turns(vertices_adv: Tensor, vertices: Tensor, faces: Tensor) -> "tuple[Tensor, Tensor]":
    """Each face's turn and its weight: the angle between its normal before and after, in degrees, and its pristine
    area (twice the area).

    The angle is ``atan2(|n x n'|, n . n')``, in ``[0, 180]``: a face folded over turns 180 degrees; a face that
    collapses to zero area counts as 90.

    Args:
        vertices_adv: ``(N, 3)`` or ``(K, N, 3)`` adversarial vertices.
        vertices: ``(N, 3)`` pristine vertices.
        faces: int ``(M, 3)`` triangles (``M >= 1``, at least one of positive area).

    Returns:
        ``(angles, weights)``: float64 ``(K, M)`` degrees and ``(M,)``.

    Raises:
        ValueError: bad shapes, or every face of zero area.

    Example:
        >>> v = torch.tensor([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); f = torch.tensor([[0, 1, 2]])
        >>> moved = v.clone(); moved[2, 2] = 1.0
        >>> angles, weights = face_normal_turns(moved, v, f)
        >>> round(float(angles[0, 0]), 3), float(weights[0])
        (45.0, 1.0)
    """
    batch = _batched(vertices_adv, vertices).double()
    faces = _check_faces(faces)
    weights = _areas(vertices, faces)
    before = _face_cross(vertices.double(), faces)  # (M, 3)
    after = _face_cross(batch, faces)  # (K, M, 3)
    sine = torch.cross(before.expand_as(after), after, dim=-1).norm(dim=-1)
    cosine = (before * after).sum(dim=-1)
    angles = torch.rad2deg(torch.atan2(sine, cosine))
    collapsed = after.norm(dim=-1) <= 1e-12 * weights.clamp(min=1e-300)
    return torch.where(collapsed, torch.full_like(angles, 90.0), angles), weights


def normal_changes(vertices_adv: Tensor, vertices: Tensor, faces: Tensor) -> Dict[str, Tensor]:
    """Area-weighted change of the face normals, in degrees: mean and 95th percentile.

    Each face's change is its turn (:func:`face_normal_turns`: the angle between its normal before and after, in
    ``[0, 180]``; a face that collapses to zero area counts as 90). The weights are the pristine face areas, so long
    thin CAD faces count by their size, not their number; faces of zero pristine area have no weight. The percentile
    is the smallest change ``a`` such that faces turning by at most ``a`` hold at least 95% of the area (a weighted
    lower quantile: no interpolation).

    Args:
        vertices_adv: ``(N, 3)`` or ``(K, N, 3)`` adversarial vertices.
        vertices: ``(N, 3)`` pristine vertices.
        faces: int ``(M, 3)`` triangles (``M >= 1``, at least one of positive area).

    Returns:
        ``{"normal_change_mean_deg": (K,), "normal_change_p95_deg": (K,)}``.

    Raises:
        ValueError: bad shapes, or every face of zero area.
    """
    angles, weights = face_normal_turns(vertices_adv, vertices, faces)
    mean = (angles * weights).sum(dim=1) / weights.sum()
    return {"normal_change_mean_deg": mean.float(), "normal_change_p95_deg": _weighted_upper(angles, weights).float()}


def edge_strains(vertices_adv: Tensor, vertices: Tensor, faces: Tensor) -> Dict[str, Tensor]:
    """Edge-length-weighted 95th percentile and the largest of the edges' strain ``|l' / l - 1|`` (``l``, ``l'``: an
    edge's pristine and adversarial length).

    Every undirected edge of ``faces`` counts once (an edge shared by two faces is one edge), weighted by its pristine
    length, so the many short edges of a finely meshed detail count by their extent, not their number; edges of zero
    pristine length have no weight. The percentile is the smallest strain ``s`` such that edges straining by at most
    ``s`` hold at least 95% of the total length (a weighted lower quantile, as :func:`normal_changes`). A strain of
    0.1 is an edge stretched or squeezed by 10%; a rigid motion or a uniform scale by ``c`` gives 0 and ``|c - 1|``.
    The largest strain is ``max |l' - l| / max(l, f d)`` over the edges of positive pristine length, ``d`` the
    pristine bounding-box diagonal and ``f`` :data:`EDGE_STRAIN_FLOOR` (0.25%): a thin part torn open (the two faces
    of a wing pulled apart) stretches its few short edges across the thickness many times over, which the
    percentile, weighted by length, does not see; the floor keeps the slivers of a remeshed or CAD mesh (0.001% of
    the diagonal long) from calling an invisible move a tear.

    The attack loop does not project onto it: a cap on it (:class:`~meshadv.perceptibility.PerceptibilityCap`) is a
    verdict check on every step's mesh.

    Args:
        vertices_adv: ``(N, 3)`` or ``(K, N, 3)`` adversarial vertices.
        vertices: ``(N, 3)`` pristine vertices.
        faces: int ``(M, 3)`` triangles (``M >= 1``, at least one edge of positive length).

    Returns:
        ``{"edge_strain_p95": (K,), "edge_strain_max": (K,)}``.

    Raises:
        ValueError: bad shapes, or every edge of zero length.

    Example:
        >>> v = torch.tensor([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); f = torch.tensor([[0, 1, 2]])
        >>> stretched = v * torch.tensor([1.5, 1.0, 1.0])  # edges of length 1, 1, 1.41 strain by 0.5, 0, 0.27
        >>> strains = edge_strains(stretched, v, f)
        >>> round(float(strains["edge_strain_p95"][0]), 4), round(float(strains["edge_strain_max"][0]), 4)
        (0.5, 0.5)
    """
    batch = _batched(vertices_adv, vertices).double()
    edges = vertex_edges(_check_faces(faces))
    before = (vertices.double()[edges[:, 0]] - vertices.double()[edges[:, 1]]).norm(dim=-1)  # (E,)
    if not float(before.sum()) > 0:
        raise ValueError("every edge has zero length: an edge strain is undefined")
    after = (batch[:, edges[:, 0]] - batch[:, edges[:, 1]]).norm(dim=-1)  # (K, E)
    strain = (after / before.clamp(min=1e-300) - 1.0).abs()
    strain = torch.where(before > 0, strain, torch.zeros_like(strain))
    floor = EDGE_STRAIN_FLOOR * float(bbox_diagonal(vertices.double()))  # > 0: some edge has positive length
    floored = (after - before).abs() / before.clamp(min=floor)
    floored = torch.where(before > 0, floored, torch.zeros_like(floored))
    return {"edge_strain_p95": _weighted_upper(strain, before).float(), "edge_strain_max": floored.amax(dim=1).float()}


def color_changes(colors_adv: Tensor, colors: Tensor, vertices: Tensor, faces: Tensor) -> Dict[str, Tensor]:
    """Area-weighted 95th percentile of the faces' RGB colour change (Euclidean distance, ``[0, sqrt(3)]``).

    Args:
        colors_adv: ``(M, 3)`` or ``(K, M, 3)`` adversarial face colours.
        colors: ``(M, 3)`` pristine face colours.
        vertices: ``(N, 3)`` pristine vertices (the weights are the pristine face areas).
        faces: int ``(M, 3)``.

    Returns:
        ``{"color_change_p95": (K,)}``: the smallest change that faces holding 95% of the area stay within.

    Raises:
        ValueError: bad shapes, or every face of zero area.

    Example:
        >>> v = torch.tensor([[0., 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]); f = torch.tensor([[0, 1, 2], [1, 3, 2]])
        >>> c = torch.zeros(2, 3); adv = c.clone(); adv[1] = 0.5      # half the area changes by sqrt(3) / 2
        >>> round(float(color_changes(adv, c, v, f)["color_change_p95"][0]), 4)
        0.866
    """
    faces = _check_faces(faces)
    batch = colors_adv.unsqueeze(0) if colors_adv.dim() == 2 else colors_adv
    if colors.dim() != 2 or colors.shape != (faces.shape[0], 3) or batch.dim() != 3 or batch.shape[1:] != colors.shape:
        raise ValueError(f"colors {tuple(colors.shape)} and colors_adv {tuple(colors_adv.shape)} must be (M, 3) and "
                         f"(M, 3) or (K, M, 3) with M = {faces.shape[0]} faces")
    weights = _areas(vertices, faces)
    change = (batch.double() - colors.double()).norm(dim=-1)
    return {"color_change_p95": _weighted_upper(change, weights).float()}


def surface_measures(vertices_adv: Tensor, colors_adv: Tensor, vertices: Tensor, colors: Tensor,
                     faces: Tensor) -> Dict[str, float]:
    """Every measure of :data:`SURFACE_MEASURES` of one adversarial mesh, as plain floats.

    Args:
        vertices_adv: ``(N, 3)`` adversarial vertices.
        colors_adv: ``(M, 3)`` adversarial face colours.
        vertices: ``(N, 3)`` pristine vertices.
        colors: ``(M, 3)`` pristine face colours.
        faces: int ``(M, 3)``.

    Returns:
        The measures (``nan`` for the area-weighted ones of a mesh whose faces all have zero area).

    Raises:
        ValueError: bad shapes.
    """
    if vertices_adv.dim() != 2 or colors_adv.dim() != 2:
        raise ValueError(f"vertices_adv and colors_adv must be one mesh's (N, 3) and (M, 3), got "
                         f"{tuple(vertices_adv.shape)} and {tuple(colors_adv.shape)}")
    faces = _check_faces(faces)
    with torch.no_grad():
        out = {k: float(v[0]) for k, v in vertex_moves(vertices_adv, vertices).items()}
        if not float(_face_cross(vertices.double(), faces).norm(dim=-1).sum()) > 0:
            return {**out, "normal_change_mean_deg": math.nan, "normal_change_p95_deg": math.nan,
                    "edge_strain_p95": math.nan, "edge_strain_max": math.nan, "color_change_p95": math.nan}
        out.update({k: float(v[0]) for k, v in normal_changes(vertices_adv, vertices, faces).items()})
        out.update({k: float(v[0]) for k, v in edge_strains(vertices_adv, vertices, faces).items()})
        out.update({k: float(v[0]) for k, v in color_changes(colors_adv, colors, vertices, faces).items()})
    return out


def texel_changes(texture_adv: Tensor, texture: Tensor) -> Dict[str, Tensor]:
    """95th percentile over texels of the RGB change of a texture image (Euclidean distance, ``[0, sqrt(3)]``).

    The texture-image counterpart of :func:`color_changes`: every texel counts once (texels are not weighted by the
    surface area they cover).

    Args:
        texture_adv: ``(Ht, Wt, 3)`` or ``(K, Ht, Wt, 3)`` adversarial texture.
        texture: ``(Ht, Wt, 3)`` pristine texture.

    Returns:
        ``{"color_change_p95": (K,)}``: the smallest change that 95% of the texels stay within.

    Raises:
        ValueError: the shapes disagree.

    Example:
        >>> t = torch.zeros(2, 2, 3); adv = t.clone(); adv[0] = 0.5       # half the texels change by sqrt(3) / 2
        >>> round(float(texel_changes(adv, t)["color_change_p95"][0]), 4)
        0.866
    """
    batch = texture_adv.unsqueeze(0) if texture_adv.dim() == 3 else texture_adv
    if texture.dim() != 3 or texture.shape[-1] != 3 or batch.dim() != 4 or batch.shape[1:] != texture.shape:
        raise ValueError(f"texture {tuple(texture.shape)} and texture_adv {tuple(texture_adv.shape)} must be "
                         "(Ht, Wt, 3) and (Ht, Wt, 3) or (K, Ht, Wt, 3)")
    change = (batch.double() - texture.double()).norm(dim=-1).reshape(batch.shape[0], -1)
    return {"color_change_p95": _weighted_upper(change, torch.ones_like(change[0])).float()}
