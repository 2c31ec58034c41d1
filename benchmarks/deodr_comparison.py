"""meshadv's ``render`` beside DEODR (a CPU differentiable renderer with analytic silhouette antialiasing), same
scenes, interleaved rounds, one thread: ``python benchmarks/render_bench.py --deodr`` (see ``run``).

DEODR is not a dependency of meshadv and is never vendored: install it on its own (``pip install deodr``, or
``pip install --target DIR deodr`` and put ``DIR`` on ``PYTHONPATH``); the comparison is skipped with a message when
it is not importable.

Per scene (an icosphere of 5,120 and of 20,480 faces at 299 px, the Stanford bunny resampled to about 10k faces at
224 px; meshadv also at ``antialias=2``), one round times, one after the other: meshadv's forward + backward with
NMR's visibility gradient, with the local one, and DEODR's forward + backward (a random linear loss of the image,
gradients of the vertices and colours). The medians over the rounds, their ratios, and the share of meshadv's call
spent outside the native calls (the torch work: camera, shading, image assembly, autograd), measured by timing the
native functions inside the calls.
"""

from __future__ import annotations

import importlib
import math
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch

from meshadv.render import Camera, Lights, render

DISTANCE, ELEVATION, AZIMUTH, FOV = 2.732, 20.0, 30.0, 30.0
LIGHT_DIRECTION, LIGHT_INTENSITY, AMBIENT = (0.3, 1.0, -0.6), 0.5, 0.5
#: (mesh, faces wanted, image side); meshadv renders each at antialias 1 and 2
SCENES = (("icosphere", 5_120, 299), ("icosphere", 20_480, 299), ("bunny", 10_000, 224))
NATIVE_CALLS = ("rasterize_forward", "rasterize_backward", "box_downsample", "box_spread", "flat_render_forward",
                "flat_render_backward")


def probe_deodr() -> tuple[str | None, str]:
    """``(version, "")`` when ``deodr`` imports, else ``(None, why)``."""
    try:
        deodr = importlib.import_module("deodr")
        importlib.import_module("deodr.pytorch")
    except ImportError as exc:
        return None, f"not importable ({exc}); `pip install deodr` outside the package's dependencies"
    return str(getattr(deodr, "__version__", "unknown")), ""


def scene_mesh(kind: str, faces: int, data: Path) -> tuple[torch.Tensor, torch.Tensor]:
    """Vertices (N,3) float32 centred at the origin in a ball of radius 0.5, and faces (M,3) int64."""
    import trimesh

    if kind == "icosphere":
        level = round(math.log(faces / 20, 4))
        mesh = trimesh.creation.icosphere(subdivisions=level, radius=0.5)
        return torch.tensor(mesh.vertices, dtype=torch.float32), torch.tensor(mesh.faces, dtype=torch.int64)
    from meshadv.mesh import load_mesh
    from meshadv.mesh.resample import resample_mesh

    bunny = resample_mesh(load_mesh(data / "bunny" / "stanford-bunny.ply"), target_faces=faces)
    verts = bunny.vertices.float()
    lo, hi = verts.min(0).values, verts.max(0).values
    verts = (verts - (lo + hi) / 2) / float((hi - lo).max())
    return verts.contiguous(), bunny.faces.long()


def deodr_renderer(verts: torch.Tensor, faces: torch.Tensor, size: int) -> Callable[[torch.Tensor], Any]:
    """DEODR's forward + backward of ``(image * cot).sum()`` for the scene, with the camera of :func:`our_camera`
    (DEODR's pinhole model with meshadv's focal length and pixel centres, image rows downward)."""
    from deodr.pytorch import CameraPytorch, Scene3DPytorch
    from deodr.pytorch.triangulated_mesh_pytorch import ColoredTriMeshPytorch

    cam = our_camera()
    rot, eye = cam.rotation()[0].double().numpy(), cam.eye()[0].double().numpy()
    focal = size / (2 * math.tan(math.radians(FOV) / 2))
    intrinsic = np.array([[focal, 0, (size - 1) / 2], [0, -focal, (size - 1) / 2], [0, 0, 1]])
    camera = CameraPytorch(np.column_stack((rot, -rot @ eye)), intrinsic, size, size)
    mesh = ColoredTriMeshPytorch(faces.numpy().astype(np.int32), vertices=verts.double(),
                                 colors=np.ones((verts.shape[0], 3)))
    scene = Scene3DPytorch()
    scene.set_mesh(mesh)
    scene.set_background_color(np.ones(3))
    direction = torch.tensor(LIGHT_DIRECTION, dtype=torch.float64)
    scene.set_light(direction / direction.norm() * LIGHT_INTENSITY, torch.tensor(AMBIENT, dtype=torch.float64))
    colors = torch.rand(verts.shape[0], 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)

    def run(cot: torch.Tensor) -> Any:
        v = verts.double().clone().requires_grad_(True)
        c = colors.clone().requires_grad_(True)
        mesh.set_vertices(v)
        mesh.set_vertices_colors(c)
        image = scene.render(camera)
        (image * cot).sum().backward()
        return image

    return run


def our_camera() -> Camera:
    return Camera.spherical(DISTANCE, AZIMUTH, ELEVATION, viewing_angle=FOV)


def meshadv_renderer(verts: torch.Tensor, faces: torch.Tensor, size: int, antialias: int,
                     visibility: str) -> Callable[[torch.Tensor], Any]:
    """meshadv's ``render`` forward + backward of ``(image * cot).sum() + alpha.sum()`` (1 thread)."""
    colors = torch.rand(faces.shape[0], 3, generator=torch.Generator().manual_seed(1))
    lights = Lights.single(LIGHT_DIRECTION, (LIGHT_INTENSITY,) * 3, (AMBIENT,) * 3)
    camera = our_camera()

    def run(cot: torch.Tensor) -> Any:
        v = verts.clone().requires_grad_(True)
        c = colors.clone().requires_grad_(True)
        out = render(v, faces, c, camera, lights, size, antialias=antialias, num_threads=1,
                     visibility_gradient=visibility)
        ((out.image * cot).sum() + out.alpha.sum()).backward()
        return out

    return run


@contextmanager
def native_timer(clock: Callable[[], float] = time.perf_counter) -> Iterator[list[float]]:
    """Adds the time (by ``clock``) of every call of the native functions ``NATIVE_CALLS`` to the yielded
    one-element list."""
    native = importlib.import_module("meshadv._raster")
    spent = [0.0]
    originals = {name: getattr(native, name) for name in NATIVE_CALLS}

    def timed(fn: Callable[..., Any]) -> Callable[..., Any]:
        def call(*args: Any, **kwargs: Any) -> Any:
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[0] += clock() - t0

        return call

    for name, fn in originals.items():
        setattr(native, name, timed(fn))
    try:
        yield spent
    finally:
        for name, fn in originals.items():
            setattr(native, name, fn)


def compare(data: Path, rounds: int, with_deodr: bool,
            clock: Callable[[], float] = time.perf_counter) -> list[dict]:
    """One row per (scene, antialias): medians (s, by ``clock``: wall or process CPU time) over ``rounds`` interleaved
    rounds of meshadv with NMR's and the local gradient, DEODR's (``None`` without it), and the torch share of
    meshadv's calls."""
    torch.set_num_threads(1)
    rows = []
    for kind, want, size in SCENES:
        verts, faces = scene_mesh(kind, want, data)
        cot = torch.randn(size, size, 3, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
        deodr = deodr_renderer(verts, faces, size) if with_deodr else None
        for k in (1, 2):
            cot_ours = cot.float().permute(2, 0, 1).unsqueeze(0).contiguous()
            runs: dict[str, Callable[[], Any]] = {
                vis: (lambda f=meshadv_renderer(verts, faces, size, k, vis): f(cot_ours)) for vis in ("nmr", "local")
            }
            if deodr is not None:
                runs["deodr"] = lambda: deodr(cot)
            times: dict[str, list[float]] = {name: [] for name in runs}
            native: dict[str, list[float]] = {"nmr": [], "local": []}
            for name, run in runs.items():  # warm-up
                run()
            for _ in range(rounds):
                for name, run in runs.items():
                    with native_timer(clock) as spent:
                        t0 = clock()
                        run()
                        times[name].append(clock() - t0)
                    if name in native:
                        native[name].append(spent[0])
            row: dict[str, Any] = {"scene": kind, "faces": int(faces.shape[0]), "size": size, "antialias": k}
            for name, ts in times.items():
                row[name] = statistics.median(ts)
            for name, ns in native.items():
                row[f"{name}_torch_share"] = statistics.median(
                    [(t - n) / t for t, n in zip(times[name], ns)])
            rows.append(row)
            print(row, flush=True)
    return rows


def section(rows: list[dict], command: str, machine: str, deodr: str) -> str:
    """The RESULTS.md section of the comparison."""
    def ms(t: float | None) -> str:
        return "–" if t is None else f"{t * 1e3:.1f}"

    def over(a: float | None, b: float | None) -> str:
        return "–" if a is None or b is None else f"{a / b:.2f}"

    lines = [
        "## Renderer against DEODR (`benchmarks/render_bench.py --deodr`)",
        "",
        "**Measures:** `meshadv.render.render` forward + backward (a random linear loss of RGB, plus alpha; "
        "gradients of vertices and colours) with NMR's visibility gradient and with the local one "
        "(docs/LOCAL_GRADIENT.md), beside DEODR's forward + backward of the same scene (mesh, camera, image size; "
        "DEODR draws per-vertex colours with analytic silhouette antialiasing, its own image model). Interleaved "
        "rounds, one thread (Rust `num_threads=1`, `torch.set_num_threads(1)`); medians of wall time, or of process "
        "CPU time with `--cpu-time`. *torch share*: the part of meshadv's call spent outside its native calls "
        "(camera, shading, image assembly, autograd, and the loss's own multiply, sum and backward).",
        "",
        "**Command:**",
        "",
        f"    {command}",
        "",
        f"**Machine:** {machine}. DEODR: {deodr}.",
        "",
        "| scene | faces | px | antialias | NMR ms | local ms | DEODR ms | NMR / DEODR | local / DEODR | "
        "torch share NMR | torch share local |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['faces']} | {r['size']} | {r['antialias']} | {ms(r['nmr'])} | {ms(r['local'])} | "
            f"{ms(r.get('deodr'))} | {over(r['nmr'], r.get('deodr'))} | {over(r['local'], r.get('deodr'))} | "
            f"{r['nmr_torch_share']:.0%} | {r['local_torch_share']:.0%} |"
        )
    return "\n".join(lines + ["", reading(rows)])


def reading(rows: list[dict]) -> str:
    """The section's reading, computed from its rows: the ratio ranges per antialias factor and the torch share."""
    def span(values: list[float], fmt: str) -> str:
        return f"{format(min(values), fmt)}-{format(max(values), fmt)}" if values else "–"

    parts = []
    for k in sorted({r["antialias"] for r in rows}):
        at = [r for r in rows if r["antialias"] == k and r.get("deodr")]
        parts.append(f"at antialias {k}, local / DEODR {span([r['local'] / r['deodr'] for r in at], '.2f')} and "
                     f"NMR / DEODR {span([r['nmr'] / r['deodr'] for r in at], '.2f')}")
    shares = [r[f"{v}_torch_share"] for r in rows for v in ("nmr", "local")]
    return ("**Reading:** " + "; ".join(parts) + f"; torch share of meshadv's call {span(shares, '.0%')}. "
            "DEODR renders at the output size with analytic edge antialiasing, so meshadv's `antialias=2` (4x the "
            "pixels) is compared with the same DEODR render.")
