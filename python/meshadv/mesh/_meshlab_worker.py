"""MeshLab (pymeshlab) worker, run as a separate process by :mod:`meshadv.mesh.resample`.

Run as a plain script (``python _meshlab_worker.py request.json``) so that it imports only numpy and pymeshlab,
not torch or meshadv. The request is a JSON object with ``op`` and its parameters; the result is an ``.npz``
file (``vertices`` float64, ``faces`` int32, ``info`` JSON string) at ``request["output"]``. A handled failure
prints one line to stderr and exits with status 2; a crash (segfault, out-of-memory kill) is seen by the
parent as a negative return code.

Ops: ``uniform`` (``generate_resampled_uniform_mesh``), ``isotropic`` (``meshing_isotropic_explicit_remeshing``),
``surface_transfer`` (a source OBJ's texture and/or vertex colours carried onto the input geometry, written as an OBJ
at ``request["output"]``: :func:`_surface_transfer`), and the diagnostics ``crash`` (raises SIGSEGV) and ``sleep``
(sleeps ``seconds``), used to test the isolation.
"""

from __future__ import annotations

import json
import math
import os
import resource
import signal
import sys
import time
from typing import TYPE_CHECKING

import numpy as np

from meshadv.util.atomic import atomic_path

if TYPE_CHECKING:
    import pymeshlab

#: Accept a face count within this relative tolerance of the target.
TARGET_TOLERANCE = 0.2
#: Maximum number of runs spent adjusting the cell size or edge length toward a target face count.
MAX_ATTEMPTS = 4


class WorkerError(Exception):
    """A handled failure, reported to the parent on stderr."""


def _new_meshset(vertices: np.ndarray, faces: np.ndarray) -> "pymeshlab.MeshSet":
    """A MeshLab mesh set holding one mesh."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces))
    return ms


def _result(ms: "pymeshlab.MeshSet") -> "tuple[np.ndarray, np.ndarray]":
    """The current mesh of ``ms`` as (float64 vertices, int32 faces); WorkerError when it is empty."""
    mesh = ms.current_mesh()
    # Checked before touching the matrices: an empty result is where MeshLab has been seen to segfault.
    if mesh.face_number() == 0 or mesh.vertex_number() == 0:
        raise WorkerError("MeshLab produced an empty mesh (the cell size or edge length is too large for this shape)")
    return np.asarray(mesh.vertex_matrix(), dtype=np.float64), np.asarray(mesh.face_matrix(), dtype=np.int32)


def _area(vertices: np.ndarray, faces: np.ndarray) -> float:
    tri = vertices[faces]
    return float(0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())


def _uniform(vertices: np.ndarray, faces: np.ndarray, req: dict) -> "tuple[np.ndarray, np.ndarray, dict]":
    import pymeshlab

    extent = vertices.max(axis=0) - vertices.min(axis=0)
    target = req.get("target_faces")
    cell = req.get("edge_length")
    if cell is None:
        # Marching cubes yields about 2.5 triangles per cell face crossed by the surface.
        cell = math.sqrt(2.5 * _area(vertices, faces) / target)
    absdist = not req["watertight"]
    tried = []
    for _ in range(MAX_ATTEMPTS if target else 1):
        cells = float(np.prod(extent / cell + 3.0))
        if cells > req["max_cells"]:
            raise WorkerError(
                f"cell size {cell:.4g} needs a {cells:.3g}-cell volume, above max_cells={req['max_cells']}; "
                "ask for fewer faces or a longer edge"
            )
        offset = 0.5 * cell if absdist else 0.0
        ms = _new_meshset(vertices, faces)
        ms.apply_filter(
            "generate_resampled_uniform_mesh",
            cellsize=pymeshlab.PureValue(cell),
            offset=pymeshlab.PureValue(offset),
            absdist=absdist,
            mergeclosevert=False,
        )
        out_v, out_f = _result(ms)
        tried.append({"cellsize": cell, "faces": len(out_f)})
        if not target or abs(len(out_f) / target - 1.0) <= TARGET_TOLERANCE:
            break
        cell *= math.sqrt(len(out_f) / target)
    diag = float(np.linalg.norm(extent))
    distance = hausdorff(vertices, faces, out_v, out_f) / diag
    return out_v, out_f, {"attempts": tried, "absdist": absdist, "offset": offset, "hausdorff": distance}


def hausdorff(vertices: np.ndarray, faces: np.ndarray, out_v: np.ndarray, out_f: np.ndarray) -> float:
    """Two-sided Hausdorff distance between two meshes (MeshLab samples each and measures exact distances)."""
    import pymeshlab

    ms = _new_meshset(vertices, faces)
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=out_v, face_matrix=out_f))
    diag = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    kw = {"samplevert": True, "sampleface": True, "samplenum": 20000, "maxdist": pymeshlab.PureValue(10.0 * diag)}
    forward = ms.get_hausdorff_distance(sampledmesh=0, targetmesh=1, **kw)["max"]
    backward = ms.get_hausdorff_distance(sampledmesh=1, targetmesh=0, **kw)["max"]
    return float(max(forward, backward))


def _remesh(
    vertices: np.ndarray, faces: np.ndarray, length: float, max_dist: float, iterations: int, smooth: bool
) -> "tuple[np.ndarray, np.ndarray]":
    import pymeshlab

    ms = _new_meshset(vertices, faces)
    ms.apply_filter(
        "meshing_isotropic_explicit_remeshing",
        iterations=iterations,
        targetlen=pymeshlab.PureValue(length),
        checksurfdist=True,
        maxsurfdist=pymeshlab.PureValue(max_dist),
        featuredeg=30.0,
        smoothflag=smooth,
    )
    return _result(ms)


def _isotropic(vertices: np.ndarray, faces: np.ndarray, req: dict) -> "tuple[np.ndarray, np.ndarray, dict]":
    target = req.get("target_faces")
    length = req.get("edge_length")
    if length is None:
        # Equilateral triangles of edge L have area sqrt(3)/4 L^2.
        length = math.sqrt(4.0 * _area(vertices, faces) / (math.sqrt(3.0) * target))
    diag = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    iterations = int(req["iterations"])
    tried = []
    for _ in range(MAX_ATTEMPTS if target else 1):
        max_dist = min(0.5 * length, req["max_deviation"] * diag)
        out_v, out_f = _remesh(vertices, faces, length, max_dist, iterations, smooth=True)
        tried.append({"targetlen": length, "maxsurfdist": max_dist, "faces": len(out_f)})
        if not target or abs(len(out_f) / target - 1.0) <= TARGET_TOLERANCE:
            break
        length *= math.sqrt(len(out_f) / target)
    distance = hausdorff(vertices, faces, out_v, out_f)
    smooth = True
    if distance > req["max_hausdorff"] * diag:
        # Tangential smoothing can drag vertices across thin or nearly coincident parts; retry without it.
        alt_v, alt_f = _remesh(vertices, faces, length, max_dist, iterations, smooth=False)
        alt_distance = hausdorff(vertices, faces, alt_v, alt_f)
        tried.append({"targetlen": length, "maxsurfdist": max_dist, "faces": len(alt_f), "smooth": False})
        if alt_distance < distance:
            out_v, out_f, distance, smooth = alt_v, alt_f, alt_distance, False
    return out_v, out_f, {"attempts": tried, "smooth": smooth, "hausdorff": distance / diag}


def _surface_transfer(req: dict) -> None:
    """Carry the texture and/or vertex colours of the OBJ ``req["source"]`` onto the geometry of ``req["input"]``
    and save it as the OBJ ``req["output"]`` (its MTL and texture PNG beside it).

    The texture: a trivial per-triangle atlas of ``texture_side`` squared texels on the new faces
    (``compute_texcoord_parametrization_triangle_trivial_per_wedge``), filled with the source's texture colour at the
    closest source point (``transfer_attributes_to_texture_per_vertex``, "Texture Color"). Vertex colours: the
    source's colour at the closest point (``transfer_attributes_per_vertex``).
    """
    import pymeshlab

    with np.load(req["input"]) as data:
        vertices = np.ascontiguousarray(data["vertices"], dtype=np.float64)
        faces = np.ascontiguousarray(data["faces"], dtype=np.int32)
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(req["source"])
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces))
    texture, colors = bool(req.get("texture")), bool(req.get("colors"))
    if texture:
        side = int(req["texture_side"])
        ms.compute_texcoord_parametrization_triangle_trivial_per_wedge(textdim=side, border=2)
        ms.transfer_attributes_to_texture_per_vertex(sourcemesh=0, targetmesh=1, attributeenum="Texture Color",
                                                     textname=str(req["texture_name"]), textw=side, texth=side)
    if colors:
        ms.transfer_attributes_per_vertex(sourcemesh=0, targetmesh=1, colortransfer=True)
    ms.save_current_mesh(req["output"], save_vertex_color=colors, save_wedge_texcoord=texture,
                         save_vertex_normal=False)


def main(argv: "list[str]") -> int:
    """Run the request in ``argv[1]``; return the exit status."""
    if len(argv) != 2:
        print("usage: _meshlab_worker.py request.json", file=sys.stderr)
        return 2
    with open(argv[1], encoding="utf-8") as handle:
        req = json.load(handle)
    limit_mb = int(req.get("memory_limit_mb") or 0)
    if limit_mb > 0:  # set here rather than in a fork-time hook, which is unsafe in a threaded parent
        resource.setrlimit(resource.RLIMIT_AS, (limit_mb << 20, limit_mb << 20))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    op = req.get("op")
    if op == "crash":
        os.kill(os.getpid(), signal.SIGSEGV)
    if op == "sleep":
        time.sleep(float(req.get("seconds", 60)))
        return 0
    if op == "surface_transfer":  # writes its own OBJ output
        try:
            _surface_transfer(req)
        except Exception as exc:  # noqa: BLE001 - report any pymeshlab failure as one line
            print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
            return 2
        return 0
    try:
        with np.load(req["input"]) as data:
            vertices = np.ascontiguousarray(data["vertices"], dtype=np.float64)
            faces = np.ascontiguousarray(data["faces"], dtype=np.int32)
        if op == "uniform":
            out_v, out_f, info = _uniform(vertices, faces, req)
        elif op == "isotropic":
            out_v, out_f, info = _isotropic(vertices, faces, req)
        else:
            raise WorkerError(f"unknown op {op!r}")
    except WorkerError as exc:
        print(str(exc), file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - report any pymeshlab failure as one line
        print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    with atomic_path(req["output"], suffix=".npz") as tmp:
        np.savez(tmp, vertices=out_v, faces=out_f, info=np.array(json.dumps(info)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
