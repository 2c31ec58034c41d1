"""Renders for choosing the perceptibility cap: an attack's vertex flow scaled to several largest moves, and capped
attacks, side by side with the benign mesh, with every perceptibility measure written beside them.

Two modes:

* ``scale``: for each saved ``meshadv attack`` result folder, the flow ``adversarial - benign`` scaled so that its
  largest vertex move is each of ``--moves`` (fractions of the bounding-box diagonal; for a texture attack the colour
  change scaled so that its area-weighted 95th percentile is each value) is rendered on the attack's centre view and
  on the held-out views (:func:`meshadv.perceptibility.held_out_views`); one PNG per folder (rows: benign, then each
  value; columns: views) and ``scale.json`` with the measures of every row. What a cap of each value lets through,
  on the changes the attack really makes.
* ``attack``: ``meshadv attack MESH --target T`` under each cap of ``--caps`` (``max_displacement`` values, the other
  ceilings of ``--cap-rest``) into ``OUT/<mesh>_<cap>/``, then the same grid of the kept results.

Example:
    python benchmarks/cap_renders.py scale /tmp/free_sofa_01 --moves 0.005,0.01,0.02,0.04,0.08 -o /tmp/cap_scale
    python benchmarks/cap_renders.py attack pascal3d/sofa/01.ply --target chair --caps 0.01,0.02,0.04 -o /tmp/caps
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, Dict, List, Sequence

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("RAYON_NUM_THREADS", "1")

import torch  # noqa: E402

torch.set_num_threads(1)


def _benign_and_adversarial(folder: Path) -> tuple[Any, Any, Dict[str, Any]]:
    """The benign (normalised as the attack loaded it) and adversarial meshes of a result folder, and its record."""
    from meshadv.attacks.result import load_result_record
    from meshadv.commands._common import load_mesh_input
    from meshadv.mesh import load_mesh

    record = load_result_record(folder)
    entry = record["input"]
    benign = load_mesh_input(entry["path"], z_up=entry["z_up"], say=False).mesh
    adversarial = load_mesh(folder / record["meshes"][0][0])
    return benign, adversarial, record


def _grid(rows: Sequence[Any], labels: Sequence[str], path: Path) -> None:
    """A PNG of ``rows`` (each ``(V, 3, H, W)``) with one label line above each row."""
    from PIL import Image, ImageDraw

    views, _, height, width = rows[0].shape
    line = 18
    canvas = Image.new("RGB", (views * width, len(rows) * (height + line)), "white")
    draw = ImageDraw.Draw(canvas)
    for r, (images, label) in enumerate(zip(rows, labels)):
        y = r * (height + line)
        draw.text((4, y + 2), label, fill="black")
        for v in range(views):
            array = (images[v].clamp(0, 1).permute(1, 2, 0).numpy() * 255).round().astype("uint8")
            canvas.paste(Image.fromarray(array), (v * width, y + line))
    path.parent.mkdir(parents=True, exist_ok=True)
    canvas.save(path)


def _views(record: Dict[str, Any]) -> Any:
    """The attack's centre view followed by its held-out views."""
    from meshadv.perceptibility import held_out_views
    from meshadv.render import ViewSet

    views = ViewSet.from_records(record["views"])
    return ViewSet.cat([views[len(views) // 2], held_out_views(views)]), views


def _label(name: str, measures: Dict[str, float]) -> str:
    return (f"{name}: move max {100 * measures['max_displacement']:.2g}% p95 {100 * measures['p95_displacement']:.2g}%"
            f", normals mean {measures['normal_change_mean_deg']:.2g} p95 {measures['normal_change_p95_deg']:.2g} deg"
            f", edge strain p95 {measures.get('edge_strain_p95', float('nan')):.2g}"
            f", SSIM held-out min {measures['ssim_held_out_min']:.3f}")


def scale(folders: Sequence[Path], moves: Sequence[float], out: Path, size: int) -> None:
    """The ``scale`` mode (module docstring)."""
    from meshadv.perceptibility import color_changes, perceptibility_measures
    from meshadv.render import RenderSetup

    setup = RenderSetup(image_size=size)
    summary: Dict[str, Any] = {}
    for folder in folders:
        benign, adversarial, record = _benign_and_adversarial(folder)
        shown, views = _views(record)
        if record["perturbation"] == "texture":  # the colour change scaled to each 95th percentile instead
            from meshadv.mesh import Mesh

            delta = adversarial.face_colors - benign.face_colors
            largest = float(color_changes(adversarial.face_colors, benign.face_colors, benign.vertices,
                                          benign.faces)["color_change_p95"][0])
            meshes = [Mesh(benign.vertices, benign.faces, (benign.face_colors + delta * (m / largest)).clamp(0, 1))
                      for m in moves]
        else:
            flow = adversarial.vertices - benign.vertices
            largest = float(flow.norm(dim=1).max()) / benign.bbox_diagonal()
            meshes = [benign.with_vertices(benign.vertices + flow * (m / largest)) for m in moves]
        measures = perceptibility_measures(benign, meshes, views, setup)
        with torch.no_grad():
            rows = [setup.render(benign.vertices[None], benign.faces, benign.face_colors, shown)[0]]
            rows += [setup.render(m.vertices[None], m.faces, m.face_colors, shown)[0] for m in meshes]
        if record["perturbation"] == "texture":
            labels = [f"benign {folder.name} (attack's own colour change p95 {largest:.3g})"]
            labels += [f"colour change scaled to p95 {m:g}: measured {d['color_change_p95']:.3g}, SSIM held-out min "
                       f"{d['ssim_held_out_min']:.3f}" for m, d in zip(moves, measures)]
        else:
            labels = [f"benign {folder.name} (attack's own largest move {100 * largest:.3g}%)"]
            labels += [_label(f"flow scaled to {100 * m:g}%", d) for m, d in zip(moves, measures)]
        _grid(rows, labels, out / f"{folder.name}_scaled.png")
        summary[folder.name] = {"attack_max_displacement": largest,
                                "rows": [{"move": m, **d} for m, d in zip(moves, measures)]}
    (out / f"scale_{'_'.join(f.name for f in folders)}.json").write_text(json.dumps(summary, indent=1) + "\n")


def attack(mesh: str, target: str, caps: Sequence[float], rest: str, steps: int, out: Path, size: int) -> None:
    """The ``attack`` mode (module docstring)."""
    from meshadv.attacks.result import load_result_record
    from meshadv.render import RenderSetup

    stem = Path(mesh).parent.name + "_" + Path(mesh).stem
    folders: List[Path] = []
    for cap in caps:
        folder = out / f"{stem}_{cap:g}"
        folders.append(folder)
        if (folder / "result.json").is_file():
            continue  # finished before: resumed
        spec = f"max_displacement={cap}" + (f",{rest}" if rest else "")
        subprocess.run([sys.executable, "-m", "meshadv", "attack", mesh, "--target", target, "--cap", spec,
                        "--steps", str(steps), "--quiet", "--threads", "1", "--benign-wrong-ok", "-o", str(folder)],
                       check=True)
    setup = RenderSetup(image_size=size)
    rows, labels, summary = [], [], {}
    for cap, folder in zip(caps, folders):
        benign, adversarial, record = _benign_and_adversarial(folder)
        shown, _ = _views(record)
        with torch.no_grad():
            if not rows:
                rows.append(setup.render(benign.vertices[None], benign.faces, benign.face_colors, shown)[0])
                labels.append(f"benign {stem}")
            rows.append(setup.render(adversarial.vertices[None], adversarial.faces, adversarial.face_colors,
                                     shown)[0])
        record = load_result_record(folder)
        d = record["distances"][0]
        labels.append(_label(f"cap {100 * cap:g}%: {'SUCCESS' if record['succeeded'][0] else 'failed'} "
                             f"{sum(record['success'][0])}/{len(record['success'][0])} views", d))
        summary[f"{cap:g}"] = {"succeeded": record["succeeded"][0], "success": record["success"][0],
                               "eval_success": record.get("eval_success"), **d}
    _grid(rows, labels, out / f"{stem}_caps.png")
    (out / f"{stem}_caps.json").write_text(json.dumps(summary, indent=1) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="mode", required=True)
    scaled = sub.add_parser("scale", help="scale saved attacks' flows to several largest moves")
    scaled.add_argument("folders", nargs="+", type=Path)
    scaled.add_argument("--moves", default="0.005,0.01,0.02,0.04,0.08")
    capped = sub.add_parser("attack", help="attack one mesh under several caps")
    capped.add_argument("mesh")
    capped.add_argument("--target", required=True)
    capped.add_argument("--caps", default="0.01,0.02,0.04")
    capped.add_argument("--cap-rest", default="", help="the other ceilings, e.g. normal_change_p95_deg=none")
    capped.add_argument("--steps", type=int, default=300)
    for p in (scaled, capped):
        p.add_argument("-o", "--out", type=Path, required=True)
        p.add_argument("--size", type=int, default=160)
    args = parser.parse_args()
    if args.mode == "scale":
        scale(args.folders, [float(x) for x in args.moves.split(",")], args.out, args.size)
    else:
        attack(args.mesh, args.target, [float(x) for x in args.caps.split(",")], args.cap_rest, args.steps, args.out,
               args.size)


if __name__ == "__main__":
    main()
