"""``meshadv attack-scene``: hide a detection by perturbing one object of a scene (indoor desk or a real photo)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

#: Default Adam learning rates: for shape in units of the object's bounding-box diagonal per step (small: NMR
#: gradients are heavy-tailed and Adam moves every parameter that receives any gradient by about lr per step), for
#: texture in logit units per step.
DEFAULT_LR = {"shape": 5e-4, "texture": 0.05}

SCENE_HELP = (
    "'indoor' (the shared desk scene), a Mitsuba scene XML file, or a photograph (.jpg/.png) to insert --object into"
)


def attack_scene(
    scene: str = typer.Argument(..., help=SCENE_HELP),
    victim: str = typer.Option("ssd_mobilenet_v2_coco", help="detector victim: ssd_mobilenet_v2_coco (weights "
                                                             "included) or yolov3 (--weights, --cfg)"),
    weights: Optional[Path] = typer.Option(None, help="yolov3: the Darknet .weights file"),
    cfg: Optional[Path] = typer.Option(None, help="yolov3: the Darknet .cfg file"),
    hide: str = typer.Option("all", help="COCO class to hide (e.g. 'dining table', 'dog') or 'all'"),
    perturbation: str = typer.Option("shape", "--perturbation", "--perturb",
                                     help="shape or texture (--perturb is the old name)"),
    obj: str = typer.Option(
        "bunny", "--object", help="object to perturb (scene object name, or a mesh file for photos)"
    ),
    place: str = typer.Option("0.5,0.75,0.3", help="photo only: u,v,height_fraction of the inserted object"),
    steps: int = typer.Option(300, help="maximum Adam steps"),
    lr: Optional[float] = typer.Option(None, help="Adam learning rate (default: 5e-4 for shape, in units of the "
                                                   "object's bounding-box diagonal; 0.05 for texture, logit units)"),
    smoothing: int = typer.Option(8, help="shape only: neighbour-averaging iterations of the flow parameters"),
    lambda_perceptual: float = typer.Option(1.0, "--lambda", help="perceptual loss weight (texture: per pixel)"),
    threshold: float = typer.Option(0.5, help="detection score threshold"),
    width: Optional[int] = typer.Option(None, help="render width (default: the scene's / photo's own)"),
    seed: int = typer.Option(0, help="random seed"),
    output: Path = typer.Option(Path("out/attack-scene"), "-o", "--output", help="output folder"),
) -> None:
    """Hide CLASS (or everything) from a detector by perturbing only one object; writes before/after images with
    detections drawn, the adversarial object mesh and a JSON record."""
    from meshadv.attacks import Disappearance, make_attack
    from meshadv.attacks.families import check_perturbation
    from meshadv.mesh import save_mesh
    from meshadv.scenes.attack import attack_scene
    from meshadv.scenes.draw import draw_detections
    from meshadv.util.atomic import write_json_atomic
    from meshadv.util.png import save_png
    from meshadv.scenes.setups import build_setup
    from meshadv.victims import load_victim

    try:
        check_perturbation(perturbation, "--perturbation")
        setup = build_setup(scene, obj, place, width)
    except (ValueError, FileNotFoundError) as exc:
        raise typer.BadParameter(str(exc)) from exc
    detector = load_victim(victim, weights=weights, cfg=cfg)
    criterion = Disappearance(hide, threshold=threshold)
    _require_something_to_hide(setup, detector, criterion, hide, threshold)
    if lr is None:
        lr = DEFAULT_LR[perturbation]
    # the same attacks as everywhere: stop once the hidden score stayed 0.05 below the threshold for 5 steps
    common = dict(steps=steps, early_stop=5, early_stop_margin=0.05, seed=seed)
    if perturbation == "shape":  # lr in units of the object's bounding-box diagonal
        attack = make_attack("shape", lr=lr * float(setup.mesh.bbox_diagonal()), smoothing=smoothing,
                             lambda_perceptual=lambda_perceptual, **common)
    else:  # the image smoothness loss sums over pixels: --lambda is per pixel
        pixels = setup.camera.width * setup.camera.height
        attack = make_attack("texture", lr=lr, lambda_perceptual=lambda_perceptual / pixels, **common)

    def progress(info: object) -> None:
        step = info.total_step  # type: ignore[attr-defined]
        if step == 1 or step % 10 == 0:
            typer.echo(f"step {step:4d}  loss {info.loss[0]:.4f}  margin {info.margin[0]:.3f}")  # type: ignore

    result = attack_scene(attack, setup, detector, criterion, callback=progress)
    output.mkdir(parents=True, exist_ok=True)
    (output / "result.json").unlink(missing_ok=True)  # no earlier record beside new files if this save is killed
    save_png(draw_detections(result.image_before, result.detections_before), output / "before.png")
    save_png(draw_detections(result.image_after, result.detections_after), output / "after.png")
    save_mesh(result.object_mesh, output / "adversarial.ply")
    record = {
        "scene": scene,
        "object": setup.object_name,
        "victim": victim,
        "hide": hide,
        "perturbation": perturbation,
        **result.to_record(),
    }
    write_json_atomic(record, output / "result.json")
    if result.interrupted:
        typer.echo("interrupted: saved the best result so far (result.json says interrupted: true)")
    typer.echo(
        f"{'success' if result.success else 'failure'}: hidden score {result.score_before:.3f} -> "
        f"{result.score_after:.3f} in {result.steps} steps; wrote {output}"
    )


def _require_something_to_hide(setup: object, detector: object, criterion: object, hide: str,
                               threshold: float) -> None:
    """Refuse (one line) when the benign scene has no detection of ``hide`` above ``threshold``: nothing to hide."""
    import torch

    from meshadv.attacks import evaluate

    bound = criterion.bind(detector)  # type: ignore[attr-defined]
    benign = evaluate(setup.mesh, setup.views(), detector, bound,  # type: ignore[attr-defined]
                      setup=setup.render_setup(1))  # type: ignore[attr-defined]
    if float(benign.scores[0].max()) >= threshold:
        return
    with torch.no_grad():
        seen = detector.detect(benign.images[0][:1], score_threshold=0.05)[0].to_records()  # type: ignore
    seen = sorted(seen, key=lambda r: -r["score"])[:5]
    listed = ", ".join(f"{r['label']} {r['score']:.2f}" for r in seen) or "nothing above 0.05"
    raise typer.BadParameter(f"nothing to hide: the detector finds no {hide!r} above {threshold} in the benign "
                             f"image (it sees: {listed}); choose --hide among those or lower --threshold",
                             param_hint="--hide")


def register(app: typer.Typer) -> None:
    """Add the ``attack-scene`` command to ``app``."""
    app.command("attack-scene")(attack_scene)
