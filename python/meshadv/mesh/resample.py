"""Uniform resampling and isotropic remeshing with MeshLab (pymeshlab), isolated in a child process and cached.

The paper resamples its CAD models uniformly with MeshLab to raise the triangle density. MeshLab can crash the
whole process on some inputs (a segfault on an empty result, an out-of-memory kill on a raw 7k-face aeroplane),
so every call runs in a separate Python process (``_meshlab_worker.py``, which imports only numpy and pymeshlab)
with a timeout and an address-space limit; a crash becomes a :class:`MeshProcessingError` naming the signal.

Results are cached on disk, keyed by the SHA-256 of the input's vertices and faces and the parameters, in
``cache_dir`` (default ``$MESHADV_CACHE/resample``, else ``~/.cache/meshadv/resample``); cache files are written
atomically, so concurrent runs never read a partial file.

Methods:
    ``uniform``: ``generate_resampled_uniform_mesh`` (a signed-distance volume re-meshed by marching cubes). For a
        mesh that is not watertight the unsigned distance with an offset of half a cell is used, which wraps thin
        open parts in a thin closed shell.
    ``isotropic``: ``meshing_isotropic_explicit_remeshing``, which keeps open boundaries and sharp features;
        surface deviation is bounded by ``max_deviation`` times the bounding-box diagonal.
    ``auto`` (default): ``uniform`` for watertight meshes, ``isotropic`` otherwise.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Optional, Union

import numpy as np
from scipy.spatial import cKDTree

from meshadv import _validate

from meshadv.util.atomic import write_bytes_atomic
from meshadv.mesh.adjacency import is_watertight
from meshadv.mesh.cleanup import clean_arrays
from meshadv.mesh.errors import MeshProcessingError
from meshadv.mesh.structure import Mesh

#: Environment variable naming meshadv's cache root (resampling uses its ``resample`` sub-folder).
CACHE_ENV_VAR = "MESHADV_CACHE"
#: Environment variable overriding the worker's address-space limit, in MiB.
MEMORY_ENV_VAR = "MESHADV_MESHLAB_MEMORY_MB"
#: Default address-space limit of the worker, in MiB.
DEFAULT_MEMORY_MB = 4096
#: Default wall-clock limit of one worker run, in seconds.
DEFAULT_TIMEOUT = 600.0
#: Default bound on the voxel count of uniform resampling (guards against out-of-memory).
DEFAULT_MAX_CELLS = 30_000_000
#: Bumped whenever the worker's algorithm changes, invalidating old cache entries.
ALGORITHM_VERSION = 2
METHODS = ("auto", "uniform", "isotropic")
_WORKER = Path(__file__).with_name("_meshlab_worker.py")


@dataclass(frozen=True)
class ResampleInfo:
    """How a resampling was obtained.

    Attributes:
        method: the method run (``uniform`` or ``isotropic``, never ``auto``).
        cache_hit: the result came from the cache.
        cache_path: the cache file (``None`` when caching is off).
        input_faces: faces of the input mesh.
        output_faces: faces of the result.
        seconds: wall time of this call.
        hausdorff: two-sided Hausdorff distance between input and result, as a fraction of the input's
            bounding-box diagonal (measured by MeshLab).
        details: what the worker tried (cell sizes or edge lengths and the face counts they gave).
    """

    method: str
    cache_hit: bool
    cache_path: Optional[Path]
    input_faces: int
    output_faces: int
    seconds: float
    hausdorff: float
    details: dict = field(default_factory=dict)


def default_cache_dir() -> Path:
    """``$MESHADV_CACHE/resample`` when the variable is set, else ``~/.cache/meshadv/resample``."""
    root = os.environ.get(CACHE_ENV_VAR)
    base = Path(root).expanduser() if root else Path.home() / ".cache" / "meshadv"
    return base / "resample"


def _memory_limit_mb(memory_limit_mb: Optional[int]) -> Optional[int]:
    if memory_limit_mb is not None:
        return memory_limit_mb
    env = os.environ.get(MEMORY_ENV_VAR)
    if env:
        try:
            return int(env)
        except ValueError as exc:
            raise ValueError(f"{MEMORY_ENV_VAR} must be an integer number of MiB, got {env!r}") from exc
    return DEFAULT_MEMORY_MB


def run_isolated(request: dict, *, timeout: float = DEFAULT_TIMEOUT, memory_limit_mb: Optional[int] = None) -> None:
    """Run one MeshLab worker request in a child process.

    Args:
        request: the worker's JSON request (see ``_meshlab_worker.py``): ``op`` and its parameters.
        timeout: seconds before the worker is killed.
        memory_limit_mb: address-space limit of the worker in MiB (``0`` for none); default
            ``$MESHADV_MESHLAB_MEMORY_MB`` or :data:`DEFAULT_MEMORY_MB`.

    Raises:
        MeshProcessingError: the worker failed, crashed (the message names the signal) or timed out.
    """
    limit_mb = _memory_limit_mb(memory_limit_mb)
    if limit_mb is not None and limit_mb < 0:
        raise ValueError(f"memory_limit_mb must be >= 0, got {limit_mb!r}")
    op = request.get("op")
    with tempfile.TemporaryDirectory(prefix="meshadv-meshlab-") as tmp:
        req_path = Path(tmp) / "request.json"
        req_path.write_text(json.dumps({**request, "memory_limit_mb": limit_mb}), encoding="utf-8")
        env = dict(os.environ)
        env.setdefault("OMP_NUM_THREADS", "1")
        try:
            proc = subprocess.run(
                [sys.executable, str(_WORKER), str(req_path)],
                capture_output=True,
                text=True,
                timeout=timeout,
                env=env,
            )
        except subprocess.TimeoutExpired as exc:
            raise MeshProcessingError(f"MeshLab {op} timed out after {timeout:g} s (killed)") from exc
    if proc.returncode < 0:
        try:
            name = signal.Signals(-proc.returncode).name
        except ValueError:
            name = f"signal {-proc.returncode}"
        hint = " (SIGKILL is usually the out-of-memory killer)" if name == "SIGKILL" else ""
        raise MeshProcessingError(f"MeshLab {op} crashed: the worker process was killed by {name}{hint}")
    if proc.returncode != 0:
        lines = [line for line in proc.stderr.strip().splitlines() if line.strip()]
        message = lines[-1] if lines else f"exit status {proc.returncode}"
        if "MemoryError" in proc.stderr or "bad_alloc" in proc.stderr:
            message += f" (out of memory under the {limit_mb} MiB limit)"
        raise MeshProcessingError(f"MeshLab {op} failed: {message}")


def _cache_key(vertices: np.ndarray, faces: np.ndarray, params: dict) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(vertices, dtype="<f4").tobytes())
    h.update(np.ascontiguousarray(faces, dtype="<i8").tobytes())
    h.update(json.dumps(params, sort_keys=True).encode("utf-8"))
    return h.hexdigest()


def _read_cache(path: Path) -> "Optional[tuple[np.ndarray, np.ndarray, dict]]":
    try:
        with np.load(path) as data:
            return data["vertices"], data["faces"], json.loads(str(data["info"]))
    except (OSError, KeyError, ValueError):
        return None  # missing or corrupt: recompute


def _transfer_colors(src: Mesh, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Give each new face the colour of the input face whose centroid is nearest to its centroid."""
    sv, sf, sc = src.numpy()
    if len(np.unique(sc, axis=0)) == 1:
        return np.broadcast_to(sc[0], (len(faces), 3)).copy()
    tree = cKDTree(sv[sf].mean(axis=1))
    _, nearest = tree.query(vertices[faces].mean(axis=1))
    return sc[nearest]


def resample_mesh_with_info(
    mesh: Mesh,
    *,
    target_faces: Optional[int] = None,
    edge_length: Optional[float] = None,
    method: str = "auto",
    cache_dir: "Union[str, os.PathLike[str], None]" = None,
    use_cache: bool = True,
    timeout: float = DEFAULT_TIMEOUT,
    memory_limit_mb: Optional[int] = None,
    max_cells: int = DEFAULT_MAX_CELLS,
    max_deviation: float = 0.004,
    max_hausdorff: float = 0.01,
    iterations: int = 10,
) -> "tuple[Mesh, ResampleInfo]":
    """Resample a mesh with MeshLab in an isolated process; return the result and how it was obtained.

    Args:
        mesh: the input mesh (its colours are carried to the new faces by nearest face centroid).
        target_faces: wanted face count (approximate, within about 20 %); exclusive with ``edge_length``.
        edge_length: wanted edge length (the cell size for ``uniform``) in the mesh's units. When neither is
            given, 1 % of the bounding-box diagonal.
        method: ``"auto"``, ``"uniform"`` or ``"isotropic"`` (see the module docstring).
        cache_dir: cache folder; default :func:`default_cache_dir`.
        use_cache: read and write the cache.
        timeout: seconds allowed per worker run.
        memory_limit_mb: worker address-space limit in MiB (``0`` for none); default ``$MESHADV_MESHLAB_MEMORY_MB``
            or 4096.
        max_cells: refuse uniform resampling whose voxel grid would exceed this many cells.
        max_deviation: for ``isotropic``, the surface deviation MeshLab checks edits against, as a fraction of
            the diagonal.
        max_hausdorff: for ``isotropic``, when the result is farther than this (fraction of the diagonal) from
            the input, remeshing is redone without tangential smoothing and the closer result kept. The
            distance obtained is reported in ``info.hausdorff``.
        iterations: for ``isotropic``, remeshing iterations.

    Returns:
        ``(mesh, info)``; the mesh is on the input's device.

    Raises:
        TypeError: an argument of the wrong type (``mesh`` not a Mesh, ``target_faces=4.5``, ...).
        ValueError: invalid arguments (a ``cache_dir`` that is a file) or an input without faces (a
            :class:`Mesh` has finite vertices).
        MeshProcessingError: MeshLab failed, crashed, timed out or produced an empty mesh.

    Example:
        >>> dense, info = resample_mesh_with_info(builtin_mesh("sphere"), target_faces=5000)  # doctest: +SKIP
    """
    start = time.perf_counter()
    if not isinstance(mesh, Mesh):
        raise TypeError(f"mesh must be a Mesh, got {type(mesh).__name__}")
    _validate.choice("method", method, METHODS)
    if target_faces is not None and edge_length is not None:
        raise ValueError("give target_faces or edge_length, not both")
    if target_faces is not None:
        _validate.integer("target_faces", target_faces, low=4)
    if edge_length is not None:
        _validate.positive_float("edge_length", edge_length)
    _validate.positive_float("timeout", timeout)
    _validate.finite_float("max_deviation", max_deviation, low=0.0, high=1.0, low_open=True, high_open=True)
    _validate.finite_float("max_hausdorff", max_hausdorff, low=0.0, high=1.0, low_open=True, high_open=True)
    _validate.positive_int("iterations", iterations)
    folder = _validate.path("cache_dir", cache_dir) if cache_dir is not None else default_cache_dir()
    blocker = next((p for p in (folder, *folder.parents) if p.exists()), None)
    if use_cache and blocker is not None and not blocker.is_dir():
        raise ValueError(f"cache_dir must be a folder, but {blocker} is a file")
    if mesh.num_faces == 0:
        raise ValueError("mesh has no faces; there is nothing to resample")

    vertices, faces, colors = mesh.numpy()
    # MeshLab's uniform resampling runs out of memory on duplicate faces; send it a clean copy.
    vertices, faces, _, _ = clean_arrays(vertices, faces, colors)
    if len(faces) == 0:
        raise ValueError("mesh has only degenerate faces; there is nothing to resample")
    watertight = is_watertight(faces)
    chosen = method if method != "auto" else ("uniform" if watertight else "isotropic")
    if target_faces is None and edge_length is None:
        edge_length = 0.01 * mesh.bbox_diagonal()
    params = {
        "op": chosen,
        "target_faces": target_faces,
        "edge_length": None if edge_length is None else float(edge_length),
        "watertight": watertight,
        "max_cells": int(max_cells),
        "max_deviation": float(max_deviation),
        "max_hausdorff": float(max_hausdorff),
        "iterations": int(iterations),
        "algorithm_version": ALGORITHM_VERSION,
        "pymeshlab": metadata.version("pymeshlab"),
    }
    key = _cache_key(vertices, faces, params)
    cache_path = None
    cached = None
    if use_cache:
        cache_path = folder / key[:2] / f"{key}.npz"
        if cache_path.is_file():
            cached = _read_cache(cache_path)

    if cached is not None:
        out_v, out_f, details = cached
    else:
        with tempfile.TemporaryDirectory(prefix="meshadv-resample-") as tmp:
            in_path, out_path = Path(tmp) / "input.npz", Path(tmp) / "output.npz"
            np.savez(in_path, vertices=vertices.astype(np.float64), faces=faces.astype(np.int32))
            run_isolated(
                {**params, "input": str(in_path), "output": str(out_path)},
                timeout=timeout,
                memory_limit_mb=memory_limit_mb,
            )
            with np.load(out_path) as data:
                out_v, out_f = data["vertices"], data["faces"]
                details = json.loads(str(data["info"]))
        if cache_path is not None:
            cache_path.parent.mkdir(parents=True, exist_ok=True)
            buffer = io.BytesIO()
            np.savez(buffer, vertices=out_v, faces=out_f, info=np.array(json.dumps(details)))
            write_bytes_atomic(cache_path, buffer.getvalue())

    out_v = np.asarray(out_v, dtype=np.float32)
    out_f = np.asarray(out_f, dtype=np.int64)
    if not np.isfinite(out_v).all() or len(out_f) == 0 or out_f.min() < 0 or out_f.max() >= len(out_v):
        raise MeshProcessingError(f"MeshLab {chosen} returned an invalid mesh")
    colors = np.zeros((len(out_f), 3), dtype=np.float32)
    out_v, out_f, colors, _ = clean_arrays(out_v, out_f, colors)
    if len(out_f) == 0:
        raise MeshProcessingError(f"MeshLab {chosen} returned only degenerate faces")
    colors = _transfer_colors(mesh, out_v, out_f)
    result = Mesh.from_numpy(out_v, out_f, colors).to(mesh.device)
    info = ResampleInfo(
        method=chosen,
        cache_hit=cached is not None,
        cache_path=cache_path,
        input_faces=mesh.num_faces,
        output_faces=result.num_faces,
        seconds=time.perf_counter() - start,
        hausdorff=float(details.get("hausdorff", float("nan"))),
        details=details,
    )
    return result, info


def resample_mesh(
    mesh: Mesh,
    *,
    target_faces: Optional[int] = None,
    edge_length: Optional[float] = None,
    method: str = "auto",
    cache_dir: "Union[str, os.PathLike[str], None]" = None,
    use_cache: bool = True,
    timeout: float = DEFAULT_TIMEOUT,
    memory_limit_mb: Optional[int] = None,
) -> Mesh:
    """Resample a mesh with MeshLab (isolated, cached); see :func:`resample_mesh_with_info`.

    Args:
        mesh: the input mesh.
        target_faces: wanted face count (approximate); exclusive with ``edge_length``.
        edge_length: wanted edge length in the mesh's units; default 1 % of the bounding-box diagonal.
        method: ``"auto"``, ``"uniform"`` or ``"isotropic"``.
        cache_dir: cache folder; default :func:`default_cache_dir`.
        use_cache: read and write the cache.
        timeout: seconds allowed per worker run.
        memory_limit_mb: worker address-space limit in MiB.

    Returns:
        The resampled mesh.

    Raises:
        ValueError: invalid arguments.
        MeshProcessingError: MeshLab failed, crashed or timed out.
    """
    return resample_mesh_with_info(
        mesh,
        target_faces=target_faces,
        edge_length=edge_length,
        method=method,
        cache_dir=cache_dir,
        use_cache=use_cache,
        timeout=timeout,
        memory_limit_mb=memory_limit_mb,
    )[0]
