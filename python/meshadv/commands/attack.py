"""``meshadv attack``: a shape or texture attack of one mesh against one victim, saved atomically.

The benign mesh is checked on the attack views first (:mod:`meshadv.commands._benign_gate`): PASCAL3D+ chair 01 is
a desk to EfficientNet-Lite0 on two of the five default views, so the example below needs ``--benign-wrong-ok`` (or
views where it is a chair, ``--azimuths``); the default perceptibility cap applies (``--cap``).

Example:
    $ meshadv attack ../shared/data/pascal3d/chair/01.ply --victim efficientnet_lite0 --target bicycle \\
          --perturbation shape --views 5 --steps 300 --benign-wrong-ok -o out/chair-bicycle
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, List, Optional, Sequence

import typer

from meshadv.commands._cap_option import CAP_HELP, parse_cap
from meshadv.commands._surface_views import SHADING_HELP
from meshadv.commands._common import (
    DEFAULT_BACKGROUND,
    DEFAULT_DISTANCE,
    DEFAULT_ELEVATION,
    DEFAULT_HELD_OUT_FRACTION,
    load_mesh_input,
    make_views,
    parse_azimuth_range,
    parse_color,
    resolve_method,
)

__all__ = ["attack", "attack_input", "build_attack", "build_criteria", "run_with_progress"]


def attack_input(loaded: Any, perturbation: str, shading: Optional[str], resample: int) -> Any:
    """The ``MeshInput`` an attack of ``perturbation`` works on (:func:`meshadv.mesh.file_input.attack_input`, the
    loader sweep jobs share), its resampling notes printed.

    Raises:
        ValueError: ``texture-map`` of a mesh without a UV texture image, or ``texture`` (per-face colours, drawn
            flat) with ``shading="smooth"``.
        MeshLoadError: the file's texture or attributes are unusable (the message names the file and field).
        MeshProcessingError: MeshLab failed on the mesh.
    """
    from meshadv.mesh import file_input

    if perturbation == "texture" and shading == "smooth":
        raise ValueError("--shading smooth needs --perturbation shape or texture-map: the per-face colour "
                         "attack (texture) draws its faces flat")
    return file_input.attack_input(loaded, perturbation, shading, resample, say=typer.echo,
                                   hint=" (--resample 0 attacks the mesh as loaded)")


def build_attack(perturbation: str, **kwargs: Any) -> Any:
    """The attack object for ``perturbation`` (the family registry); ``None`` values fall back to defaults.

    Raises:
        ValueError: unknown ``perturbation``.
    """
    from meshadv.attacks import make_attack

    return make_attack(perturbation, **{k: v for k, v in kwargs.items() if v is not None})


def build_criteria(
    victim: Any,
    targets: Sequence[str],
    untargeted: Optional[str],
    disappear: Optional[str],
    threshold: float = 0.5,
) -> List[Any]:
    """Criteria from the command-line options: one per ``--target``, or an untargeted / disappearance one.

    Raises:
        ValueError: none or several kinds given, or a kind that does not suit the victim.
    """
    from meshadv.attacks import Disappearance, Misclassification, TargetedMisclassification

    kinds = sum([bool(targets), untargeted is not None, disappear is not None])
    if kinds != 1:
        raise ValueError("give exactly one of --target (repeatable), --untargeted or --disappear")
    if disappear is not None:
        return [Disappearance(disappear, threshold=threshold)]
    if untargeted is not None:
        return [Misclassification(untargeted)]
    return [TargetedMisclassification(t) for t in targets]


def run_with_progress(
    attack_obj: Any,
    mesh: Any,
    views: Any,
    victim: Any,
    criteria: Sequence[Any],
    *,
    eval_views: Any = None,
    setup: Any = None,
    quiet: bool = False,
    extra_callback: Optional[Callable[[Any], None]] = None,
) -> Any:
    """Run an attack with a rich progress bar (loss, current top-1 and distance); Ctrl-C ends it early.

    Returns:
        The ``AttackResult`` (``interrupted=True`` after Ctrl-C: the best result so far).
    """
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                               TimeRemainingColumn)
    from rich.console import Console
    from rich.table import Column

    names = list(getattr(victim, "class_names", ()) or ())
    total = attack_obj.steps * attack_obj.binary_search_steps
    # the attack's own distance: the Eq. 4 Laplacian sum for shape (the paper's tables use its pair mean), the
    # colour RMSE for texture, the texel RMSE for texture-map
    dist_name = {"shape": "lap-sum", "texture": "rmse", "texture-map": "texel-rmse"}.get(
        getattr(attack_obj, "perturbation", ""), "dist")

    def fmt(v: Optional[float]) -> str:
        return "-" if v is None else f"{v:.4g}"

    # Counter, elapsed time and ETA keep their width (about 54 columns with a 4-digit total); only the info text
    # is cut, with an ellipsis, to what is left of the terminal (80 columns included).
    info_width = max(8, Console().width - 56)
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(bar_width=16), MofNCompleteColumn(),
                  TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(),
                  TextColumn("{task.fields[info]}",
                             table_column=Column(no_wrap=True, overflow="ellipsis", max_width=info_width)),
                  disable=quiet) as progress:
        task = progress.add_task("attack", total=total, info="")

        def callback(info: Any) -> None:
            top = info.top1[0] if info.top1 else None
            top_name = "-" if top is None else (names[top] if top < len(names) else str(top))
            progress.update(
                task, completed=info.round * info.steps + info.step + 1,
                description=f"r{info.round + 1}/{info.rounds}",
                info=(f"top-1 {top_name[:24]}  margin {fmt(info.margin[0])}  loss {fmt(info.loss[0])}  "
                      f"{dist_name} {fmt(info.distance[0])}  best {fmt(info.best_distance[0])}"),
            )
            if extra_callback is not None:
                extra_callback(info)

        return attack_obj(mesh, views, victim, list(criteria), setup=setup, eval_views=eval_views,
                          callback=callback)


def attack(
    mesh: str = typer.Argument(..., help="mesh file (PLY/OBJ/OFF), builtin:NAME, or 'default'"),
    victim: str = typer.Option("efficientnet_lite0", help="victim name (the list is above)"),
    weights: Optional[Path] = typer.Option(None, help="weights file: a state_dict for densenet121 / inception_v3, "
                                                      "Darknet .weights for yolov3"),
    cfg: Optional[Path] = typer.Option(None, help="Darknet .cfg file (yolov3 only)"),
    target: List[str] = typer.Option([], help="target class: ImageNet name/index or PASCAL3D+ class (repeatable: "
                                              "several targets are attacked together as a batch)"),
    untargeted: Optional[str] = typer.Option(None, help="untargeted attack away from this true class"),
    source: Optional[str] = typer.Option(
        None, help="the class the benign mesh is, checked on every attack view before the attack (default: "
                   "--untargeted's class, else the PASCAL3D+ class of a mesh under a pascal3d/CLASS/ folder, else "
                   "not checked)"),
    benign_wrong_ok: bool = typer.Option(
        False, "--benign-wrong-ok", help="attack even when the benign render is not the source class on some views "
                                         "(default: refuse)"),
    disappear: Optional[str] = typer.Option(None, help="detector: class to hide, or 'all'"),
    perturbation: str = typer.Option("shape", "--perturbation",
                                      help="shape, texture (face colours) or texture-map (the texels of the "
                                           "file's UV texture image; an OBJ with map_Kd or a GLB)"),
    views: int = typer.Option(5, help="number of victim views"),
    azimuths: str = typer.Option("150:210", help="azimuth range LOW:HIGH or LOW-HIGH (degrees) of the victim views; "
                                                 "180 faces the front of a PASCAL3D+ model"),
    eval_views: Optional[int] = typer.Option(
        None, min=0, help="held-out views that judge the result (never optimised on, never used to pick it): "
                          "default: the views between and around the victim views (8 for the default 5: the 4 "
                          "azimuths between them, 30 degrees beyond either end, 20 degrees above and below); N: N "
                          "views between the victim views; 0: none (needs --held-out-fraction 0)"),
    held_out_fraction: float = typer.Option(
        DEFAULT_HELD_OUT_FRACTION, min=0.0, max=1.0,
        help="SUCCESS needs the target to hold on at least this fraction of the held-out views as well as on the "
             "victim views (0: the victim views' verdict alone)"),
    elevation: float = typer.Option(DEFAULT_ELEVATION, help="camera elevation (degrees)"),
    distance: float = typer.Option(DEFAULT_DISTANCE, help="camera distance (mesh normalised to [-1, 1])"),
    method: Optional[str] = typer.Option(
        None, help="update rule: ddn (least distortion: a per-target budget that shrinks while the target holds, no "
                   "lambda; the default) or adam (the paper's Adam + lambda search; with "
                   "--binary-search 5 --steps 1000 --early-stop 0 the paper's protocol exactly)"),
    steps: int = typer.Option(300, help="maximum steps (per binary-search round with --method adam)"),
    lr: Optional[float] = typer.Option(None, help="--method adam: Adam learning rate (default: the attack's)"),
    lambda_: Optional[float] = typer.Option(None, "--lambda", help="--method adam: initial perceptual weight lambda"),
    smoothing: Optional[int] = typer.Option(
        None, help="shape only: rounds of neighbour averaging of the optimised vertex flow (default: the attack's; "
                   "0 = the paper's exact per-vertex flow)"),
    binary_search: int = typer.Option(1, help="--method adam: binary-search rounds over lambda (paper: 5)"),
    visibility_gradient: Optional[str] = typer.Option(
        None, help="--method ddn, shape only: the rasterization gradient of the vertices, nmr (the Neural Mesh "
                   "Renderer's, docs/NMR_GRADIENT.md) or local (its sweeps cut to 2 pixels of each edge, "
                   "docs/LOCAL_GRADIENT.md; cheaper); default: the rule's"),
    loss: str = typer.Option("ce", help="classifier loss: ce or cw"),
    kappa: float = typer.Option(0.0, help="C&W confidence"),
    early_stop: Optional[int] = typer.Option(
        None, help="stop once the target held for this many steps (0: never; default: 10 with adam, never with ddn, "
                   "which keeps lowering the distortion after the first success)"),
    early_stop_margin: Optional[float] = typer.Option(
        None, help="margin the target must hold with for early stopping (default: 0.5 logits for classifiers, "
                   "0.05 below the threshold for detectors)"),
    budget: Optional[float] = typer.Option(None, help="distortion ceiling (shape: the Eq. 4 Laplacian sum of the "
                                                "flow, i.e. pair mean x 2E; texture: colour RMSE; "
                                                "texture-map: texel RMSE)"),
    cap: str = typer.Option(
        "default", help="perceptibility cap: 'default' (" + CAP_HELP + "), 'none' (the paper's protocol), or "
                        "NAME=VALUE,... of max_displacement (largest vertex move / bounding-box diagonal), "
                        "normal_change_p95_deg (area-weighted 95th-percentile turn of the face normals, degrees), "
                        "edge_strain_p95 (length-weighted 95th-percentile relative change of the edge lengths), "
                        "edge_strain_max (largest change of one edge's length over that length, at least 0.25% of the "
                        "diagonal), "
                        "color_change_p95 (area-weighted 95th-percentile RGB change of the face colours); a step "
                        "outside it never counts as a success, and a target that cannot succeed inside it fails with "
                        "its closest result inside it"),
    jitter: bool = typer.Option(False, help="random camera/light jitter at every step (robustness)"),
    eot: int = typer.Option(0, min=0, max=4096, help="robust attack: draw this many fresh views from the whole "
                                                     "azimuth range (+-10 degrees), elevation (+-5) and distance "
                                                     "(+-10%) at every step, with sub-pixel shifts, light, "
                                                     "antialias, size, blur and noise, and a low-frequency "
                                                     "perturbation; success is judged on 12 fresh views "
                                                     "and the held-out views (0, the default: off, the fixed "
                                                     "views)"),
    image_size: int = typer.Option(224, min=1, max=16384, help="rendered image size in pixels"),
    background: str = typer.Option(DEFAULT_BACKGROUND, help="background colour r,g,b in [0, 1]"),
    threshold: float = typer.Option(0.5, help="detector score threshold (--disappear)"),
    z_up: Optional[bool] = typer.Option(None, "--z-up/--y-up", help="mesh file is Z-up (default: guess)"),
    shading: Optional[str] = typer.Option(
        None, help=SHADING_HELP + "; the attack's renders, its saved meshes and their Mitsuba transfer use it (smooth: "
                   "the area-weighted normals of the attacked vertices; not with --perturbation texture)"),
    resample: int = typer.Option(
        4000, min=0, help="attack a mesh file resampled uniformly with MeshLab to about this many faces, as the paper "
                          "does (0: the mesh as loaded; built-in shapes are never resampled; a texture is carried "
                          "onto a new atlas, vertex colours onto the new vertices; --perturbation texture-map attacks "
                          "the file as loaded); the adversarial mesh is saved in the input file's frame all the same"),
    seed: int = typer.Option(0, help="random seed"),
    quiet: bool = typer.Option(False, help="no progress bar"),
    output: Path = typer.Option(..., "-o", "--output", help="output folder"),
) -> None:
    """Attack MESH so that VICTIM sees the target class (shape or texture perturbation); Ctrl-C saves the best
    result so far. SUCCESS means: the target holds on the victim views and on at least --held-out-fraction of the
    held-out views, which the attack never optimised on, with the mesh inside the perceptibility cap (--cap).
    Writes the adversarial mesh (PLY, OBJ; a textured one also as OBJ + MTL + texture PNG and GLB, vertex colours
    as OBJ `v x y z r g b`; and in the input file's frame), before/after PNGs, a labelled
    comparison.png and result.json into OUTPUT.

    Victims: efficientnet_lite0, efficientnet_lite2, ssd_mobilenet_v2_coco (weights included); densenet121,
    inception_v3 (--weights STATE_DICT.pth), yolov3 (--weights FILE.weights --cfg FILE.cfg)."""
    import torch

    from meshadv.attacks.robust_settings import robust_options
    from meshadv.attacks.update import RECOMMENDED_METHOD
    from meshadv.commands._benign_gate import benign_gate, source_class
    from meshadv.commands._comparison import status_words, write_attack_outputs
    from meshadv.commands._surface_views import parse_shading
    from meshadv.mesh.errors import MeshProcessingError
    from meshadv.perceptibility import held_out_views
    from meshadv.render import RenderSetup
    from meshadv.render.visibility import check_visibility_gradient
    from meshadv.victims import load_victim

    torch.manual_seed(seed)
    try:
        if smoothing is not None and perturbation != "shape":
            raise ValueError("--smoothing applies to --perturbation shape only")
        method = resolve_method(method, RECOMMENDED_METHOD, {
            "--lr": lr is not None, "--lambda": lambda_ is not None, "--binary-search": binary_search != 1,
            "--smoothing": bool(smoothing)})
        if early_stop is None:
            early_stop = 0 if method == "ddn" else 10
        if visibility_gradient is not None and (method != "ddn" or perturbation != "shape"):
            raise ValueError("--visibility-gradient applies to --method ddn --perturbation shape only")
        method_options = None if visibility_gradient is None else {
            "visibility_gradient": check_visibility_gradient(visibility_gradient, "--visibility-gradient")}
        loaded = attack_input(load_mesh_input(mesh, z_up=z_up), perturbation, parse_shading(shading), resample)
        mesh_obj, label = loaded.mesh, loaded.label
        az = parse_azimuth_range(azimuths)
        view_set = make_views(views, az, elevation, distance)
        if eval_views == 0 and held_out_fraction > 0:
            raise ValueError("--eval-views 0 leaves no held-out views to judge the result on: give "
                             "--held-out-fraction 0 too (the victim views' verdict alone)")
        if eval_views is None:
            held_out = held_out_views(view_set)
        else:
            held_out = make_views(eval_views + 1, az, elevation, distance, offset=0.5) if eval_views > 0 else None
        jitter_cfg = dict(azimuth=5.0, elevation=3.0, distance=0.05, light_direction=0.2,
                          light_intensity=0.2) if jitter else None
        victim_obj = load_victim(victim, weights=weights, cfg=cfg)
        if early_stop_margin is None:
            early_stop_margin = 0.05 if victim_obj.kind == "detector" else 0.5
        shape_only = {"smoothing": smoothing} if perturbation == "shape" and smoothing is not None else {}
        robust = robust_options(perturbation, method, eot) if eot > 0 else {}
        robust_lr = robust.pop("lr", None)
        if lr is None and smoothing is None:
            lr = robust_lr
        method_options = {**robust.pop("method_options", {}), **(method_options or {})} or None
        setup = RenderSetup(image_size=image_size, background=parse_color(background))
        attack_obj = build_attack(
            perturbation, steps=steps, lr=lr, lambda_perceptual=lambda_, binary_search_steps=binary_search, loss=loss,
            kappa=kappa, early_stop=early_stop if early_stop > 0 else None, early_stop_margin=early_stop_margin,
            max_distortion=budget, jitter=jitter_cfg, seed=seed, method=method, method_options=method_options,
            perceptibility_cap=parse_cap(cap), held_out_fraction=held_out_fraction, **{**robust, **shape_only},
        )
        criteria = build_criteria(victim_obj, target, untargeted, disappear, threshold)
        for crit in criteria:
            crit.bind(victim_obj)  # validate class names now, before the attack starts
    except (ValueError, FileNotFoundError, ImportError, MeshProcessingError) as exc:
        raise typer.BadParameter(str(exc)) from exc
    typer.echo(f"mesh {label}: {mesh_obj.num_vertices} vertices, {mesh_obj.num_faces} faces; "
               f"{attack_obj!r}")
    source = source_class(source, untargeted, loaded.path)
    criteria = benign_gate(mesh_obj, view_set, victim_obj, criteria, setup=setup, source=source,
                           success_fraction=attack_obj.success_fraction, go_on=benign_wrong_ok)
    result = run_with_progress(attack_obj, mesh_obj, view_set, victim_obj, criteria, eval_views=held_out,
                               setup=setup, quiet=quiet)
    path = result.save(output)
    comparison = write_attack_outputs(result, victim_obj, output, loaded,
                                      f"{label}: {perturbation} attack ({result.criteria[0].get('label', '')}) "
                                      f"{status_words(result)} ({result.steps} steps)", source_class=source)
    typer.echo(result.summary())
    if held_out is not None:
        verdict = (f"SUCCESS needs the target on >= {100 * held_out_fraction:.0f}% of them"
                   if held_out_fraction > 0 else "the verdict is the victim views' alone (--held-out-fraction 0)")
        typer.echo(f"held-out views: {len(held_out)}, never optimised on and never used to pick the result; "
                   f"{verdict}")
    if eot > 0:
        typer.echo(f"robust attack: {eot} fresh views per step; success judged on {len(result.view_records)} fresh "
                   f"views of the range, none of them optimised on")
    if result.interrupted:
        typer.echo("interrupted: saved the best result so far")
    typer.echo(f"wrote {path} and {comparison}")
