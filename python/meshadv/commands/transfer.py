"""``meshadv transfer ...``: transfer adversarial meshes to Mitsuba 3 (a photorealistic, non-differentiable renderer).

Commands:
    variant               which Mitsuba variant works here (llvm_ad_rgb needs a recent LLVM; scalar_rgb always works)
    check                 compare Mitsuba's and meshadv's renders of one mesh (mask IoU, interior colour difference)
    render                render a mesh with Mitsuba (optionally inside the indoor / living-room scene)
    controlled            re-render a sweep's adversarial meshes under the same camera and lights (Table 3, Fig. 5)
    blackbox-classifier   the black-box pipeline against a classifier (aeroplane outdoors)
    blackbox-detector     the black-box pipeline against a detector (bunny in the indoor scene)
    report                the transfer tables of a results database (Markdown)

Results go into the table ``transfer`` of the sweep's results database (see :mod:`meshadv.transfer.results`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Optional

import typer

from meshadv.commands._common import DEFAULT_DISTANCE, DEFAULT_ELEVATION
from meshadv.commands._surface_views import SHADING_HELP

if TYPE_CHECKING:
    from meshadv.transfer.robust import Robustness

__all__ = ["register", "transfer_app"]

transfer_app = typer.Typer(
    name="transfer",
    help="Transfer adversarial meshes to Mitsuba 3 (controlled and black-box evaluations).",
    no_args_is_help=True,
)


def _surface_mesh_arg(spec: str, shading: Optional[str]) -> Any:
    """The normalised mesh of MESH drawn as ``meshadv render`` draws it: a file's texture or vertex colours under
    ``--shading`` (:func:`~meshadv.mesh.file_input.surface_input`), else per face."""
    from meshadv.commands._common import load_mesh_input
    from meshadv.commands._surface_views import parse_shading
    from meshadv.mesh.file_input import surface_input

    try:
        return surface_input(load_mesh_input(spec), parse_shading(shading)).mesh
    except (ValueError, FileNotFoundError) as exc:
        raise typer.BadParameter(str(exc)) from exc


def _echo_json(data: dict) -> None:
    typer.echo(json.dumps(data, indent=2, default=str))


@transfer_app.command("variant")
def variant_cmd() -> None:
    """Probe Mitsuba's CPU variants (each in a child process) and print the one that will be used."""
    from meshadv.transfer.mitsuba_process import PREFERRED_VARIANTS, best_variant, probe_variant

    for name in PREFERRED_VARIANTS:
        typer.echo(f"{name}: {'works' if probe_variant(name) else 'FAILS'}")
    typer.echo(f"using: {best_variant()}")


@transfer_app.command("check")
def check_cmd(
    mesh: str = typer.Argument("builtin:sphere", help="Mesh file, builtin:NAME or default."),
    size: int = typer.Option(96, help="Image side in pixels."),
    spp: int = typer.Option(256, help="Mitsuba samples per pixel."),
    distance: float = typer.Option(3.0, help="Camera distance."),
    azimuth: float = typer.Option(30.0, help="Camera azimuth (degrees)."),
    elevation: float = typer.Option(20.0, help="Camera elevation (degrees)."),
    shading: Optional[str] = typer.Option(None, help=SHADING_HELP),
    out: Optional[Path] = typer.Option(None, "-o", "--out", help="Folder for the two images and the numbers."),
) -> None:
    """Render MESH with meshadv and with Mitsuba (direct light only) and print how well they agree; a textured or
    vertex-coloured file is compared with its texture or colours under --shading."""
    from meshadv.transfer.mitsuba_check import conversion_check, head_light_record

    if size < 8:
        raise typer.BadParameter("size must be >= 8", param_hint="--size")
    mesh_obj = _surface_mesh_arg(mesh, shading)
    record = head_light_record(distance, azimuth, elevation, 0.5, 0.4)
    result = conversion_check(mesh_obj, record, image_size=size, spp=spp)
    _echo_json(result.summary())
    if out is not None:
        from meshadv.util.atomic import write_json_atomic
        from meshadv.util.png import save_png

        out.mkdir(parents=True, exist_ok=True)
        for name, img in (("meshadv.png", result.meshadv_image), ("mitsuba.png", result.mitsuba_image)):
            save_png(img, out / name)
        write_json_atomic(result.summary(), out / "check.json")


@transfer_app.command("render")
def render_cmd(
    mesh: str = typer.Argument(..., help="Mesh file, builtin:NAME or default."),
    out: Path = typer.Option(..., "-o", "--out", help="Output PNG."),
    size: int = typer.Option(224, help="Image side in pixels (as `meshadv attack`)."),
    spp: int = typer.Option(64, help="Samples per pixel."),
    max_depth: int = typer.Option(8, help="Path depth (2 = direct light only)."),
    distance: float = typer.Option(DEFAULT_DISTANCE, help="Camera distance (as `meshadv attack`)."),
    azimuth: float = typer.Option(180.0, help="Camera azimuth (degrees; 180 = the centre of `meshadv attack`'s "
                                              "views)."),
    elevation: float = typer.Option(DEFAULT_ELEVATION, help="Camera elevation (degrees, as `meshadv attack`)."),
    viewing_angle: float = typer.Option(30.0, help="Field of view (degrees)."),
    scene: str = typer.Option("none", help="none, indoor, living-room, or a Mitsuba scene XML to place the mesh in."),
    variant: Optional[str] = typer.Option(None, help="Mitsuba variant (default: the best that works)."),
    shading: Optional[str] = typer.Option(None, help=SHADING_HELP),
) -> None:
    """Render MESH with Mitsuba under meshadv's camera conventions and a head light (a textured or vertex-coloured
    file with its texture or colours under --shading)."""
    import numpy as np

    from meshadv.transfer import MitsubaCamera, MitsubaLights, render_scene, scene_spec
    from meshadv.transfer.setups import base_scene_file
    from meshadv.util.png import save_png

    if size < 8:
        raise typer.BadParameter("size must be >= 8", param_hint="--size")
    try:
        base = base_scene_file(scene)
    except ValueError as err:
        raise typer.BadParameter(str(err), param_hint="--scene") from None
    mesh_obj = _surface_mesh_arg(mesh, shading)
    camera = MitsubaCamera.spherical(distance, azimuth, elevation, viewing_angle=viewing_angle)
    lights = MitsubaLights(np.array([camera.eye]), np.full((1, 3), 0.5), np.full(3, 0.5 if base is None else 0.0))
    spec = scene_spec(mesh_obj, camera, lights, image_size=size, spp=spp, max_depth=max_depth, base_scene=base,
                      background=(1.0, 1.0, 1.0) if base is None else None)
    image = render_scene(spec, variant=variant)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_png(image.image, out)
    typer.echo(f"wrote {out} ({image.variant})")


@transfer_app.command("attack")
def attack_cmd(
    folder: Path = typer.Argument(..., help="Output folder of `meshadv attack` or `meshadv demo` (result.json)."),
    spp: int = typer.Option(64, help="Mitsuba samples per pixel."),
    max_depth: int = typer.Option(8, help="Path depth (>= 3 adds interreflection)."),
    variant: Optional[str] = typer.Option(None, help="Mitsuba variant (default: the best that works)."),
) -> None:
    """Re-render one `meshadv attack` result with Mitsuba under the attack's own views and test its victim; the benign
    mesh is rendered too, and untargeted transfer counts only on views where the victim gets it right; writes
    FOLDER/transfer.json, FOLDER/mitsuba_v<view>.png and FOLDER/mitsuba_benign_v<view>.png."""
    from meshadv.transfer.controlled import transfer_attack_folder, transfer_attack_summary

    rows = transfer_attack_folder(folder, spp=spp, max_depth=max_depth, variant=variant)
    for row in rows:
        typer.echo(f"view {row.view}: meshadv {'adversarial' if row.success_meshadv else 'benign'} "
                   f"({row.top1_meshadv}), Mitsuba {'adversarial' if row.success_mitsuba else 'benign'} "
                   f"({row.top1_mitsuba}); benign mesh in Mitsuba: {row.top1_benign_mitsuba} "
                   f"({'right' if row.benign_correct_mitsuba else 'WRONG: untargeted transfer not counted'})")
    typer.echo(transfer_attack_summary(rows) + f"; wrote {folder / 'transfer.json'}")


@transfer_app.command("controlled")
def controlled_cmd(
    results: Path = typer.Argument(..., help="Results database of a finished `meshadv sweep`."),
    limit: Optional[int] = typer.Option(None, min=1, help="At most this many adversarial meshes in this run."),
    spp: int = typer.Option(64, help="Mitsuba samples per pixel."),
    max_depth: int = typer.Option(8, help="Path depth (>= 3 adds interreflection)."),
    experiment: str = typer.Option("controlled", help="Name of this transfer run in the database."),
    images: Optional[Path] = typer.Option(None, help="Folder for the Mitsuba renders, named "
                                          "<class>_c<configuration>_to_<target>_<perturbation>_<victim>_<id>_v<view>"
                                          ".png and listed with their job ids in index.csv."),
    all_attacks: bool = typer.Option(False, "--all", help="Also transfer attacks that failed in meshadv."),
    variant: Optional[str] = typer.Option(None, help="Mitsuba variant (default: the best that works)."),
) -> None:
    """Re-render RESULTS' adversarial meshes with Mitsuba under the same views and test the victims (resumable); each
    benign mesh is rendered too, and untargeted transfer counts only where the victim gets it right."""
    from meshadv.commands._common_options import interrupted_exit
    from meshadv.transfer.controlled import pending_cases, transfer_case_into
    from meshadv.transfer.results import load_transfer_rows, transfer_report

    if not results.is_file():
        raise typer.BadParameter(f"{results} does not exist", param_hint="RESULTS")
    done, todo = pending_cases(results, experiment=experiment, only_successful=not all_attacks, limit=limit)
    if not todo and not done:
        hint = "" if all_attacks else " (none succeeded in meshadv; add --all to transfer the failed attacks too)"
        typer.echo(f"no finished single-view attacks with an adversarial mesh in this database{hint}")
        raise typer.Exit(code=1)
    typer.echo(f"{len(done)} adversarial meshes already transferred, transferring {len(todo)}")
    uncontrolled = sum(getattr(case, "benign_mesh", None) is None for case in todo)
    if uncontrolled:
        typer.echo(f"warning: {uncontrolled} of them have no benign mesh here (their spec's mesh cannot be loaded): "
                   "their untargeted transfer is not counted", err=True)
    finished = 0
    try:
        for case in todo:  # one case at a time, saved at once: an interrupted run resumes where it stopped
            transfer_case_into(results, case, experiment=experiment, spp=spp, max_depth=max_depth, variant=variant,
                               image_dir=images)
            finished += 1
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: every finished mesh is already in the database
        raise interrupted_exit(f"interrupted: {len(done) + finished} transferred adversarial meshes are kept in "
                               f"{results}; run the same command again to transfer the other "
                               f"{len(todo) - finished}") from None
    typer.echo(transfer_report(load_transfer_rows(results, experiment=experiment, kind="controlled")))


def _method(method: Optional[str], lr: Optional[float], lambda_perceptual: Optional[float],
            texture_smoothing: Optional[int]) -> str:
    """The update rule of a black-box command: ``method``, by default ``"adam"``.

    Raises:
        typer.BadParameter: an unknown rule, or Adam's own options (--lr, --lambda-perceptual) or
            --texture-smoothing (a parametrisation ddn cannot step) with ddn.
    """
    from meshadv.commands._common import resolve_method

    adam_only = {"--lr": lr is not None, "--lambda-perceptual": lambda_perceptual is not None,
                 "--texture-smoothing": texture_smoothing is not None}
    try:
        return resolve_method(method, "adam", adam_only)
    except ValueError as err:
        raise typer.BadParameter(str(err), param_hint="--method") from err


def _attack_kwargs(steps: int, lr: Optional[float], lambda_perceptual: Optional[float], antialias: int = 1,
                   loss: str = "ce", kappa: float = 0.0, early_stop: Optional[int] = None, seed: int = 0,
                   method: str = "adam") -> dict:
    """The attack's keyword arguments from a black-box command's options (``lr`` / ``lambda_perceptual`` only when
    given: the attack's defaults otherwise).

    Raises:
        typer.BadParameter: an option out of range.
    """
    if steps < 1:
        raise typer.BadParameter("steps must be >= 1", param_hint="--steps")
    if antialias < 1:
        raise typer.BadParameter("antialias must be >= 1", param_hint="--antialias")
    if loss not in ("ce", "cw"):
        raise typer.BadParameter("loss must be ce or cw", param_hint="--loss")
    if kappa < 0:
        raise typer.BadParameter("kappa must be >= 0", param_hint="--kappa")
    if early_stop is not None and early_stop < 1:
        raise typer.BadParameter("early-stop must be >= 1", param_hint="--early-stop")
    kwargs: dict = {"steps": steps, "antialias": antialias, "loss": loss, "kappa": kappa, "early_stop": early_stop,
                    "seed": seed, "method": method}
    if lr is not None:
        if not lr > 0:
            raise typer.BadParameter("lr must be > 0", param_hint="--lr")
        kwargs["lr"] = lr
    if lambda_perceptual is not None:
        if lambda_perceptual < 0:
            raise typer.BadParameter("lambda-perceptual must be >= 0", param_hint="--lambda-perceptual")
        kwargs["lambda_perceptual"] = lambda_perceptual
    return kwargs


def _jitter(scale: float, light_scale: Optional[float] = None) -> dict:
    """:func:`~meshadv.transfer.robust.scaled_jitter` of ``--jitter`` and ``--light-jitter``."""
    from meshadv.transfer.robust import scaled_jitter

    if scale < 0:
        raise typer.BadParameter("jitter must be >= 0", param_hint="--jitter")
    if light_scale is not None and light_scale < 0:
        raise typer.BadParameter("light-jitter must be >= 0", param_hint="--light-jitter")
    return scaled_jitter(scale, light_scale)


def _robustness(eot: int, margin: float, pixel_noise: float, verify: int, seed: int) -> "Robustness":
    from meshadv.transfer.robust import Robustness

    for value, hint, low in ((eot, "--eot", 1), (margin, "--margin", 0), (pixel_noise, "--pixel-noise", 0),
                             (verify, "--verify", 0)):
        if value < low:
            raise typer.BadParameter(f"must be >= {low}, got {value}", param_hint=hint)
    return Robustness(eot=eot, margin=margin, pixel_noise=pixel_noise, verify_samples=verify, seed=seed)


def _check_blackbox_render(perturbation: str, size: int, spp: int, texture_smoothing: Optional[int]) -> None:
    """The options both black-box commands check alike: --perturbation, --size, --spp and --texture-smoothing."""
    from meshadv.attacks.families import check_perturbation

    try:
        check_perturbation(perturbation, "--perturbation")
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--perturbation") from exc
    if size < 8:
        raise typer.BadParameter("size must be >= 8", param_hint="--size")
    if spp < 1:
        raise typer.BadParameter("spp must be >= 1", param_hint="--spp")
    if texture_smoothing is None:
        return
    if texture_smoothing < 0:
        raise typer.BadParameter("texture-smoothing must be >= 0", param_hint="--texture-smoothing")
    if perturbation != "texture":
        raise typer.BadParameter("texture-smoothing needs --perturbation texture", param_hint="--texture-smoothing")


def _skip_finished(resume: bool, db: Optional[Path], experiment: str, case_id: str) -> bool:
    """With ``--resume``: whether ``db`` already holds the black-box row ``case_id`` of ``experiment`` (then says so).

    Raises:
        typer.BadParameter: ``--resume`` without ``--db``.
    """
    if not resume:
        return False
    if db is None:
        raise typer.BadParameter("--resume needs --db (the database that holds the finished rows)",
                                 param_hint="--resume")
    from meshadv.transfer.blackbox import finished_blackbox

    if not finished_blackbox(db, experiment, case_id):
        return False
    typer.echo(f"{case_id}: already in {db} (experiment {experiment}); skipped (--resume)")
    return True


def _save_blackbox(result: Any, db: Optional[Path], out: Optional[Path], experiment: str) -> None:
    """Print the row, write ``out`` (every file atomically) and add the row to ``db``; an attack cut short by Ctrl-C
    or SIGTERM keeps its best mesh so far in ``out`` but stays out of ``db`` and exits with status 130."""
    from meshadv.commands._common_options import interrupted_exit
    from meshadv.transfer.blackbox import save_blackbox_outputs
    from meshadv.transfer.results import save_transfer_rows

    public = result.to_record()
    _echo_json(public)
    if out is not None:
        save_blackbox_outputs(result, out)
    if public.get("interrupted"):
        kept = f"the best mesh so far and its renders are in {out}; " if out is not None else ""
        raise interrupted_exit(f"interrupted after {public.get('steps_run')} of {public.get('steps')} attack steps: "
                               f"{kept}the row is not added to {db if db is not None else 'a database'}; run the "
                               "same command again for a full run")
    if db is not None:
        save_transfer_rows(db, [public], experiment=experiment, kind="blackbox")


def _progress(every: int) -> Optional[Callable[[Any], None]]:
    """A callback printing the attack's progress to stderr every ``every`` steps (None when ``every`` is 0)."""
    if every < 0:
        raise typer.BadParameter("progress must be >= 0", param_hint="--progress")
    if every == 0:
        return None

    def report(info: Any) -> None:
        if info.step % every == 0 or info.step == info.steps - 1:
            margin = info.margin[0]
            typer.echo(f"step {info.step}/{info.steps} loss {info.loss[0]} worst margin {margin} "
                       f"distance {info.distance[0]} best {info.best_distance[0]}", err=True)

    return report


_RESUME_HELP = ("Skip this run when --db already holds its row (same --experiment and case id): run a list of "
                "black-box commands again after a kill and only the unfinished ones run. The case id names most "
                "settings but not all (not --lr, for one): give --case-id when others differ.")
_LIGHT_JITTER_HELP = "Scale of the light part of the jitter (default: --jitter)."
_EOT_HELP = "Jittered samples of the estimated view per attack step (expectation over transformation)."
_MARGIN_HELP = ("Margin the criterion must hold with on every sample of a step to count as a success "
                "(classifier: logits; detector: score below the threshold).")
_NOISE_HELP = ("Std of Gaussian noise added to the rendered object's pixels of what the victim sees during the attack "
               "(the photo behind it has its own noise; 0 = none).")
_AA_HELP = "Supersampling of meshadv's renders in the attack (Mitsuba's pixels are area averages)."
_SMOOTH_HELP = ("Texture as a smoothed per-vertex colour field with this many rounds of neighbour averaging "
                "(for meshes with many faces per pixel); default: the paper's per-face colours.")
_METHOD_HELP = ("Update rule: adam (Adam + lambda; --lr, --lambda-perceptual, --texture-smoothing; the default) or ddn "
                "(least distortion: a per-target budget that shrinks while the criterion holds, no lambda; shape: its "
                "lengths scaled to the object's bounding-box diagonal as in `meshadv attack-scene`; it settles on the "
                "decision boundary of the attack's renders, so give a --margin for a result that transfers). A ddn "
                "run's default case id ends in _ddn.")
_VERIFY_HELP = ("Fresh views around the estimate (the default jitter, whatever --jitter) to re-test the adversarial "
                "mesh on in meshadv (0 = skip).")


@transfer_app.command("blackbox-classifier")
def blackbox_classifier_cmd(
    mesh: str = typer.Argument("aeroplane", help="aeroplane (PASCAL3D+ aeroplane/01), a mesh file or builtin:NAME."),
    true_class: str = typer.Option("aeroplane", help="The object's class."),
    target: Optional[str] = typer.Option(None, help="Target class (default: untargeted)."),
    victim: str = typer.Option("efficientnet_lite0", help="Classifier victim."),
    perturbation: str = typer.Option("texture", "--perturbation", help="shape or texture."),
    method: Optional[str] = typer.Option(None, help=_METHOD_HELP),
    steps: int = typer.Option(100, help="Attack steps."),
    lr: Optional[float] = typer.Option(None, help="--method adam: attack learning rate (default: the attack's)."),
    lambda_perceptual: Optional[float] = typer.Option(None, help="--method adam: perceptual loss weight (default: "
                                                                 "the attack's)."),
    jitter: float = typer.Option(1.0, help="Scale of the per-step jitter of the estimates (0 = none)."),
    light_jitter: Optional[float] = typer.Option(None, help=_LIGHT_JITTER_HELP),
    eot: int = typer.Option(1, help=_EOT_HELP),
    margin: float = typer.Option(0.0, help=_MARGIN_HELP),
    pixel_noise: float = typer.Option(0.0, help=_NOISE_HELP),
    antialias: int = typer.Option(1, help=_AA_HELP),
    texture_smoothing: Optional[int] = typer.Option(None, help=_SMOOTH_HELP + " --method adam only."),
    loss: str = typer.Option("ce", help="Classifier loss: ce or cw (C&W margin with --kappa)."),
    kappa: float = typer.Option(0.0, help="C&W confidence (--loss cw)."),
    early_stop: Optional[int] = typer.Option(None, help="Stop once the margin has held this many steps in a row."),
    verify: int = typer.Option(16, help=_VERIFY_HELP),
    seed: int = typer.Option(0, help="Seed of the jitter, the pixel noise and the verification views."),
    progress: int = typer.Option(25, help="Print the attack's progress to stderr every N steps (0 = quiet)."),
    size: int = typer.Option(224, help="Image side."),
    spp: int = typer.Option(64, help="Mitsuba samples per pixel (the photo and every Mitsuba render)."),
    case_id: Optional[str] = typer.Option(None, help="Row id (default: built from the setup and the settings)."),
    db: Optional[Path] = typer.Option(None, help="Results database to add the row to."),
    out: Optional[Path] = typer.Option(None, "-o", "--out", help="Folder for images, mesh and numbers."),
    experiment: str = typer.Option("blackbox", help="Name of this run in the database."),
    resume: bool = typer.Option(False, "--resume", help=_RESUME_HELP),
) -> None:
    """Black-box pipeline against a classifier: estimate camera + lights from a Mitsuba photo, attack, re-render."""
    from meshadv.commands._common import load_mesh_arg
    from meshadv.transfer.blackbox import blackbox_classifier, ddn_shape_options, settings_suffix
    from meshadv.transfer.setups import default_aeroplane, outdoor_classifier_setup
    from meshadv.victims import load_victim

    _check_blackbox_render(perturbation, size, spp, texture_smoothing)
    method = _method(method, lr, lambda_perceptual, texture_smoothing)
    kwargs = _attack_kwargs(steps, lr, lambda_perceptual, antialias, loss, kappa, early_stop, seed, method)
    robustness = _robustness(eot, margin, pixel_noise, verify, seed)
    callback = _progress(progress)
    jitter_dict = _jitter(jitter, light_jitter)
    if case_id is None:
        case_id = (f"outdoor_{Path(mesh).stem}_{perturbation}_{target or 'untargeted'}"
                   + settings_suffix(jitter, eot, margin, pixel_noise, antialias, steps, 100, light_jitter, seed,
                                      texture_smoothing, spp, method))
    if _skip_finished(resume, db, experiment, case_id):
        return
    mesh_obj = default_aeroplane() if mesh == "aeroplane" else load_mesh_arg(mesh)[0]
    kwargs.update(ddn_shape_options(method, perturbation, mesh_obj))
    hidden = outdoor_classifier_setup(mesh_obj, image_size=size, spp=spp)
    row = blackbox_classifier(mesh_obj, hidden, victim=load_victim(victim), true_class=true_class, target=target,
                              perturbation=perturbation, attack_kwargs=kwargs, jitter=jitter_dict,
                              robustness=robustness, texture_smoothing=texture_smoothing, case_id=case_id,
                              callback=callback)
    _save_blackbox(row, db, out, experiment)


@transfer_app.command("blackbox-detector")
def blackbox_detector_cmd(
    hide: str = typer.Option("dining table", help="Class to hide (detector class name), e.g. 'chair'."),
    victim: str = typer.Option("ssd_mobilenet_v2_coco", help="Detector victim."),
    perturbation: str = typer.Option("texture", "--perturbation", help="texture or shape (of the bunny)."),
    context: str = typer.Option("photo", help="photo: only the bunny is rendered by meshadv, over the Mitsuba photo; "
                                "render: desk, chair and bunny are rendered by meshadv over the empty room."),
    light_fit: str = typer.Option("object", help="object: fit the lights on the bunny's pixels (the light where it "
                                  "stands); known: on desk, chair and bunny together."),
    method: Optional[str] = typer.Option(None, help=_METHOD_HELP),
    steps: int = typer.Option(100, help="Attack steps."),
    lr: Optional[float] = typer.Option(None, help="--method adam: attack learning rate (default: the attack's)."),
    lambda_perceptual: Optional[float] = typer.Option(None, help="--method adam: perceptual loss weight (default: "
                                                                 "the attack's)."),
    jitter: float = typer.Option(1.0, help="Scale of the per-step jitter of the estimates (0 = none)."),
    light_jitter: Optional[float] = typer.Option(None, help=_LIGHT_JITTER_HELP),
    eot: int = typer.Option(1, help=_EOT_HELP),
    margin: float = typer.Option(0.0, help=_MARGIN_HELP),
    pixel_noise: float = typer.Option(0.0, help=_NOISE_HELP),
    antialias: int = typer.Option(1, help=_AA_HELP),
    texture_smoothing: Optional[int] = typer.Option(None, help=_SMOOTH_HELP + " --method adam only."),
    early_stop: Optional[int] = typer.Option(None, help="Stop once the margin has held this many steps in a row."),
    verify: int = typer.Option(16, help=_VERIFY_HELP),
    seed: int = typer.Option(0, help="Seed of the jitter, the pixel noise and the verification views."),
    progress: int = typer.Option(25, help="Print the attack's progress to stderr every N steps (0 = quiet)."),
    score_threshold: float = typer.Option(0.3, help="Detection score at which the hidden class counts as detected."),
    object_scale: float = typer.Option(1.0, help="Scale of the bunny about its base (1 = the scene's 0.25 m)."),
    size: int = typer.Option(300, help="Image side."),
    spp: int = typer.Option(64, help="Mitsuba samples per pixel (the photo and every Mitsuba render)."),
    case_id: Optional[str] = typer.Option(None, help="Row id (default: built from the setup and the settings)."),
    db: Optional[Path] = typer.Option(None, help="Results database to add the row to."),
    out: Optional[Path] = typer.Option(None, "-o", "--out", help="Folder for images, mesh and numbers."),
    experiment: str = typer.Option("blackbox", help="Name of this run in the database."),
    resume: bool = typer.Option(False, "--resume", help=_RESUME_HELP),
) -> None:
    """Black-box pipeline against a detector: the bunny on the indoor desk hides the table (or the chair)."""
    from meshadv.transfer.blackbox import blackbox_detector, ddn_shape_options, settings_suffix
    from meshadv.transfer.setups import indoor_detector_setup
    from meshadv.victims import load_victim

    _check_blackbox_render(perturbation, size, spp, texture_smoothing)
    if context not in ("photo", "render"):
        raise typer.BadParameter("context must be photo or render", param_hint="--context")
    if light_fit not in ("object", "known"):
        raise typer.BadParameter("light-fit must be object or known", param_hint="--light-fit")
    if not 0 < score_threshold <= 1:
        raise typer.BadParameter("score-threshold must be in (0, 1]", param_hint="--score-threshold")
    if not object_scale > 0:
        raise typer.BadParameter("object-scale must be > 0", param_hint="--object-scale")
    method = _method(method, lr, lambda_perceptual, texture_smoothing)
    kwargs = _attack_kwargs(steps, lr, lambda_perceptual, antialias, early_stop=early_stop, seed=seed, method=method)
    robustness = _robustness(eot, margin, pixel_noise, verify, seed)
    callback = _progress(progress)
    jitter_dict = _jitter(jitter, light_jitter)
    if case_id is None:
        case_id = (f"indoor_bunny_hide_{hide.replace(' ', '_')}"
                   + (f"_{perturbation}" if perturbation != "texture" else "")
                   + (f"_{context}" if context != "photo" else "")
                   + ("_lightsknown" if light_fit != "object" else "")
                   + (f"_scale{object_scale:g}" if object_scale != 1.0 else "")
                   + settings_suffix(jitter, eot, margin, pixel_noise, antialias, steps, 100, light_jitter, seed,
                                      texture_smoothing, spp, method))
    if _skip_finished(resume, db, experiment, case_id):
        return
    setup = indoor_detector_setup(image_size=size, spp=spp, object_scale=object_scale)
    kwargs.update(ddn_shape_options(method, perturbation, setup.objects[setup.object_index]))
    row = blackbox_detector(setup.objects, setup.object_index, setup.hidden, victim=load_victim(victim),
                            hide_class=hide, perturbation=perturbation, context=context, light_fit=light_fit,
                            background_exclude=setup.background_exclude,
                            attack_kwargs=kwargs, jitter=jitter_dict, robustness=robustness,
                            texture_smoothing=texture_smoothing,
                            score_threshold=score_threshold, case_id=case_id, callback=callback)
    row["object_scale"] = object_scale
    _save_blackbox(row, db, out, experiment)


@transfer_app.command("report")
def report_cmd(
    results: Path = typer.Argument(..., help="Results database."),
    out: Optional[Path] = typer.Option(None, "-o", "--out", help="Markdown file to write (default: print)."),
    experiment: Optional[str] = typer.Option(None, help="Only this transfer run."),
) -> None:
    """Print (or write) the transfer tables and confusion matrices stored in RESULTS."""
    from meshadv.transfer.results import load_transfer_rows, transfer_report

    if not results.is_file():
        raise typer.BadParameter(f"{results} does not exist", param_hint="RESULTS")
    text = transfer_report(load_transfer_rows(results, experiment=experiment))
    if out is None:
        typer.echo(text)
    else:
        from meshadv.util.atomic import write_text_atomic

        out.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out, text)
        typer.echo(f"wrote {out}")


def register(app: typer.Typer) -> None:
    """Add the ``transfer`` command group to ``app``."""
    app.add_typer(transfer_app, name="transfer")
