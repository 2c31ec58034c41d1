"""Candidate perceptibility measures of attacked meshes, for choosing the cap's ceilings by measurement.

For each saved ``meshadv attack`` result folder (benign mesh: its ``benign.ply`` when the record names one, else
the input file loaded as the attack loaded it), and for ``FOLDER@m1,m2,...`` the folder's flow scaled so that its
largest vertex move is each ``m`` (fractions of the bounding-box diagonal, as ``benchmarks/cap_renders.py scale``),
one row of candidates:

* ``move_max``, ``move_p95`` -- :func:`meshadv.perceptibility.vertex_moves` (percent of the diagonal);
* ``normals_p95`` -- :func:`meshadv.perceptibility.normal_changes` (degrees); ``normals_p99`` the area-weighted 99th
  percentile; ``flipped`` the area (percent) of faces turned by more than 90 degrees;
* ``area_p95`` -- area-weighted 95th percentile of the faces' relative area change ``|A'/A - 1|``;
* ``strain_p95`` -- :func:`meshadv.perceptibility.edge_strains`; ``strain_p99`` the same at 99%;
* ``principal_p95`` -- area-weighted 95th percentile of each face's largest principal strain ``max |s_i - 1|``
  (``s_i`` the singular values of the affine map from the benign to the adversarial triangle);
* ``dihedral_p95`` -- length-weighted 95th percentile of the change of the angle between adjacent faces' normals
  (degrees; trimesh's ``face_adjacency_angles``);
* ``bend_p95`` -- 95th percentile (weighted by vertex area) of the flow's uniform Laplacian over the vertex's mean
  edge length (a local bend of the flow, dimensionless);
* ``patch_turn_max`` -- the largest, over the faces, of the area-weighted mean normal turn (degrees) of the faces
  whose centroids lie within :data:`PATCH_RADIUS` of the bounding-box diagonal of the face's centroid (the worst
  patch: damage on less than 5% of the surface, which no 95th percentile sees); ``region_turn_max`` the same over
  regions of a fixed area instead, each face's region the faces nearest its centroid that hold :data:`REGION_AREA`
  of the surface (so a few large CAD triangles do not make a patch of their own);
* ``new_selfx`` -- area (percent) of faces that intersect another face in the adversarial mesh and not in the benign
  one (pymeshlab's ``compute_selection_by_self_intersections_per_face``: sheets of a thin part passing through each
  other);
* ``ssim_min`` -- the record's ``ssim_held_out_min`` (result folders only).

Prints a markdown table and writes ``--out`` (JSON, written atomically). With ``--renders DIR``, each result folder
also gets ``DIR/<folder>.png``: the benign and the adversarial mesh on the attack's first, middle and last views,
closer (a 26 degree field of view) and larger (384 px, 2x antialias) than the attack's own renders, so that thin
parts can be judged.

Example:
    python benchmarks/cap_candidates.py /tmp/capthin/aeroplane_02_default /tmp/cap/free_sofa_01@0.01,0.02 \\
        --out /tmp/capthin/candidates.json --renders /tmp/capthin/close_ups
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("RAYON_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(1)

COLUMNS = ("move_max", "move_p95", "normals_p95", "normals_p99", "flipped", "area_p95", "strain_p95", "strain_p99",
           "principal_p95", "dihedral_p95", "bend_p95", "patch_turn_max", "region_turn_max", "new_selfx", "ssim_min")

#: Radius of the ``patch_turn_max`` patches, as a fraction of the bounding-box diagonal.
PATCH_RADIUS = 0.04
#: Area of the ``region_turn_max`` regions, as a fraction of the surface.
REGION_AREA = 0.01


def _region_max(centroids: np.ndarray, area: np.ndarray, values: np.ndarray, fraction: float) -> float:
    """The largest area-weighted mean of ``values`` over each face's region: the faces nearest its centroid that
    together hold ``fraction`` of the total area."""
    c, a, v = (torch.tensor(np.array(x, dtype=np.float64)) for x in (centroids, area, values))
    need = float(fraction * a.sum())
    best = 0.0
    for start in range(0, len(c), 512):
        order = torch.argsort(torch.cdist(c[start:start + 512], c), dim=1)
        weights = a[order]
        last = torch.searchsorted(torch.cumsum(weights, dim=1), torch.full((len(order), 1), need, dtype=a.dtype))
        inside = torch.arange(len(c))[None] <= last.clamp(max=len(c) - 1)
        means = (v[order] * weights * inside).sum(dim=1) / (weights * inside).sum(dim=1)
        best = max(best, float(means.max()))
    return best


def _weighted_quantile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    """The smallest value whose entries at most it hold at least ``q`` of the total weight."""
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order]) / weights.sum()
    return float(values[order][min(int(np.searchsorted(cumulative, q - 1e-12)), len(order) - 1)])


def _self_intersecting(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """bool ``(M,)``: the faces pymeshlab finds intersecting another face."""
    import pymeshlab

    meshes = pymeshlab.MeshSet()
    meshes.add_mesh(pymeshlab.Mesh(vertices, faces.astype(np.int32)))
    meshes.compute_selection_by_self_intersections_per_face()
    return meshes.current_mesh().face_selection_array().astype(bool)


def candidates(benign: Any, vertices_adv: torch.Tensor) -> Dict[str, float]:
    """Every candidate of the module docstring (but ``ssim_min``) of one adversarial version of ``benign``."""
    import trimesh

    from meshadv.mesh.adjacency import uniform_laplacian, vertex_edges
    from meshadv.perceptibility import edge_strains, normal_changes, vertex_moves

    v0, v1, faces = benign.vertices.double(), vertices_adv.double(), benign.faces.long()
    moves = vertex_moves(v1, v0)
    out = {"move_max": 100 * float(moves["max_displacement"][0]), "move_p95": 100 * float(moves["p95_displacement"][0]),
           "normals_p95": float(normal_changes(v1, v0, faces)["normal_change_p95_deg"][0]),
           "strain_p95": float(edge_strains(v1, v0, faces)["edge_strain_p95"][0])}
    a, b = v0.numpy(), v1.numpy()
    f = faces.numpy()
    m0, m1 = trimesh.Trimesh(a, f, process=False), trimesh.Trimesh(b, f, process=False)
    area = m0.area_faces
    n0, n1 = np.cross(a[f[:, 1]] - a[f[:, 0]], a[f[:, 2]] - a[f[:, 0]]), np.cross(b[f[:, 1]] - b[f[:, 0]],
                                                                                  b[f[:, 2]] - b[f[:, 0]])
    turn = np.degrees(np.arctan2(np.linalg.norm(np.cross(n0, n1), axis=1), (n0 * n1).sum(1)))
    out["normals_p99"] = _weighted_quantile(turn, area, 0.99)
    out["flipped"] = 100 * float(area[turn > 90].sum() / area.sum())
    kept = area > 1e-12 * area.max()
    out["area_p95"] = _weighted_quantile(np.abs(m1.area_faces[kept] / area[kept] - 1), area[kept], 0.95)
    edges = vertex_edges(faces).numpy()
    l0 = np.linalg.norm(a[edges[:, 0]] - a[edges[:, 1]], axis=1)
    l1 = np.linalg.norm(b[edges[:, 0]] - b[edges[:, 1]], axis=1)
    long = l0 > 0
    out["strain_p99"] = _weighted_quantile(np.abs(l1[long] / l0[long] - 1), l0[long], 0.99)
    # principal strains: the benign triangle in its own plane's frame, mapped onto the adversarial one
    e1, e2 = a[f[:, 1]] - a[f[:, 0]], a[f[:, 2]] - a[f[:, 0]]
    x = e1 / np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-300)
    y = np.cross(np.cross(e1, e2), e1)
    y /= np.maximum(np.linalg.norm(y, axis=1, keepdims=True), 1e-300)
    frame = np.stack([np.stack([(e1 * x).sum(1), (e1 * y).sum(1)], 1), np.stack([(e2 * x).sum(1), (e2 * y).sum(1)], 1)],
                     2)
    image = np.stack([b[f[:, 1]] - b[f[:, 0]], b[f[:, 2]] - b[f[:, 0]]], 2)
    singular = np.linalg.svd(image[kept] @ np.linalg.inv(frame[kept]), compute_uv=False)
    principal = np.maximum(np.abs(singular[:, 0] - 1), np.abs(singular[:, 1] - 1))
    out["principal_p95"] = _weighted_quantile(principal, area[kept], 0.95)
    adjacent = m0.face_adjacency_edges
    hinge = np.linalg.norm(a[adjacent[:, 0]] - a[adjacent[:, 1]], axis=1)
    dihedral = np.degrees(np.abs(m1.face_adjacency_angles - m0.face_adjacency_angles))
    out["dihedral_p95"] = _weighted_quantile(dihedral, hinge, 0.95)
    edges_t = torch.as_tensor(edges)
    bend = uniform_laplacian(v1 - v0, edges_t).norm(dim=1).numpy()
    degree = np.bincount(edges.ravel(), minlength=len(a))
    mean_edge = np.bincount(edges.ravel(), weights=np.repeat(l0, 2), minlength=len(a)) / np.maximum(degree, 1)
    vertex_area = np.bincount(f.ravel(), weights=np.repeat(area / 3, 3), minlength=len(a))
    used = degree > 0
    out["bend_p95"] = _weighted_quantile(bend[used] / np.maximum(mean_edge[used], 1e-300), vertex_area[used], 0.95)
    from scipy.spatial import cKDTree

    centroids = a[f].mean(axis=1)
    diagonal = float(np.linalg.norm(a.max(0) - a.min(0)))
    patches = cKDTree(centroids).query_ball_point(centroids, PATCH_RADIUS * diagonal)
    out["patch_turn_max"] = max(float((turn[p] * area[p]).sum() / max(area[p].sum(), 1e-300)) for p in patches)
    out["region_turn_max"] = _region_max(centroids, area, turn, REGION_AREA)
    new = _self_intersecting(b, f) & ~_self_intersecting(a, f)
    out["new_selfx"] = 100 * float(area[new].sum() / area.sum())
    return out


def _load(folder: Path) -> Tuple[Any, Any, Dict[str, Any]]:
    """The benign and adversarial meshes of a result folder and its record."""
    from meshadv.attacks.result import load_result_record
    from meshadv.mesh import load_mesh

    record = load_result_record(folder)
    adversarial = load_mesh(folder / record["meshes"][0][0])
    name = record.get("input", {}).get("benign_mesh")
    if name:
        return load_mesh(folder / name), adversarial, record
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from cap_renders import _benign_and_adversarial

    benign, adversarial, record = _benign_and_adversarial(folder)
    return benign, adversarial, record


def close_up(benign: Any, adversarial: Any, record: Dict[str, Any], path: Path) -> None:
    """The ``--renders`` PNG of one result folder (module docstring)."""
    from meshadv.render import Camera, Lights, RenderSetup, ViewSet

    cam = ViewSet.from_records(record["views"]).camera
    pick = sorted({0, len(cam.azimuth) // 2, len(cam.azimuth) - 1})
    camera = Camera.spherical(float(cam.distance[0]), cam.azimuth[pick], cam.elevation[pick], viewing_angle=26.0)
    views = ViewSet(camera, Lights.default(camera))
    setup = RenderSetup(image_size=384, antialias=2)
    with torch.no_grad():
        rows = [setup.render(m.vertices[None], m.faces, m.face_colors, views)[0] for m in (benign, adversarial)]
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from cap_renders import _grid

    _grid(rows, [f"benign {path.stem}", f"adversarial {path.stem}"], path)


def measure(specs: List[str], renders: Optional[Path] = None) -> Dict[str, Dict[str, float]]:
    """``{row name: candidates}`` of ``FOLDER`` and ``FOLDER@m1,m2`` specs (and the ``--renders`` PNGs of the
    folders into ``renders``)."""
    rows: Dict[str, Dict[str, float]] = {}
    for spec in specs:
        path, _, moves = spec.partition("@")
        folder = Path(path)
        benign, adversarial, record = _load(folder)
        if not moves:
            row = candidates(benign, adversarial.vertices)
            row["ssim_min"] = float(record["distances"][0].get("ssim_held_out_min", math.nan))
            rows[folder.name] = row
            if renders is not None:
                close_up(benign, adversarial, record, renders / f"{folder.name}.png")
            continue
        flow = adversarial.vertices.double() - benign.vertices.double()
        largest = float(flow.norm(dim=1).max()) / benign.bbox_diagonal()
        for move in moves.split(","):
            scaled = benign.vertices.double() + flow * (float(move) / largest)
            rows[f"{folder.name} scaled to {100 * float(move):g}%"] = candidates(benign, scaled)
    return rows


def table(rows: Dict[str, Dict[str, float]]) -> str:
    """The markdown table of ``rows``."""
    lines = ["| mesh | " + " | ".join(COLUMNS) + " |", "|---|" + "---:|" * len(COLUMNS)]
    for name, row in rows.items():
        lines.append(f"| {name} | " + " | ".join(f"{row.get(c, math.nan):.3g}" for c in COLUMNS) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("specs", nargs="+", help="result folders, or FOLDER@m1,m2 for its flow scaled")
    parser.add_argument("--out", type=Path, default=None, help="JSON of the rows")
    parser.add_argument("--renders", type=Path, default=None, help="folder for close-up PNGs of the result folders")
    args = parser.parse_args()
    rows = measure(args.specs, args.renders)
    print(table(rows))
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.out.with_suffix(args.out.suffix + ".tmp")
        tmp.write_text(json.dumps(rows, indent=1) + "\n")
        tmp.replace(args.out)


if __name__ == "__main__":
    main()
