"""Does MeshLab resampling of a textured mesh keep its look? Render the original and three resamplings and compare.

For each generated mesh (built-in shapes with box-projected UVs and a generated 256 x 256 texture of smooth colour
fields and stripes; no downloads), resampled uniformly to about ``--faces`` faces:

* ``texture_transfer``: :func:`meshadv.mesh.surface_resample.resample_surface_mesh` (a new per-triangle texture
  atlas filled from the original texture at the closest point), what ``meshadv attack`` does;
* ``vertex_colours``: the texture's colour at the closest point per new vertex (MeshLab
  ``transfer_texture_to_color_per_vertex``), interpolated;
* ``per_face``: the original face colours (the texture at each face's UV centroid) carried to the new faces by
  nearest centroid (what resampling a per-face mesh does).

Each is rendered smooth from 4 azimuths at 128 px and compared with the original's render over the pixels all
renders cover (eroded by one pixel): mean and 95th percentile of the per-pixel mean absolute RGB difference. The
renders are saved side by side (original, texture transfer, vertex colours, per face) as ``<out>/<mesh>.png``.

Command (the numbers in benchmarks/RESULTS.md):
    OMP_NUM_THREADS=1 RAYON_NUM_THREADS=1 PYTHONPATH=python python3 benchmarks/surface_resample.py \\
        --out /tmp/surface_resample
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from surface_assets import box_textured  # noqa: E402

from meshadv.mesh import resample_mesh_with_info  # noqa: E402
from meshadv.mesh.surface_mesh import SurfaceMesh, save_surface_mesh  # noqa: E402
from meshadv.mesh.surface_resample import resample_surface_mesh  # noqa: E402
from meshadv.render import ViewSet, render, render_surface  # noqa: E402
from meshadv.util.atomic import write_json_atomic  # noqa: E402


def generated_texture(side: int = 256) -> torch.Tensor:
    """A (side, side, 3) texture: smooth colour fields plus stripes (edges of several widths)."""
    y, x = torch.meshgrid(torch.linspace(0, 1, side), torch.linspace(0, 1, side), indexing="ij")
    r = 0.5 + 0.4 * torch.sin(6.0 * x + 2.0 * y)
    g = 0.5 + 0.4 * torch.cos(9.0 * y - 3.0 * x)
    b = ((torch.floor(x * 12) + torch.floor(y * 5)) % 2) * 0.8 + 0.1
    return torch.stack([r, g, b], -1).clamp(0, 1)


def _vertex_colour_baseline(surface: SurfaceMesh, dense: Any) -> torch.Tensor:
    """(N,3) the texture's colour at the closest source point of each new vertex (MeshLab)."""
    import pymeshlab

    with tempfile.TemporaryDirectory() as tmp:
        save_surface_mesh(surface, Path(tmp) / "s.obj")
        ms = pymeshlab.MeshSet()
        ms.load_new_mesh(str(Path(tmp) / "s.obj"))
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=dense.vertices.double().numpy(),
                                   face_matrix=dense.faces.int().numpy()))
        ms.transfer_texture_to_color_per_vertex(sourcemesh=0, targetmesh=1)
        return torch.as_tensor(np.asarray(ms.mesh(1).vertex_color_matrix())[:, :3], dtype=torch.float32)


def _erode(mask: np.ndarray) -> np.ndarray:
    p = np.pad(mask, ((0, 0), (1, 1), (1, 1)))
    return p[:, 1:-1, 1:-1] & p[:, :-2, 1:-1] & p[:, 2:, 1:-1] & p[:, 1:-1, :-2] & p[:, 1:-1, 2:]


def measure(name: str, faces: int, out: Path) -> dict[str, Any]:
    """One mesh's row: face counts and the three resamplings' differences to the original render."""
    source = box_textured(name, 16)
    source = source.with_texture(generated_texture())
    views = ViewSet.orbit([0.0, 90.0, 180.0, 270.0], elevation=20.0, distance=3.0)

    def draw(s: Any, **kw: Any) -> tuple[np.ndarray, np.ndarray]:
        o = render_surface(s.vertices, s.faces, views.camera, views.lights, 128, shading="smooth", **kw)
        return o.image.permute(0, 2, 3, 1).numpy(), o.alpha[:, 0].numpy() > 0.5

    with torch.no_grad():
        ref, mask = draw(source, texture=source.texture, uvs=source.uvs, uv_faces=source.uv_faces)
        moved, _ = resample_surface_mesh(source, target_faces=faces)
        dense, info = resample_mesh_with_info(source.mesh, target_faces=faces)
        renders = {"texture_transfer": draw(moved, texture=moved.texture, uvs=moved.uvs, uv_faces=moved.uv_faces),
                   "vertex_colours": draw(dense, vertex_colors=_vertex_colour_baseline(source, dense))}
        flat = render(dense.vertices, dense.faces, dense.face_colors, views.camera, views.lights, 128)
        renders["per_face"] = (flat.image.permute(0, 2, 3, 1).numpy(), flat.alpha[:, 0].numpy() > 0.5)
    for _, m in renders.values():
        mask = mask & m
    inside = _erode(mask)
    row: dict[str, Any] = {"mesh": name, "faces_in": source.num_faces, "faces_out": moved.num_faces,
                           "texture_side": int(moved.texture.shape[0]), "method": info.method}
    for key, (img, _) in renders.items():
        d = np.abs(img - ref).mean(-1)[inside]
        row[key] = {"mean": round(float(d.mean()), 4), "p95": round(float(np.percentile(d, 95)), 4)}
    strip = np.concatenate([np.concatenate([ref[v]] + [renders[k][0][v] for k in renders], 1) for v in range(2)])
    Image.fromarray((strip * 255 + 0.5).astype(np.uint8)).save(out / f"{name}.png")
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--meshes", default="sphere,bottle,chair")
    parser.add_argument("--faces", type=int, default=4000)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in args.meshes.split(","):
        rows.append(measure(name, args.faces, args.out))
        print(json.dumps(rows[-1]))
        write_json_atomic({"faces": args.faces, "rows": rows}, args.out / "results.json")


if __name__ == "__main__":
    main()
