"""``meshadv attack-scene``: hide a detection by perturbing one object of a scene (indoor desk or a real photo)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import typer

from meshadv.commands._cap_option import CAP_HELP, parse_cap
from meshadv.commands._common import DEFAULT_HELD_OUT_FRACTION

#: Default Adam learning rates (``--method adam``): for shape in units of the object's bounding-box diagonal per step
#: (small: NMR gradients are heavy-tailed and Adam moves every parameter that receives any gradient by about lr per
#: step), for texture in logit units per step.
DEFAULT_LR = {"shape": 5e-4, "texture": 0.05}
#: Default rounds of neighbour averaging of the shape flow with ``--method adam`` (the dense bunny roughens without).
DEFAULT_SMOOTHING = 8
#: Default perceptual weight with ``--method adam`` (texture: per pixel).
DEFAULT_LAMBDA = 1.0

#: Held-out views by default: meshadv.scenes.held_out.DEFAULT_HELD_OUT_VIEWS, written out so that the command line
#: loads without torch (tests/test_scenes.py checks that the two agree).
DEFAULT_EVAL_VIEWS = 6

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
    perturbation: str = typer.Option("shape", "--perturbation", help="shape or texture"),
    obj: str = typer.Option(
        "bunny", "--object", help="object to perturb (scene object name, or a mesh file for photos)"
    ),
    place: str = typer.Option("0.5,0.75,0.3", help="photo only: u,v,height_fraction of the inserted object"),
    method: Optional[str] = typer.Option(
        None, help="update rule: ddn (least distortion: a per-target budget that shrinks while the class stays hidden, "
                   "no lambda, runs every step; shape: its lengths scaled to the object's bounding-box diagonal; the "
                   "default) or adam (Adam + lambda, stops once the class stayed hidden 0.05 below --threshold for 5 "
                   "steps; --lr, --lambda, --smoothing)"),
    steps: int = typer.Option(300, help="maximum steps"),
    lr: Optional[float] = typer.Option(None, help="--method adam: Adam learning rate (default: 5e-4 for shape, in "
                                                   "units of the object's bounding-box diagonal; 0.05 for texture, "
                                                   "logit units)"),
    smoothing: Optional[int] = typer.Option(
        None, min=0, help=f"--method adam, shape only: neighbour-averaging iterations of the flow parameters (default: "
                          f"{DEFAULT_SMOOTHING})"),
    lambda_perceptual: Optional[float] = typer.Option(
        None, "--lambda", help=f"--method adam: perceptual loss weight (default: {DEFAULT_LAMBDA:g}; texture: per "
                               f"pixel)"),
    threshold: float = typer.Option(0.5, help="detection score threshold"),
    cap: str = typer.Option("default", help="perceptibility cap of the object: 'default' (" + CAP_HELP + "), "
                                            "'none', or NAME=VALUE,... (as `meshadv attack --cap`); a result outside "
                                            "it is a failure"),
    eval_views: int = typer.Option(
        DEFAULT_EVAL_VIEWS, min=0, help="held-out views that judge the result (never optimised on, never used to "
                                            "pick it), drawn with --seed: a rendered scene's camera turned 2-5 degrees "
                                            "about its look-at point, pitched up to 3 and moved up to 5% along its "
                                            "line of sight; a photo's object shifted up to 4% of the image and "
                                            "resized up to 10%; 0: none (needs --held-out-fraction 0)"),
    held_out_fraction: float = typer.Option(
        DEFAULT_HELD_OUT_FRACTION, min=0.0, max=1.0,
        help="SUCCESS needs the class hidden on at least this fraction of the held-out views as well as from the "
             "scene camera (0: the scene camera's verdict alone)"),
    width: Optional[int] = typer.Option(None, help="render width (default: the scene's / photo's own)"),
    seed: int = typer.Option(0, help="random seed"),
    output: Path = typer.Option(Path("out/attack-scene"), "-o", "--output", help="output folder"),
) -> None:
    """Hide CLASS (or everything) from a detector by perturbing only one object; writes before/after images with
    detections drawn, the adversarial object mesh and a JSON record. SUCCESS means: the class is hidden from the
    scene camera and on at least --held-out-fraction of the held-out views (small camera moves, or for a photo small
    changes of the object's placement), which the attack never optimised on, with the object inside the
    perceptibility cap (--cap)."""
    from meshadv.attacks import Disappearance
    from meshadv.attacks.families import check_perturbation
    from meshadv.attacks.result import enough_views
    from meshadv.attacks.update import RECOMMENDED_METHOD
    from meshadv.commands._common import resolve_method
    from meshadv.mesh import save_mesh
    from meshadv.scenes.attack import attack_scene
    from meshadv.scenes.held_out import scene_held_out_views
    from meshadv.scenes.draw import draw_detections
    from meshadv.util.atomic import write_json_atomic
    from meshadv.util.png import save_png
    from meshadv.scenes.setups import build_setup
    from meshadv.victims import load_victim

    try:
        check_perturbation(perturbation, "--perturbation")
        if smoothing is not None and perturbation != "shape":
            raise ValueError("--smoothing applies to --perturbation shape only")
        method = resolve_method(method, RECOMMENDED_METHOD, {
            "--lr": lr is not None, "--lambda": lambda_perceptual is not None, "--smoothing": bool(smoothing)})
        if eval_views == 0 and held_out_fraction > 0:
            raise ValueError("--eval-views 0 leaves no held-out views to judge the result on: give "
                             "--held-out-fraction 0 too (the scene camera's verdict alone)")
        setup = build_setup(scene, obj, place, width)
        cap = parse_cap(cap)
    except (ValueError, FileNotFoundError) as exc:
        raise typer.BadParameter(str(exc)) from exc
    detector = load_victim(victim, weights=weights, cfg=cfg)
    criterion = Disappearance(hide, threshold=threshold)
    _require_something_to_hide(setup, detector, criterion, hide, threshold)
    attack = _scene_attack(setup, perturbation, method, steps, seed, lr, smoothing, lambda_perceptual, cap,
                           held_out_fraction)
    held_out = scene_held_out_views(setup, eval_views, seed) if eval_views > 0 else None

    def progress(info: object) -> None:
        step = info.total_step  # type: ignore[attr-defined]
        if step == 1 or step % 10 == 0:
            typer.echo(f"step {step:4d}  loss {info.loss[0]:.4f}  margin {info.margin[0]:.3f}")  # type: ignore

    result = attack_scene(attack, setup, detector, criterion, callback=progress, held_out=held_out)
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
    held_line = result.held_out_line()
    if held_out is not None and held_line is not None:
        moves = "camera moves" if held_out.kind == "camera" else "object placements"
        scores = ", ".join(f"{b:.2f} -> {a:.2f}" for b, a in zip(result.held_out_scores_before or [],
                                                               result.held_out_scores or []))
        typer.echo(f"{held_line} ({moves}; the hidden class's score on each, pristine -> adversarial: {scores})")
    verdict = "success" if result.success else "failure"
    rate, fraction = result.held_out_rate, result.held_out_fraction
    if result.views_success and fraction is not None and (rate is None or not enough_views(rate, fraction)):
        verdict += " (hidden from the scene camera, not on enough held-out views)"
    typer.echo(
        f"{verdict}: hidden score {result.score_before:.3f} -> "
        f"{result.score_after:.3f} in {result.steps} steps; wrote {output}"
    )


def _scene_attack(setup: Any, perturbation: str, method: str, steps: int, seed: int, lr: Optional[float],
                  smoothing: Optional[int], lambda_perceptual: Optional[float], cap: Any = None,
                  held_out_fraction: float = 0.0) -> Any:
    """The attack of ``meshadv attack-scene``. ``method="adam"``: the paper's Adam with a perceptual weight, stopped
    once the hidden score stayed 0.05 below the threshold for 5 steps (``lr`` of a shape attack in units of the
    object's bounding-box diagonal, ``lambda_perceptual`` of a texture attack per pixel; defaults
    :data:`DEFAULT_LR`, :data:`DEFAULT_SMOOTHING`, :data:`DEFAULT_LAMBDA`). ``method="ddn"``: the distortion-budget
    rule with its default options, a shape attack's lengths scaled to the object
    (:func:`~meshadv.attacks.budget.shape_options_for`),
    run for every step (it keeps lowering the distortion after the first success and returns the least distorted
    success). ``cap``: the perceptibility cap (``None``: none). ``held_out_fraction``: the fraction of the held-out
    views the class must also be hidden on (0: the scene camera's verdict alone)."""
    from meshadv.attacks import make_attack
    from meshadv.attacks.budget import shape_options_for

    if method == "ddn":
        options = shape_options_for(setup.mesh) if perturbation == "shape" else {}
        return make_attack(perturbation, method=method, method_options=options, steps=steps, seed=seed,
                           perceptibility_cap=cap, held_out_fraction=held_out_fraction)
    common = dict(method=method, steps=steps, early_stop=5, early_stop_margin=0.05, seed=seed,
                  perceptibility_cap=cap, held_out_fraction=held_out_fraction)
    lr = DEFAULT_LR[perturbation] if lr is None else lr
    lambda_perceptual = DEFAULT_LAMBDA if lambda_perceptual is None else lambda_perceptual
    if perturbation == "shape":  # lr in units of the object's bounding-box diagonal
        return make_attack("shape", lr=lr * float(setup.mesh.bbox_diagonal()),
                           smoothing=DEFAULT_SMOOTHING if smoothing is None else smoothing,
                           lambda_perceptual=lambda_perceptual, **common)
    # the image smoothness loss sums over pixels: --lambda is per pixel
    pixels = setup.camera.width * setup.camera.height
    return make_attack("texture", lr=lr, lambda_perceptual=lambda_perceptual / pixels, **common)


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
