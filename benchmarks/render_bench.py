"""Benchmark of meshadv's differentiable renderer against a pure-PyTorch rasterizer, PyTorch3D and Mitsuba 3.

Times ``meshadv.render.render`` (PyTorch camera + shading, Rust rasterizer), the same pipeline with the vectorised
pure-PyTorch rasterizer of ``benchmarks/torch_reference_rasterizer.py``, with PyTorch3D's CPU rasterizer when
``pytorch3d`` is importable (it has no wheel on PyPI: build it from source outside this repository and put it on
``PYTHONPATH``; never vendored) and, when available, Mitsuba 3's ``llvm_ad_rgb`` variant rendering the same mesh
(probed and run in subprocesses so it can never crash the bench).
Forward and forward+backward (gradients of a random linear loss of the image w.r.t. vertices and colours), for a UV
sphere of about 1k, 10k and 100k faces, at 224, 299 and 512 px, batch 1 and 8, with 1 and 2 threads. Median times.

Usage:
    python benchmarks/render_bench.py                # full grid, writes the render section of benchmarks/RESULTS.md
    python benchmarks/render_bench.py --quick        # small grid
    python benchmarks/render_bench.py --no-mitsuba --out /tmp/results.md
    PYTHONPATH=/path/to/pytorch3d python benchmarks/render_bench.py   # with the PyTorch3D columns
    python benchmarks/render_bench.py --deodr --rounds 15  # beside DEODR (benchmarks/deodr_comparison.py) only

PyTorch3D (0.7.9 was timed) builds CPU-only from its source when no CUDA toolkit is found, outside this checkout:
    git clone https://github.com/facebookresearch/pytorch3d /path/to/pytorch3d && cd /path/to/pytorch3d
    sed -i 's/-std=c++17/-std=c++20/' setup.py        # the headers of torch 2.15 require C++20
    pip install ninja && MAX_JOBS=2 python setup.py build_ext --inplace   # about 12 minutes on 2 cores
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from torch_reference_rasterizer import torch_rasterize  # noqa: E402

from meshadv.render import Camera, Lights, render  # noqa: E402
from meshadv.render.lighting import shade  # noqa: E402

MARK_START = "<!-- render-bench:start -->"
MARK_END = "<!-- render-bench:end -->"
DEODR_MARKS = ("<!-- render-bench-deodr:start -->", "<!-- render-bench-deodr:end -->")
DISTANCE, FOV = 2.732, 30.0
READING_NOTE = (
    "meshadv's fwd+bwd is dominated by the Rust NMR vertex-gradient sweep (`rasterize_backward`), which, as NMR "
    "defines it, walks each edge's pixel lines from the edge to the image border; the PyTorch baseline's "
    "straight-through gradient touches only covered pixels and PyTorch3D's soft rasterizer only pixels within its "
    "blur radius of a face, and neither is NMR's gradient. When only colours need gradients (texture attacks) the "
    "vertex sweep is skipped. PyTorch3D on the CPU tests every face at every pixel (it bins faces only on CUDA), so "
    "its cost grows with faces x pixels."
)


# ----------------------------------------------------------------------------- mesh
def uv_sphere(target_faces: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A bumpy UV sphere of radius about 0.5 with about ``target_faces`` triangles (rings x 2 segments x rings)."""
    rings = max(3, round(math.sqrt(target_faces / 4)))
    segments = 2 * rings
    theta = torch.linspace(0, math.pi, rings + 1, dtype=torch.float64)[1:-1]
    phi = torch.arange(segments, dtype=torch.float64) * (2 * math.pi / segments)
    t, p = torch.meshgrid(theta, phi, indexing="ij")
    ring_verts = torch.stack([torch.sin(t) * torch.cos(p), torch.cos(t), torch.sin(t) * torch.sin(p)], -1).reshape(
        -1, 3
    )
    verts = torch.cat(
        [
            torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64),
            ring_verts,
            torch.tensor([[0.0, -1.0, 0.0]], dtype=torch.float64),
        ]
    )
    faces = []
    idx = lambda r, s: 1 + r * segments + s % segments  # noqa: E731
    for s in range(segments):
        faces.append([0, idx(0, s + 1), idx(0, s)])
    for r in range(rings - 2):
        for s in range(segments):
            a, b, c, d = idx(r, s), idx(r, s + 1), idx(r + 1, s), idx(r + 1, s + 1)
            faces += [[a, b, d], [a, d, c]]
    south = len(verts) - 1
    for s in range(segments):
        faces.append([south, idx(rings - 2, s), idx(rings - 2, s + 1)])
    # A little deterministic bumpiness so that faces occlude each other and shading varies.
    gen = torch.Generator().manual_seed(0)
    verts = verts * (1 + 0.03 * torch.rand(len(verts), 1, generator=gen, dtype=torch.float64))
    return (verts * 0.5).float(), torch.tensor(faces, dtype=torch.int64)


# ----------------------------------------------------------------------------- timing
def median_time(fn: Callable[[], object], repeats: int, budget_s: float) -> tuple[float, int]:
    """Median wall time (s) of ``fn`` after one warm-up call; fewer repeats when a call is slow."""
    t0 = time.perf_counter()
    fn()
    first = time.perf_counter() - t0
    n = max(1, min(repeats, int(budget_s / max(first, 1e-6))))
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), n


def make_inputs(faces_target: int, batch: int) -> dict:
    verts, faces = uv_sphere(faces_target)
    gen = torch.Generator().manual_seed(1)
    colors = torch.rand(faces.shape[0], 3, generator=gen) * 0.6 + 0.2
    az = torch.linspace(0, 315, batch)
    camera = Camera.spherical(DISTANCE, az, 20.0, viewing_angle=FOV)
    lights = Lights.single((0.3, 1.0, -0.6), (0.5, 0.5, 0.5), (0.5, 0.5, 0.5))
    lights = Lights(
        lights.directions.expand(batch, -1, -1), lights.colors.expand(batch, -1, -1), lights.ambient.expand(batch, -1)
    )
    return {"verts": verts, "faces": faces, "colors": colors, "camera": camera, "lights": lights}


def meshadv_step(inp: dict, size: int, threads: int, backward: bool, cot: torch.Tensor | None) -> Callable[[], None]:
    def run() -> None:
        v = inp["verts"].clone().requires_grad_(backward)
        c = inp["colors"].clone().requires_grad_(backward)
        out = render(v, inp["faces"], c, inp["camera"], inp["lights"], size, num_threads=threads)
        if backward:
            loss = (out.image * cot[:, :3]).sum() + (out.alpha * cot[:, 3:]).sum()
            loss.backward()

    return run


def torch_step(inp: dict, size: int, backward: bool, cot: torch.Tensor | None) -> Callable[[], None]:
    """The same pipeline (camera + shading in PyTorch) with the pure-PyTorch rasterizer."""
    bg = torch.tensor([1.0, 1.0, 1.0, 0.0])

    def run() -> None:
        v = inp["verts"].clone().requires_grad_(backward)
        c = inp["colors"].clone().requires_grad_(backward)
        cam, lights = inp["camera"], inp["lights"]
        screen = cam.project(v)
        shaded = shade(v, inp["faces"], c, lights, cam).expand(screen.shape[0], -1, -1)
        attrs = torch.cat([shaded, torch.ones_like(shaded[..., :1])], -1)
        image, _, _ = torch_rasterize(screen, inp["faces"], attrs, size, size, bg, 0.1, 100.0)
        if backward:
            (image.permute(0, 3, 1, 2) * cot).sum().backward()

    return run


# ----------------------------------------------------------------------------- PyTorch3D (optional)
# SoftRas blending as PyTorch3D's soft shaders use it: BlendParams' default sigma and gamma, the blur radius that
# keeps faces whose sigmoid weight is above 1e-4 (PyTorch3D's documented recipe), a few faces per pixel.
P3D_SIGMA, P3D_GAMMA, P3D_FACES_PER_PIXEL = 1e-4, 1e-4, 4
P3D_BLUR_RADIUS = math.log(1.0 / 1e-4 - 1.0) * P3D_SIGMA


def probe_pytorch3d() -> tuple[str | None, str]:
    """Return (version, message); version None when PyTorch3D's rasterizer cannot be imported."""
    try:
        import pytorch3d
        from pytorch3d.renderer.mesh.rasterize_meshes import rasterize_meshes  # noqa: F401
    except ImportError as exc:
        return None, f"not importable ({exc}); build it from source outside the repository and add it to PYTHONPATH"
    return str(pytorch3d.__version__), "ok"


def pytorch3d_step(inp: dict, size: int, backward: bool, cot: torch.Tensor | None) -> Callable[[], torch.Tensor]:
    """The same camera + shading with PyTorch3D's CPU rasterizer (naive: PyTorch3D has no binned CPU path).

    Forward: hard rasterization (1 face per pixel, no blur), each pixel the shaded colour of its face. Forward +
    backward: PyTorch3D's soft rasterizer and SoftRas blending (its route to vertex gradients; not NMR's gradient).
    Returns the RGBA image (B, H, W, 4), for the silhouette check against meshadv.
    """
    from pytorch3d.renderer.blending import BlendParams, softmax_rgb_blend
    from pytorch3d.renderer.mesh.rasterize_meshes import rasterize_meshes
    from pytorch3d.structures import Meshes

    background = (1.0, 1.0, 1.0)
    blend = BlendParams(sigma=P3D_SIGMA, gamma=P3D_GAMMA, background_color=background)
    flip_x = torch.tensor([-1.0, 1.0, 1.0])  # PyTorch3D's NDC has +x to the left, +y up

    def run() -> torch.Tensor:
        v = inp["verts"].clone().requires_grad_(backward)
        c = inp["colors"].clone().requires_grad_(backward)
        cam, lights, faces = inp["camera"], inp["lights"], inp["faces"]
        screen = cam.project(v) * flip_x
        batch = screen.shape[0]
        shaded = shade(v, faces, c, lights, cam).expand(batch, -1, -1)
        meshes = Meshes(verts=list(screen), faces=[faces] * batch)
        blur, per_pixel = (P3D_BLUR_RADIUS, P3D_FACES_PER_PIXEL) if backward else (0.0, 1)
        pix_to_face, zbuf, _, dists = rasterize_meshes(
            meshes, image_size=size, blur_radius=blur, faces_per_pixel=per_pixel, bin_size=0
        )
        colors = shaded.reshape(-1, 3)[pix_to_face.clamp(min=0)]  # (B, H, W, K, 3), packed face indices
        if backward:
            fragments = argparse.Namespace(pix_to_face=pix_to_face, zbuf=zbuf, dists=dists)
            image = softmax_rgb_blend(colors, fragments, blend, znear=0.1, zfar=100.0)
            (image.permute(0, 3, 1, 2) * cot).sum().backward()
            return image.detach()
        covered = pix_to_face[..., :1] >= 0
        rgb = torch.where(covered, colors[..., 0, :], torch.tensor(background))
        return torch.cat([rgb, covered.float()], -1)

    return run


def silhouette_agreement(inp: dict, size: int) -> float:
    """Fraction of pixels where meshadv and PyTorch3D (hard) agree on coverage, batch element 0: a check that both
    render the same picture."""
    torch.set_num_threads(1)
    ours = render(inp["verts"], inp["faces"], inp["colors"], inp["camera"], inp["lights"], size).alpha[0, 0] > 0.5
    theirs = pytorch3d_step(inp, size, False, None)()[0, ..., 3] > 0.5
    return float((ours == theirs).float().mean())


# ----------------------------------------------------------------------------- mitsuba (subprocess)
MITSUBA_WORKER = textwrap.dedent(
    r"""
    import json, math, statistics, sys, time
    import numpy as np
    import drjit as dr
    import mitsuba as mi
    cfg = json.loads(sys.argv[1])
    mi.set_variant("llvm_ad_rgb")
    mi.set_log_level(mi.LogLevel.Error)
    dr.set_thread_count(cfg["threads"])
    data = np.load(cfg["mesh"])
    verts, faces, size = data["verts"], data["faces"].astype(np.uint32), cfg["size"]
    mesh = mi.Mesh("mesh", len(verts), len(faces))
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(verts.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(faces.ravel())
    params.update()
    integrator = cfg["integrator"]
    sensors = []
    for az in np.linspace(0, 315, cfg["batch"]):
        a, e, d = math.radians(az), math.radians(20.0), cfg["distance"]
        eye = [d * math.cos(e) * math.sin(a), d * math.sin(e), -d * math.cos(e) * math.cos(a)]
        sensors.append(mi.load_dict({
            "type": "perspective", "fov": cfg["fov"], "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at(origin=eye, target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
                     "pixel_format": "rgb", "sample_border": True},
            "sampler": {"type": "independent", "sample_count": 1},
        }))
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": integrator},
        "mesh": {"type": "ply", "filename": cfg["ply"], "bsdf": {"type": "diffuse"}},
        "sun": {"type": "directional", "direction": [-0.3, -1.0, 0.6], "irradiance": 0.5},
        "env": {"type": "constant", "radiance": 0.5},
    })
    sp = mi.traverse(scene)
    key = "mesh.vertex_positions"
    def step(backward):
        if backward:
            dr.enable_grad(sp[key])
            sp.update()
        for i, sensor in enumerate(sensors):
            img = mi.render(scene, sp, sensor=sensor, spp=1, seed=i)
            if backward:
                dr.backward(dr.mean(img))
            else:
                dr.eval(img)
        if backward:
            g = dr.grad(sp[key])
            dr.eval(g)
            dr.disable_grad(sp[key])
    out = {}
    for name, bw in (("forward", False), ("backward", True)):
        step(bw)
        times = []
        for _ in range(cfg["repeats"]):
            t0 = time.perf_counter(); step(bw); times.append(time.perf_counter() - t0)
        out[name] = statistics.median(times)
    print(json.dumps(out))
    """
)


def probe_mitsuba() -> tuple[str | None, str]:
    """Return (version, message); version None when llvm_ad_rgb cannot render."""
    code = (
        "import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); "
        "s = mi.load_dict({'type': 'scene', 'integrator': {'type': 'direct'}, "
        "'shape': {'type': 'sphere'}, 'sensor': {'type': 'perspective', 'to_world': "
        "mi.ScalarTransform4f().look_at(origin=[0, 0, -4], target=[0, 0, 0], up=[0, 1, 0]), "
        "'film': {'type': 'hdrfilm', 'width': 8, 'height': 8}}}); "
        "import drjit as dr; dr.eval(mi.render(s, spp=1)); print(mi.__version__)"
    )
    try:
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return None, f"probe failed: {exc}"
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["unknown error"]
        return None, f"llvm_ad_rgb unavailable: {tail[0][:200]}"
    return proc.stdout.strip().splitlines()[-1], "ok"


def save_ply(path: Path, verts: np.ndarray, faces: np.ndarray) -> None:
    """Binary little-endian PLY (vertices float32, faces uchar count + int32 indices)."""
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(verts)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    face_rec = np.empty(len(faces), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    face_rec["n"], face_rec["idx"] = 3, faces
    with open(path, "wb") as fh:
        fh.write(header.encode())
        fh.write(verts.astype("<f4").tobytes())
        fh.write(face_rec.tobytes())


def run_mitsuba(
    inp: dict, size: int, batch: int, threads: int, repeats: int, tmp: Path, integrator: str = "direct"
) -> dict | str:
    """Mitsuba timings in a subprocess, or an error string."""
    ply = tmp / f"mesh_{inp['faces'].shape[0]}.ply"
    npz = tmp / f"mesh_{inp['faces'].shape[0]}.npz"
    if not ply.exists():
        save_ply(ply, inp["verts"].numpy(), inp["faces"].numpy())
        np.savez(npz, verts=inp["verts"].numpy(), faces=inp["faces"].numpy())
    cfg = {
        "mesh": str(npz),
        "ply": str(ply),
        "size": size,
        "batch": batch,
        "threads": threads,
        "repeats": repeats,
        "fov": FOV,
        "distance": DISTANCE,
        "integrator": integrator,
    }
    try:
        proc = subprocess.run(
            [sys.executable, "-c", MITSUBA_WORKER, json.dumps(cfg)], capture_output=True, text=True, timeout=900
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"error: {exc}"
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["unknown"]
        return f"error: {tail[0][:160]}"
    for line in reversed(proc.stdout.strip().splitlines()):
        try:
            return json.loads(line)
        except json.JSONDecodeError:
            continue
    return f"error: no result in Mitsuba output: {proc.stdout.strip()[-160:]!r}"


# ----------------------------------------------------------------------------- report
def machine_info() -> dict:
    cpu = platform.processor() or "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            cwd=Path(__file__).parent,
            timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        commit = "unknown"
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "platform": platform.platform(),
        "commit": commit or "unknown",
    }


def fmt(t: float | None) -> str:
    return "–" if t is None else f"{t * 1e3:.1f}"


def speedup(ours: float | None, theirs: float | None) -> float | None:
    """meshadv's speed-up over another renderer: their time / meshadv's (None when either is missing)."""
    return None if ours is None or theirs is None else theirs / ours


def ratio(ours: float | None, theirs: float | None) -> str:
    """A table cell of :func:`speedup`."""
    s = speedup(ours, theirs)
    return "–" if s is None else f"{s:.1f}×"


def speedup_range(rows: list[dict], ours: str, theirs: str) -> str | None:
    """``"a-bx"``: the smallest and largest :func:`speedup` over the one-thread rows that have both columns."""
    ratios = [s for r in rows if r["threads"] == 1 and (s := speedup(r.get(ours), r.get(theirs))) is not None]
    if not ratios:
        return None
    return f"{min(ratios):.1f}-{max(ratios):.1f}x"


def reading(rows: list[dict]) -> str:
    """What the table says at one thread, computed from its rows, then why (``READING_NOTE``)."""
    said = []
    for mode, label in (("fwd", "forward"), ("bwd", "fwd+bwd")):
        parts = [
            f"{span} over {name}"
            for other, name in (
                ("torch", "the PyTorch rasterizer"),
                ("p3d", "PyTorch3D"),
                ("mitsuba", "Mitsuba's `direct`"),
            )
            if (span := speedup_range(rows, f"meshadv_{mode}", f"{other}_{mode}")) is not None
        ]
        if parts:
            said.append(f"{label} " + ", ".join(parts))
    text = ""
    if said:
        text = "Reading the table: meshadv's speed-up at one thread (their time / meshadv's; below 1x meshadv is "
        text += "slower), " + "; ".join(said) + "."
    # The Rust bench's case (crates/raster/examples/bench.rs: ~10k faces, 299 px, one thread), through Python.
    at_299 = [r for r in rows if (r["threads"], r["batch"], r["size"]) == (1, 1, 299) and "meshadv_bwd" in r]
    if at_299:
        r = min(at_299, key=lambda r: abs(r["faces"] - 10_000))
        text += (
            f" At 299 px / {r['faces']:,} faces / batch 1: forward {fmt(r['meshadv_fwd'])} ms, forward + backward "
            f"{fmt(r['meshadv_bwd'])} ms through the Python API."
        )
    return (text + " " + READING_NOTE).strip()


def write_section(path: Path, text: str, marks: tuple[str, str] = (MARK_START, MARK_END)) -> None:
    """Replace the section between the markers ``marks`` (the render section's by default) of ``path``, keeping
    everything else; a new section goes at the end."""
    start, end = marks
    block = f"{start}\n{text.rstrip()}\n{end}\n"
    old = path.read_text() if path.exists() else "# Benchmark results\n\n"
    if start in old and end in old:
        head, rest = old.split(start, 1)
        tail = rest.split(end, 1)[1].lstrip("\n")
        new = head + block + ("\n" + tail if tail else "")
    else:
        new = old.rstrip() + "\n\n" + block
    path.write_text(new)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small grid (1k/10k faces, 224 px, batch 1, 1-2 threads)")
    parser.add_argument("--repeats", type=int, default=5, help="timed repetitions per cell (median reported)")
    parser.add_argument("--budget", type=float, default=6.0, help="seconds of timing per cell before fewer repeats")
    parser.add_argument("--no-mitsuba", action="store_true", help="skip Mitsuba 3")
    parser.add_argument("--no-torch", action="store_true", help="skip the pure-PyTorch rasterizer")
    parser.add_argument(
        "--torch-max-work", type=int, default=100_000, help="skip the PyTorch baseline when faces x batch exceeds this"
    )
    parser.add_argument("--no-pytorch3d", action="store_true", help="skip PyTorch3D even when it is importable")
    parser.add_argument(
        "--pytorch3d-max-work",
        type=float,
        default=1e9,
        help="skip PyTorch3D when faces x pixels x batch exceeds this (its CPU rasterizer tests every face per pixel)",
    )
    parser.add_argument("--max-minutes", type=float, default=45.0, help="stop starting new cells after this long")
    parser.add_argument("--mitsuba-max-batch", type=int, default=8, help="skip Mitsuba for larger batches")
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "RESULTS.md")
    parser.add_argument("--deodr", action="store_true",
                        help="only the comparison with DEODR (benchmarks/deodr_comparison.py), its own section")
    parser.add_argument("--rounds", type=int, default=15, help="--deodr: interleaved rounds (medians reported)")
    parser.add_argument("--data", type=Path, default=Path(os.environ.get("MESHADV_DATA", Path(__file__).resolve()
                                                                       .parents[2] / "shared" / "data")),
                        help="--deodr: the shared data folder (the bunny)")
    parser.add_argument("--cpu-time", action="store_true",
                        help="--deodr: process CPU time instead of wall time (steadier on a busy machine; every "
                             "renderer runs on one thread, so on a quiet one the two agree)")
    args = parser.parse_args(argv)
    if args.deodr:
        return run_deodr_comparison(args, argv)

    face_counts = [1_000, 10_000] if args.quick else [1_000, 10_000, 100_000]
    sizes = [224] if args.quick else [224, 299, 512]
    batches = [1] if args.quick else [1, 8]
    threads_list = [1, 2]

    mi_version, mi_msg = (None, "skipped (--no-mitsuba)") if args.no_mitsuba else probe_mitsuba()
    print(f"mitsuba: {mi_version or mi_msg}", flush=True)
    p3d_version, p3d_msg = (None, "skipped (--no-pytorch3d)") if args.no_pytorch3d else probe_pytorch3d()
    print(f"pytorch3d: {p3d_version or p3d_msg}", flush=True)
    agreement = {}
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="render_bench_"))
    started, skipped = time.monotonic(), 0
    load_start = os.getloadavg()[0]
    projective = None
    if mi_version:
        # One cell with Mitsuba's visibility-aware integrator, for scale (it is far slower than the grid allows).
        projective = run_mitsuba(make_inputs(1_000, 1), 224, 1, 2, 1, tmp, integrator="direct_projective")
        print(f"mitsuba direct_projective 1k faces 224 px: {projective}", flush=True)
    for nf in face_counts:
        for batch in batches:
            inp = make_inputs(nf, batch)
            for size in sizes:
                cot = torch.randn(batch, 4, size, size, generator=torch.Generator().manual_seed(2))
                for threads in threads_list:
                    if time.monotonic() - started > args.max_minutes * 60:
                        skipped += 1
                        continue
                    row = {"faces": int(inp["faces"].shape[0]), "size": size, "batch": batch, "threads": threads}
                    for mode, bw in (("fwd", False), ("bwd", True)):
                        torch.set_num_threads(1)  # meshadv: only the Rust thread count varies
                        row[f"meshadv_{mode}"], _ = median_time(
                            meshadv_step(inp, size, threads, bw, cot), args.repeats, args.budget
                        )
                        if not args.no_torch and nf * batch <= args.torch_max_work:
                            torch.set_num_threads(threads)
                            row[f"torch_{mode}"], _ = median_time(
                                torch_step(inp, size, bw, cot), args.repeats, args.budget
                            )
                        if p3d_version and nf * size * size * batch <= args.pytorch3d_max_work:
                            torch.set_num_threads(threads)
                            row[f"p3d_{mode}"], _ = median_time(
                                pytorch3d_step(inp, size, bw, cot), args.repeats, args.budget
                            )
                    if p3d_version and (row["faces"], size) not in agreement and "p3d_fwd" in row:
                        agreement[row["faces"], size] = silhouette_agreement(inp, size)
                    if mi_version and batch <= args.mitsuba_max_batch:
                        res = run_mitsuba(inp, size, batch, threads, max(1, min(args.repeats, 3)), tmp)
                        if isinstance(res, dict):
                            row["mitsuba_fwd"], row["mitsuba_bwd"] = res["forward"], res["backward"]
                        else:
                            row["mitsuba_note"] = res
                            print(f"mitsuba: {res}", flush=True)
                    rows.append(row)
                    print(json.dumps(row), flush=True)

    info = machine_info()
    load_end = os.getloadavg()[0]
    cmd = "python benchmarks/render_bench.py" + (" " + " ".join(argv if argv is not None else sys.argv[1:])).rstrip()
    lines = [
        "## Renderer (`benchmarks/render_bench.py`)",
        "",
        f"Command: `{cmd.strip()}`  ",
        f"Machine: {info['cpu']}, {info['cores']} cores visible (shared with other jobs), {info['platform']}; "
        f"Python {info['python']}, PyTorch {info['torch']}, commit {info['commit']}, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.  ",
        f"Mitsuba 3 llvm_ad_rgb: {mi_version or mi_msg}.  ",
        f"PyTorch3D: {p3d_version or p3d_msg}.  ",
        f"1-minute load average {load_start:.1f} at the start and {load_end:.1f} at the end: the 2 cores were shared "
        "with other jobs, so timings (especially the 2-thread ones) are noisy upper bounds.",
        "",
        "Median wall time in ms. Mesh: bumpy UV sphere (about 1k/10k/100k faces) filling ~40% of the image, "
        "per-face colours, one directional light + ambient, views at azimuths spread over 0-315°.",
        "* **meshadv**: `meshadv.render.render` (one native op for float32: camera projection, Lambert shading, "
        "Rust rasterizer, RGB + alpha, and their adjoint), "
        "Rust `num_threads` = thr, `torch.set_num_threads(1)` for the small PyTorch part.",
        "* **torch**: the same camera + shading with the vectorised pure-PyTorch rasterizer "
        "(benchmarks/torch_reference_rasterizer.py: same hard image model; backward = exact attribute gradient plus "
        "straight-through soft-coverage vertex gradient), `torch.set_num_threads(threads)`.",
        "* **mitsuba**: Mitsuba 3 `llvm_ad_rgb`, `direct` integrator, 1 spp, the same mesh and cameras rendered one "
        "view at a time (batch = views), backward = gradient of the mean pixel w.r.t. vertex positions; "
        "`dr.set_thread_count(threads)`. A physically based renderer (ray traced, emitter sampling), shown for scale, "
        "not the same image model; `direct` ignores visibility discontinuities in the gradient "
        "(the visibility-aware `direct_projective` is timed once, below).",
        "* **p3d**: PyTorch3D's CPU rasterizer (`rasterize_meshes`, naive: PyTorch3D has no binned CPU path, so it "
        "tests every face at every pixel) after the same camera + shading, `torch.set_num_threads(threads)`; "
        "forward = hard rasterization (1 face per pixel, each pixel its face's shaded colour); fwd+bwd = its soft "
        f"rasterizer ({P3D_FACES_PER_PIXEL} faces per pixel, blur radius {P3D_BLUR_RADIUS:.2e}) and SoftRas blending "
        f"(`softmax_rgb_blend`, sigma = gamma = {P3D_SIGMA:g}), its route to vertex gradients: not NMR's gradient. "
        f"Cells above {args.pytorch3d_max_work:.0e} faces x pixels x batch are skipped (–).",
        "* fwd+bwd: forward then backward of a random linear loss of RGB and alpha w.r.t. vertices and colours.",
        "",
        reading(rows),
        "",
        "| faces | px | batch | thr | meshadv fwd | torch fwd | speed-up | p3d fwd | speed-up | mitsuba fwd | "
        "meshadv fwd+bwd | torch fwd+bwd | speed-up | p3d fwd+bwd | speed-up | mitsuba fwd+bwd |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['faces']} | {r['size']} | {r['batch']} | {r['threads']} | {fmt(r.get('meshadv_fwd'))} | "
            f"{fmt(r.get('torch_fwd'))} | {ratio(r.get('meshadv_fwd'), r.get('torch_fwd'))} | "
            f"{fmt(r.get('p3d_fwd'))} | {ratio(r.get('meshadv_fwd'), r.get('p3d_fwd'))} | "
            f"{fmt(r.get('mitsuba_fwd'))} | {fmt(r.get('meshadv_bwd'))} | {fmt(r.get('torch_bwd'))} | "
            f"{ratio(r.get('meshadv_bwd'), r.get('torch_bwd'))} | {fmt(r.get('p3d_bwd'))} | "
            f"{ratio(r.get('meshadv_bwd'), r.get('p3d_bwd'))} | {fmt(r.get('mitsuba_bwd'))} |"
        )
    if agreement:
        lines += [
            "",
            "PyTorch3D's hard silhouette against meshadv's (fraction of pixels where both agree on coverage, first "
            "view): "
            + ", ".join(f"{nf} faces / {px} px {share:.4f}" for (nf, px), share in sorted(agreement.items()))
            + ".",
        ]
    if isinstance(projective, dict):
        lines += [
            "",
            "Mitsuba `direct_projective` (visibility-aware gradients), 1k faces, 224 px, batch 1, 2 threads: "
            f"forward {fmt(projective['forward'])} ms, fwd+bwd {fmt(projective['backward'])} ms.",
        ]
    elif projective is not None:
        lines += ["", f"Mitsuba `direct_projective`: {projective}"]
    if skipped:
        lines += ["", f"{skipped} cells were not run: the --max-minutes limit ({args.max_minutes}) was reached."]
    notes = sorted({r["mitsuba_note"] for r in rows if "mitsuba_note" in r})
    if notes:
        lines += ["", "Mitsuba errors: " + "; ".join(notes)]
    write_section(args.out, "\n".join(lines))
    print(f"wrote {args.out}")
    return 0


def run_deodr_comparison(args: argparse.Namespace, argv: list[str] | None) -> int:
    """``--deodr``: the comparison of benchmarks/deodr_comparison.py, written to its own section of ``args.out``."""
    import deodr_comparison

    version, why = deodr_comparison.probe_deodr()
    print(f"deodr: {version or why}", flush=True)
    load_start = os.getloadavg()[0]
    clock = time.process_time if args.cpu_time else time.perf_counter
    rows = deodr_comparison.compare(args.data, args.rounds, version is not None, clock)
    info = machine_info()
    machine = (f"{info['cpu']}, {info['cores']} cores visible, shared (1-minute load {load_start:.1f} at the start, "
               f"{os.getloadavg()[0]:.1f} at the end); Python {info['python']}, PyTorch {info['torch']}, commit "
               f"{info['commit']}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    cmd = "python benchmarks/render_bench.py " + " ".join(argv if argv is not None else sys.argv[1:])
    write_section(args.out, deodr_comparison.section(rows, cmd.strip(), machine, version or why), DEODR_MARKS)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
