"""``meshadv render``: look at a mesh as the victim sees it (PNG per view, optional top-5 predictions).

Example:
    $ meshadv render ../shared/data/pascal3d/chair/01.ply --views 4 --azimuths 0:270 \\
          --victim efficientnet_lite0 -o out/r
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from meshadv.commands._surface_views import SHADING_HELP
from meshadv.commands._common import (
    DEFAULT_BACKGROUND,
    DEFAULT_DISTANCE,
    DEFAULT_ELEVATION,
    load_mesh_input,
    make_views,
    parse_azimuth_range,
    parse_color,
    topk_labels,
)

__all__ = ["render"]


def render(
    mesh: str = typer.Argument(..., help="mesh file (PLY/OBJ/OFF), builtin:NAME, or 'default'"),
    views: int = typer.Option(4, help="number of views"),
    azimuths: str = typer.Option("150:210", help="azimuth range LOW:HIGH or LOW-HIGH (degrees); 180 faces the front "
                                                 "of a PASCAL3D+ model"),
    elevation: float = typer.Option(DEFAULT_ELEVATION, help="camera elevation (degrees)"),
    distance: float = typer.Option(DEFAULT_DISTANCE, help="camera distance (mesh normalised to [-1, 1])"),
    image_size: int = typer.Option(224, min=1, max=16384, help="image size in pixels"),
    background: str = typer.Option(DEFAULT_BACKGROUND, help="background colour r,g,b in [0, 1]"),
    victim: Optional[str] = typer.Option(None, help="also print this classifier's top-5 (or detector's boxes); "
                                                    "efficientnet_lite0/2, ssd_mobilenet_v2_coco, densenet121, "
                                                    "inception_v3, yolov3"),
    weights: Optional[Path] = typer.Option(None, help="weights file of densenet121 / inception_v3 / yolov3"),
    cfg: Optional[Path] = typer.Option(None, help="Darknet .cfg file (yolov3 only)"),
    z_up: Optional[bool] = typer.Option(None, "--z-up/--y-up", help="mesh file is Z-up (default: guess)"),
    shading: Optional[str] = typer.Option(None, help=SHADING_HELP),
    output: Path = typer.Option(..., "-o", "--output", help="output folder"),
) -> None:
    """Render MESH from VIEWS azimuths and write view_{j}.png (+ predictions.json with --victim) into OUTPUT."""
    import torch

    from meshadv.commands._surface_views import parse_shading, render_file_surface
    from meshadv.render import RenderSetup, render_views
    from meshadv.util.atomic import write_json_atomic
    from meshadv.util.png import save_png

    try:
        shading = parse_shading(shading)
        loaded = load_mesh_input(mesh, z_up=z_up)
        mesh_obj, label = loaded.mesh, loaded.label
        view_set = make_views(views, parse_azimuth_range(azimuths), elevation, distance)
        bg = parse_color(background)
        images = render_file_surface(loaded, view_set, image_size, bg, shading)
    except (ValueError, FileNotFoundError) as exc:
        raise typer.BadParameter(str(exc)) from exc
    output.mkdir(parents=True, exist_ok=True)
    if images is None:
        with torch.no_grad():
            images, _ = render_views(mesh_obj.vertices.unsqueeze(0), mesh_obj.faces, mesh_obj.face_colors, view_set,
                                     RenderSetup(image_size=image_size, background=bg))
    records = []
    for j, rec in enumerate(view_set.to_records()):
        name = f"view_{j}.png"
        save_png(images[j], output / name)  # atomic (meshadv.util.atomic)
        records.append({"file": name, "azimuth": rec["azimuth"], "elevation": rec["elevation"],
                        "distance": rec["distance"]})
    typer.echo(f"{label}: {mesh_obj.num_vertices} vertices, {mesh_obj.num_faces} faces; wrote {len(records)} views")
    if victim is not None:
        from meshadv.victims import load_victim

        try:
            model = load_victim(victim, weights=weights, cfg=cfg)
        except (ValueError, FileNotFoundError, ImportError) as exc:
            raise typer.BadParameter(str(exc)) from exc
        with torch.no_grad():
            if model.kind == "classifier":
                top = topk_labels(model(images), list(model.class_names))
                for j, rows in enumerate(top):
                    records[j]["top5"] = [{"label": n, "probability": p} for n, p in rows]
                    typer.echo(f"  view {j} (az {records[j]['azimuth']:.0f}): "
                               + ", ".join(f"{n} {p:.2f}" for n, p in rows))
            else:
                for j, det in enumerate(model.detect(images)):
                    records[j]["detections"] = det.to_records()
                    typer.echo(f"  view {j}: " + (", ".join(f"{r['label']} {r['score']:.2f}"
                                                            for r in det.to_records()) or "no detections"))
    write_json_atomic({"mesh": label, "victim": victim, "image_size": image_size, "views": records},
                      output / "predictions.json")
    typer.echo(f"wrote {output}")
