"""``meshadv demo``: a complete shape attack in about a minute on 2 CPU cores.

The default mesh (the shared PASCAL3D+ chair when the shared data exist, else the built-in chair) is rendered from
2 views (azimuths 165 and 195, around the front) at 128 px against the real EfficientNet-Lite0. Unless ``--target``
is given, the target is the class the pristine renders rank highest after the current top-1 (averaged over the
views), a reachable but real change of label. The shape attack (Laplacian-regularised vertex flow, Adam lr 5e-3,
lambda 0.01, C&W margin loss, early stopping once the target leads by 0.5 logits for 2 steps) then writes
before/after PNGs, a side-by-side ``comparison.png``, the adversarial mesh (PLY, OBJ) and ``result.json``.

Example:
    $ meshadv demo -o out/demo
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional, Tuple

import typer

from meshadv.commands._common import DEFAULT_DISTANCE, DEFAULT_ELEVATION, load_mesh_arg, make_views

__all__ = ["demo", "pick_target", "comparison_image"]


def pick_target(logits: Any) -> Tuple[int, int]:
    """``(current top-1, runner-up)`` of the mean softmax over views of ``(V, C)`` logits."""
    import torch

    probs = torch.softmax(logits.detach().float(), dim=1).mean(dim=0)
    top2 = probs.topk(2).indices.tolist()
    return int(top2[0]), int(top2[1])


def comparison_image(before: Any, after: Any) -> Any:
    """Stack ``(V, 3, H, W)`` before / after renders into one ``(3, 2H, V*W)`` image (top row before)."""
    import torch

    top = torch.cat(list(before), dim=2)
    bottom = torch.cat(list(after), dim=2)
    return torch.cat([top, bottom], dim=1)


def demo(
    mesh: str = typer.Option("default", help="mesh file, builtin:NAME, or 'default'"),
    victim: str = typer.Option("efficientnet_lite0", help="classifier victim"),
    target: Optional[str] = typer.Option(None, help="target class (default: the pristine runner-up)"),
    views: int = typer.Option(2, help="number of victim views (spread over azimuths 165..195)"),
    image_size: int = typer.Option(128, help="rendered image size (the victim resizes to its input size)"),
    steps: int = typer.Option(100, help="maximum Adam steps"),
    seed: int = typer.Option(0, help="random seed"),
    quiet: bool = typer.Option(False, help="no progress bar"),
    output: Path = typer.Option(Path("meshadv-demo"), "-o", "--output", help="output folder"),
) -> None:
    """Run a complete shape attack on a built-in default mesh against a real victim and save the result."""
    import torch

    from meshadv.attacks import ShapeAttack, TargetedMisclassification
    from meshadv.render import RenderSetup, render_views
    from meshadv.attacks.result import save_png
    from meshadv.commands.attack import run_with_progress
    from meshadv.victims import load_victim

    torch.manual_seed(seed)
    try:
        mesh_obj, label = load_mesh_arg(mesh)
        model = load_victim(victim)
    except (ValueError, FileNotFoundError, ImportError) as exc:
        raise typer.BadParameter(str(exc)) from exc
    if model.kind != "classifier":
        raise typer.BadParameter(f"victim {victim} is a {model.kind}; the demo attacks a classifier")
    view_set = make_views(views, (165.0, 195.0), DEFAULT_ELEVATION, DEFAULT_DISTANCE)
    names = list(model.class_names)
    with torch.no_grad():
        images, _ = render_views(mesh_obj.vertices.unsqueeze(0), mesh_obj.faces, mesh_obj.face_colors, view_set,
                                 RenderSetup(image_size=image_size))
        top1, runner_up = pick_target(model(images))
    goal = target if target is not None else runner_up
    typer.echo(f"mesh {label} ({mesh_obj.num_faces} faces), {views} views at {image_size} px; "
               f"pristine top-1 '{names[top1]}', target '{goal if target is not None else names[runner_up]}'")
    attack_obj = ShapeAttack(steps=steps, lr=5e-3, lambda_perceptual=0.01, loss="cw", early_stop=2,
                             early_stop_margin=0.5, seed=seed)
    try:
        criterion = TargetedMisclassification(goal)
        result = run_with_progress(attack_obj, mesh_obj, view_set, model, [criterion],
                                   setup=RenderSetup(image_size=image_size), quiet=quiet)
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from exc
    path = result.save(output)
    tmp = output / ".tmp-comparison.png"
    save_png(comparison_image(result.original_images, result.images[0]), tmp)
    tmp.replace(output / "comparison.png")
    typer.echo(result.summary())
    typer.echo(f"wrote {path} and {output / 'comparison.png'}")
