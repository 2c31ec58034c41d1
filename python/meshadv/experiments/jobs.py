"""The attack job: one MeshAdv attack of one mesh towards one target class, run inside a sweep worker.

``run_attack_job(spec, out_dir)`` loads the mesh and the victim named by the spec (see
:func:`meshadv.experiments.config.expand_jobs`), checks that the benign render is classified as the mesh's class (the
paper attacks correctly classified inputs; otherwise the job is recorded as ``skipped``), runs
:class:`~meshadv.attacks.ShapeAttack` or :class:`~meshadv.attacks.TextureAttack` towards
``TargetedMisclassification(target)`` over the spec's views (and evaluates on the unseen views of a multi-view job;
the attack option ``required_margin`` > 0 wraps the criterion in :class:`~meshadv.attacks.WithMargin`, so success
means the target leads by that many logits and the kept mesh is the least distorted one that does),
and writes into ``out_dir``: ``benign.ply``, ``benign_v{j}.png`` and everything :meth:`AttackResult.save` writes
(``result.json`` last, so artefacts are complete before the runner records the job).

The returned record holds ``success``, ``cpu_time`` (CPU seconds of the job's process), ``distance``
(per-pair-mean Laplacian loss for shape, face-colour RMSE for texture: the paper's measures), ``distances``,
``steps``, ``time``, ``benign_correct``, the top-1 labels, ``eval_success_rate`` and ``benign_unseen_correct``
(multi-view: whether the benign render is the source class on every unseen view; with ``benign_correct_only`` a
multi-view job is skipped unless it is right on its attack and unseen views alike), ``artifacts`` (file
names relative to ``out_dir``) and what the job ran with where its spec may not say: ``victim_optimize`` (whether the
victim was built with ``load_victim(optimize=True)``: the spec's ``victim_optimize``, else the default then) and
``attack_config`` (the attack's effective hyper-parameters, update-rule defaults filled in: ``Attack.config()``);
:mod:`meshadv.experiments.regenerate` pins both when it reruns the job. The attack reports every step to the sweep
driver (:func:`meshadv.experiments.worker.report_steps`); :func:`planned_steps` is the most steps a job can run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple

from meshadv._validate import setting_flag
from meshadv.experiments.regenerate import attack_pin_key, pinned_spec

__all__ = ["run_attack_job", "load_job_mesh", "save_job_mesh", "JobContext", "BenignVerdict", "planned_steps",
           "victim_optimize", "default_attack_options", "pin_defaults", "prepare_attack_specs", "seed_pinned_defaults",
           "DISTANCE_KEYS", "PINNED_DEFAULTS_KEY"]

#: Distance key of the record's ``distance`` per perturbation type: the measure comparable with the paper
#: (``meshadv.attacks.distances.PAPER_COMPARABLE``; the texel RMSE for ``texture-map``, which the paper does not
#: have; the record's ``distances`` holds every measure).
DISTANCE_KEYS = {"shape": "laplacian_pair_mean", "texture": "color_rmse", "texture-map": "texel_rmse"}

_VICTIM_CACHE: Dict[str, Any] = {}


def load_job_mesh(mesh_spec: Dict[str, Any], perturbation: Optional[str] = None) -> Any:
    """Load the mesh described by a job's ``mesh`` entry, normalised into ``[-1, 1]`` (Y up), as the job of
    ``perturbation`` attacks it.

    With ``perturbation`` given and ``mesh_spec["surface"]`` true (the default; :func:`pin_defaults` pins false for
    a database started when jobs loaded every file per face) a file's texture and vertex colours are taken as they
    are, by ``meshadv attack``'s loader (:func:`meshadv.mesh.file_input.attack_input`: a shape job of a textured or
    vertex-coloured file attacks its :class:`~meshadv.mesh.surface_mesh.SurfaceMesh` under ``mesh_spec["shading"]``,
    resampled with its texture carried onto a new atlas; a texture job the per-face mesh). A file with neither, and
    every built-in shape, loads per face as always (drawn smooth, each vertex the mean of its faces' colours, for
    ``shading = "smooth"``).

    Args:
        mesh_spec: ``{"source": "pascal3d", "path": "pascal3d/<class>/NN.ply", ...}`` (path relative to the shared
            data folder), ``{"source": "builtin", "name": ...}`` or ``{"source": "files", "path": ...}``;
            optional ``target_faces`` (uniform resampling), ``max_faces``, ``shading`` (``"flat"`` or ``"smooth"``;
            default: what the file asks for) and ``surface``.
        perturbation: the job's perturbation (``None``: the per-face mesh).

    Returns:
        A ``meshadv.mesh.Mesh``, or a ``SurfaceMesh`` (see above).

    Raises:
        ValueError: unknown source, bad shading. FileNotFoundError: missing file or shared data.
        MeshLoadError: the file's texture or attributes are unusable (the message names the file and field).

    Example:
        >>> load_job_mesh({"source": "files", "path": "ball.obj", "shading": "smooth"}, "shape")  # doctest: +SKIP
        SurfaceMesh(...)
    """
    from meshadv import mesh as meshlib
    from meshadv.mesh.file_input import MeshInput, attack_input, read_file_input

    source = mesh_spec.get("source")
    max_faces = int(mesh_spec.get("max_faces", 20000))
    target_faces = int(mesh_spec.get("target_faces", 0))
    shading = mesh_spec.get("shading")
    if shading not in (None, "flat", "smooth"):
        raise ValueError(f"mesh.shading must be flat or smooth, got {shading!r}")
    if source == "builtin":
        mesh = meshlib.builtin_mesh(mesh_spec["name"])
        if target_faces > 0:  # a built-in shape is resampled here (the attack command takes it as it is)
            mesh = meshlib.resample_mesh(mesh, target_faces=target_faces)
        loaded, resample = MeshInput(mesh, str(mesh_spec["name"]), None, None, False), 0
    elif source in ("pascal3d", "files"):
        if source == "pascal3d":
            from meshadv.data import require_shared_data

            path = require_shared_data(mesh_spec["path"])
        else:
            path = Path(mesh_spec["path"])
            if not path.is_file():
                raise FileNotFoundError(f"mesh file {path} does not exist")
        loaded, resample = read_file_input(path, z_up=source == "pascal3d", max_faces=max_faces), target_faces
    else:
        raise ValueError(f"mesh.source must be pascal3d, builtin or files, got {source!r}")
    if perturbation is None or not mesh_spec.get("surface", True):
        return loaded.mesh if resample == 0 else meshlib.resample_mesh(loaded.mesh, target_faces=resample)
    return attack_input(loaded, str(perturbation), None if perturbation == "texture" else shading, resample).mesh


def save_job_mesh(mesh: Any, out: Path, stem: str) -> Dict[str, str]:
    """Write a job's mesh into ``out`` as ``<stem>.ply`` (per face, or a ``SurfaceMesh``'s vertex colours) and, for a
    ``SurfaceMesh``, ``<stem>.obj`` with its texture (MTL + PNG) or vertex colours
    (:func:`~meshadv.mesh.surface_mesh.save_any_mesh`); returns the artefact names, ``<stem>_mesh`` and
    ``<stem>_surface``."""
    from meshadv.mesh.surface_mesh import SurfaceMesh, save_any_mesh

    save_any_mesh(mesh, out / f"{stem}.ply")
    if not isinstance(mesh, SurfaceMesh):
        return {f"{stem}_mesh": f"{stem}.ply"}
    save_any_mesh(mesh, out / f"{stem}.obj")
    return {f"{stem}_mesh": f"{stem}.ply", f"{stem}_surface": f"{stem}.obj"}


def _make_job_attack(spec: Dict[str, Any], options: Dict[str, Any]) -> Any:
    """The attack of ``spec`` from its attack options (render-setup keys and ``required_margin`` removed)."""
    from meshadv.attacks import make_attack
    from meshadv.attacks.families import check_perturbation

    perturbation = check_perturbation(spec["perturbation"], "spec['perturbation']")
    return make_attack(perturbation, **{"seed": int(spec.get("seed", 0)), **options})


def _attack_options(spec: Dict[str, Any]) -> Tuple[Dict[str, Any], Dict[str, Any], float]:
    """``(render-setup options, attack options, required_margin)`` of a spec's ``attack`` entry."""
    from meshadv.render.setup import split_setup_options

    setup_options, options = split_setup_options(dict(spec.get("attack", {})))
    required_margin = float(options.pop("required_margin", 0.0))
    return setup_options, options, required_margin


def planned_steps(spec: Dict[str, Any]) -> Optional[int]:
    """The most optimiser steps the attack job of ``spec`` can run (``steps`` x rounds of its update rule; early
    stopping ends sooner), or ``None`` when the spec's attack cannot be built (the job will fail and say why)."""
    from meshadv.attacks.update import make_update_rule

    try:
        attack = _make_job_attack(spec, _attack_options(spec)[1])
        rule = make_update_rule(attack.method, attack=attack, num_targets=1, **attack.method_options)
    except (KeyError, TypeError, ValueError):
        return None
    return int(attack.steps) * int(rule.rounds)


def victim_optimize(spec: Dict[str, Any]) -> bool:
    """Whether the job of ``spec`` builds its victim with ``load_victim(optimize=True)``: the spec's
    ``victim_optimize`` when it sets one, else ``load_victim``'s current default (recorded with the job, since the
    folded network's float32 rounding moves an attack's result)."""
    value = spec.get("victim_optimize")
    if value is None:
        from meshadv.victims import load_victim

        return bool((load_victim.__kwdefaults__ or {}).get("optimize", True))
    return setting_flag("spec['victim_optimize']", value)


#: Meta key of a results database's pinned defaults (:func:`pin_defaults`).
PINNED_DEFAULTS_KEY = "pinned_defaults"


def default_attack_options(perturbation: str, method: Optional[str]) -> Dict[str, Any]:
    """The code's current defaults of an attack of ``perturbation`` and update rule ``method`` (``None``: the
    attack's default rule): ``Attack.config()`` of an attack built with nothing else set, less ``perturbation`` and
    ``seed``, with the recommended rule's perceptibility cap (:func:`meshadv.perceptibility.recommended_cap`) for
    ``method`` :data:`~meshadv.attacks.update.RECOMMENDED_METHOD` (the paper's Adam keeps none). Only defaults: a
    spec's own options are merged over them."""
    from meshadv.attacks import make_attack
    from meshadv.attacks.families import check_perturbation
    from meshadv.attacks.update import RECOMMENDED_METHOD
    from meshadv.perceptibility import recommended_cap

    kwargs: Dict[str, Any] = {} if method is None else {"method": method}
    if method == RECOMMENDED_METHOD:
        kwargs["perceptibility_cap"] = recommended_cap(perturbation)
    config = make_attack(check_perturbation(perturbation, "perturbation"), **kwargs).config()
    return {k: v for k, v in config.items() if k not in ("perturbation", "seed")}


def pin_defaults(store: Any, specs: Any) -> Dict[str, Any]:
    """The defaults a results database's attack jobs run with, fixed the first time a kind of job runs.

    A spec names only what its config sets; the rest comes from the code's defaults (the update rule's options, the
    victim's ``optimize``), which can change between the start of a sweep and its resumption. The database keeps, in
    its meta entry :data:`PINNED_DEFAULTS_KEY`, ``{"victim_optimize": bool, "surface_meshes": bool, "attack":
    {"<type>/<method>": options}}`` (the :data:`meshadv.experiments.regenerate.Assumed` format): entries missing for
    a kind of job among ``specs`` are added from today's code, existing ones are kept, so every job of a database
    runs with the defaults of its first run. ``surface_meshes`` (whether jobs take a file's texture and vertex
    colours as they are, :func:`load_job_mesh`) is pinned true for a new database and false for one that already
    holds finished jobs without the pin: they were run per face. The runner applies them
    (:func:`meshadv.experiments.regenerate.pinned_spec`) before a job runs; the job ids do not change.

    Args:
        store: an open, writable :class:`~meshadv.experiments.store.ResultStore`.
        specs: the specs about to run.

    Returns:
        The pinned defaults.
    """
    pins = dict(store.get_meta(PINNED_DEFAULTS_KEY) or {})
    attack_pins = dict(pins.get("attack") or {})
    changed = False
    if "victim_optimize" not in pins:
        pins["victim_optimize"] = victim_optimize({})
        changed = True
    if "surface_meshes" not in pins:  # a database with finished jobs but no pin was started loading per face
        pins["surface_meshes"] = store.counts()["done"] == 0
        changed = True
    for spec in specs:
        attack = spec.get("attack") or {}
        key = attack_pin_key(spec.get("perturbation"), attack.get("method"))
        if key not in attack_pins:
            try:
                attack_pins[key] = default_attack_options(str(spec.get("perturbation")), attack.get("method"))
            except (KeyError, TypeError, ValueError):  # a bad spec fails in its job, with the job's own message
                continue
            changed = True
    pins["attack"] = attack_pins
    if changed:
        store.set_meta(PINNED_DEFAULTS_KEY, pins)
    return pins


def seed_pinned_defaults(store: Any, assumed: Dict[str, Any]) -> Dict[str, Any]:
    """Pin a database's defaults from an assumed-defaults mapping (e.g. ``docs/results/paper_medium/
    sweep_defaults.json``, read with :func:`meshadv.experiments.regenerate.load_assumed`) before it is resumed:
    the defaults its finished jobs ran with, which today's code may no longer have. Entries the database already
    pins are kept.

    Returns:
        The pinned defaults.
    """
    pinned_spec({}, None, assumed)  # validates
    pins = dict(store.get_meta(PINNED_DEFAULTS_KEY) or {})
    attack_pins = dict(pins.get("attack") or {})
    for key, options in (assumed.get("attack") or {}).items():
        full = key if "/" in key else attack_pin_key(key, options.get("method"))
        attack_pins.setdefault(full, dict(options))
    pins["attack"] = attack_pins
    if "victim_optimize" in assumed:
        pins.setdefault("victim_optimize", assumed["victim_optimize"])
    store.set_meta(PINNED_DEFAULTS_KEY, pins)
    return pins


def _victim(name: str, weights: Any = None, optimize: bool = True) -> Any:
    key = f"{name}:{weights}:{optimize}"
    if key not in _VICTIM_CACHE:
        from meshadv.victims import load_victim

        _VICTIM_CACHE[key] = load_victim(name, weights=weights, optimize=optimize)
    return _VICTIM_CACHE[key]


@dataclass(frozen=True)
class BenignVerdict:
    """How the job's victim classifies a mesh's benign render over the job's attack views."""

    #: whether every attack view is classified as the job's source class
    correct: bool
    #: the victim's top-1 label per view
    top1: List[str]
    #: the benign renders, ``(views, 3, H, W)``
    images: Any


@dataclass(frozen=True)
class JobContext:
    """What a job renders and attacks with, built from its spec alone: views, victim, render setup, attack options."""

    spec: Dict[str, Any]
    views: Any
    eval_views: Any
    victim: Any
    victim_optimize: bool
    setup: Any
    attack_options: Dict[str, Any]
    required_margin: float

    @classmethod
    def from_spec(cls, spec: Dict[str, Any]) -> "JobContext":
        """The context of ``spec`` (the victim is loaded once per process and cached)."""
        from meshadv.render import ViewSet
        from meshadv.render.setup import RenderSetup

        optimize = victim_optimize(spec)
        setup_options, options, required_margin = _attack_options(spec)
        return cls(
            spec=spec,
            views=ViewSet.from_records(spec["views"]),
            eval_views=ViewSet.from_records(spec["eval_views"]) if spec.get("eval_views") else None,
            victim=_victim(spec["victim"], spec.get("victim_weights"), optimize),
            victim_optimize=optimize,
            setup=RenderSetup(image_size=int(spec.get("image_size", 224)), **setup_options),
            attack_options=options,
            required_margin=required_margin,
        )

    def benign_verdict(self, mesh: Any, views: Any = None) -> BenignVerdict:
        """Judge ``mesh``'s benign render as the attack renders it: the job's check before it attacks. Right on a
        view when the top-1 is in the source class's group (:func:`~meshadv.attacks.criteria.resolve_true_class`:
        any ImageNet class of a PASCAL3D+ class's group; a class of no group itself alone). ``views``: the views
        to judge (default the job's attack views; a multi-view job's unseen views are :attr:`eval_views`)."""
        from meshadv.attacks import Misclassification, evaluate

        benign = evaluate(mesh, self.views if views is None else views, self.victim,
                          Misclassification(self.spec["source_class"]), setup=self.setup)
        names = getattr(self.victim, "class_names", None)
        top1 = benign.top1[0].tolist() if benign.top1 is not None else []
        labels = [names[i] if names and i < len(names) else str(i) for i in top1]
        return BenignVerdict(correct=not bool(benign.success.any()), top1=labels, images=benign.images[0])


def run_attack_job(spec: Dict[str, Any], out_dir: Path) -> Dict[str, Any]:
    """Run one attack job (see the module docstring).

    Args:
        spec: a job from :func:`meshadv.experiments.config.expand_jobs`.
        out_dir: the job's artefact folder (exists).

    Returns:
        The JSON-able record.

    Raises:
        ValueError: bad spec (unknown perturbation type, victim, class...).
        KeyboardInterrupt: the attack was interrupted (Ctrl-C, or SIGTERM where it takes Ctrl-C's path): nothing is
            recorded, so that a sweep re-queues the job and a regeneration is not taken for the job's artefacts.
    """
    import torch

    from meshadv.attacks import Criterion, TargetedMisclassification, WithMargin
    from meshadv.attacks.families import check_perturbation
    from meshadv.experiments.perturbation import PERTURBATION_KEY, Perturbation
    from meshadv.experiments.provenance import compute_environment
    from meshadv.experiments.worker import attack_step_callback
    from meshadv.mesh.surface_mesh import SurfaceMesh
    from meshadv.util.png import save_png

    start, cpu_start = time.perf_counter(), time.process_time()
    out = Path(out_dir)
    perturbation = check_perturbation(spec["perturbation"], "spec['perturbation']")
    torch.manual_seed(int(spec.get("seed", 0)))
    mesh = load_job_mesh(spec["mesh"], perturbation)
    context = JobContext.from_spec(spec)
    benign = context.benign_verdict(mesh)  # judge the benign render as the attack renders it
    # a multi-view job also judges its unseen views: Table 2 counts the meshes right on every view it is scored on
    unseen = None if context.eval_views is None else context.benign_verdict(mesh, context.eval_views)
    artifacts = save_job_mesh(mesh, out, "benign")
    benign_pngs = []
    for j in range(benign.images.shape[0]):
        save_png(benign.images[j], out / f"benign_v{j}.png")
        benign_pngs.append(f"benign_v{j}.png")
    record: Dict[str, Any] = {
        "compute": compute_environment(),  # what the float rounding depends on (regeneration compares it)
        "benign_correct": benign.correct,
        "benign_top1": benign.top1,
        **({} if unseen is None else {"benign_unseen_correct": unseen.correct, "benign_unseen_top1": unseen.top1}),
        "victim_optimize": context.victim_optimize,
        "num_vertices": int(mesh.vertices.shape[0]),
        "num_faces": int(mesh.faces.shape[0]),
        # whether a file's texture and vertex colours were taken as they are (regeneration loads the mesh so again)
        "mesh_surface": bool(spec["mesh"].get("surface", True)),
        **({"mesh_shading": mesh.shading} if isinstance(mesh, SurfaceMesh) else {}),  # how its surface was drawn
        "artifacts": {**artifacts, "benign_images": benign_pngs},
    }
    if spec.get("benign_correct_only") and not (benign.correct and (unseen is None or unseen.correct)):
        wrong = benign if not benign.correct else unseen
        where = "" if wrong is benign else " on the unseen views"
        record.update(skipped=True, success=False, distance=None, steps=0, time=time.perf_counter() - start,
                      reason=f"benign render{where} classified as {wrong.top1}, not {spec['source_class']}")
        return record
    attack = _make_job_attack(spec, context.attack_options)
    # the effective hyper-parameters, defaults filled in (a spec names only what its config sets): regeneration
    # (meshadv.experiments.regenerate) pins them, so a later change of a default does not change a rerun
    record["attack_config"] = attack.config()
    criterion: Criterion = TargetedMisclassification(spec["target"])
    if context.required_margin > 0:
        criterion = WithMargin(criterion, context.required_margin)
    result = attack(mesh, context.views, context.victim, criterion, setup=context.setup,
                    eval_views=context.eval_views, callback=attack_step_callback)
    if result.interrupted:  # the attack keeps its best so far on Ctrl-C; a job cut short is not a result
        raise KeyboardInterrupt(f"attack job interrupted after {result.steps} steps")
    result.save(out)
    distances = dict(result.distances[0])
    ply, obj = result.mesh_filenames(0)
    rec = result.to_record()
    record.update(
        skipped=False,
        success=bool(result.succeeded[0]),
        distance=distances.get(DISTANCE_KEYS[perturbation]),
        distances=distances,
        steps=int(result.steps),
        time=float(result.wall_time),
        job_time=time.perf_counter() - start,
        cpu_time=time.process_time() - cpu_start,  # CPU seconds of this process (every thread): cost projections
        steps_to_success=result.steps_to_success[0],
        adversarial_top1=(rec.get("top1_names") or [None])[0],
        target_score=[float(s) for s in result.scores[0].tolist()],
        eval_success_rate=None if result.eval_success is None else float(result.eval_success[0].float().mean()),
        lambda_perceptual=rec["lambdas"][0],
    )
    n_views = result.original_images.shape[0]
    # the perturbation itself (float16, compressed): a copy of the database alone rebuilds the mesh counted here
    record[PERTURBATION_KEY] = Perturbation.between(mesh, result.mesh).to_record()
    record["artifacts"].update(
        adversarial_mesh=ply,
        adversarial_obj=obj,
        adversarial_images=[f"after_v{j}.png" for j in range(n_views)],
        result="result.json",
    )
    return record


def prepare_attack_specs(store: Any, specs: List[Dict[str, Any]]) -> Callable[[Dict[str, Any]], Dict[str, Any]]:
    """The ``prepare_specs`` hook of :func:`run_attack_job` (:func:`meshadv.experiments.runner.run_sweep`): pin the
    database's defaults for ``specs`` (:func:`pin_defaults`) and return the function that fills them into a spec
    (:func:`meshadv.experiments.regenerate.pinned_spec`)."""
    pins = pin_defaults(store, specs)
    return lambda spec: pinned_spec(spec, None, pins)[0]


run_attack_job.prepare_specs = prepare_attack_specs  # type: ignore[attr-defined]
