"""Does Mitsuba draw a texture times vertex colours as meshadv does? The conversion check on generated spheres.

A UV sphere (16 x 32 segments) with a 32 x 64 checker texture (the one of ``tests/test_transfer_surface.py``), with
and without smooth vertex colours (0.5 + 0.45 x the position / its largest coordinate, per channel), both loaded back
from a GLB written by meshadv (``COLOR_0`` beside the base-colour texture). Each is drawn by meshadv's surface path and
by Mitsuba (the bitmap times the ``vertex_color`` mesh attribute through the ``meshadv_product`` texture of
:mod:`meshadv.transfer.mitsuba_product`) at ``--size`` px and ``--spp`` samples, head light, flat and smooth, and
compared as ``meshadv transfer check`` compares them (:func:`meshadv.transfer.mitsuba_check.conversion_check`): mask
IoU and the mean and 95th percentile of the interior per-pixel mean absolute RGB difference. The two renders of each
case are saved side by side as ``<out>/<case>_<shading>.png`` (meshadv left, Mitsuba right).

Command (the numbers in benchmarks/RESULTS.md):
    OMP_NUM_THREADS=1 RAYON_NUM_THREADS=1 PYTHONPATH=python python3 benchmarks/mitsuba_texture_colours.py \\
        --out /tmp/mitsuba_texture_colours
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_transfer_surface import _checker_sphere  # noqa: E402

from meshadv.mesh.surface_mesh import SurfaceMesh, load_surface_mesh, save_surface_mesh  # noqa: E402
from meshadv.transfer.mitsuba_check import conversion_check, head_light_record  # noqa: E402


def _cases(folder: Path) -> dict[str, SurfaceMesh]:
    """The texture-only and the texture-times-colours sphere, each written as GLB and loaded back."""
    textured = _checker_sphere()
    v = textured.vertices
    both = SurfaceMesh(textured.mesh, textured.uvs, textured.uv_faces, textured.texture,
                       0.5 + 0.45 * v / v.abs().max()).with_texture(textured.texture)
    out = {}
    for name, mesh in (("texture", textured), ("texture_x_colours", both)):
        save_surface_mesh(mesh, folder / f"{name}.glb")
        out[name] = load_surface_mesh(folder / f"{name}.glb")
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--out", type=Path, default=Path("/tmp/mitsuba_texture_colours"))
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cases = _cases(Path(tmp))
        for name, mesh in cases.items():
            assert (mesh.vertex_colors is not None) == (name != "texture"), name
            for shading in ("flat", "smooth"):
                start = time.perf_counter()
                check = conversion_check(mesh, head_light_record(3.5, 30.0, 20.0, 0.5, 0.5), image_size=args.size,
                                         spp=args.spp, shading=shading)
                rows.append({"case": name, "shading": shading, "mask_iou": round(check.mask_iou, 4),
                             "mean": round(check.mean_abs_difference, 4), "p95": round(check.p95_abs_difference, 4),
                             "interior_pixels": check.interior_pixels,
                             "seconds": round(time.perf_counter() - start, 1)})
                side = np.concatenate([check.meshadv_image, check.mitsuba_image], axis=1)
                Image.fromarray((np.clip(side, 0, 1) * 255 + 0.5).astype(np.uint8)).save(
                    args.out / f"{name}_{shading}.png")
    print("| case | shading | mask IoU | mean | p95 | interior px | s |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['shading']} | {r['mask_iou']} | {r['mean']} | {r['p95']} | {r['interior_pixels']} "
              f"| {r['seconds']} |")
    (args.out / "results.json").write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
