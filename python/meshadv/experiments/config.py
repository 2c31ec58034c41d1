"""The declarative sweep file (TOML or YAML) and its expansion into attack jobs.

A sweep file has these sections (every key optional unless noted; see ``configs/paper_small.toml``)::

    [experiment]  name, seeds = [0], output = "runs/<name>" (relative to the file), db = "<output>/results.db"
    [meshes]      source = "pascal3d" | "builtin" | "files"
                  classes = [...] (PASCAL3D+ classes; default all 7), models_per_class = 1 (models 01, 02, ...),
                  or models = ["01", ...] (every class) or models = {chair = ["03"], ...} (per class)
                  builtin = [{name = "sphere", class = "bottle"}], files = [{path = "x.ply", class = "chair"}]
                  target_faces = 0 (uniform resampling, 0 = keep), max_faces = 20000
    [render]      image_size = 224, configurations = 72, config_seed = 0, distance = [3.6, 4.4],
                  azimuth = [0, 360], elevation = [0, 30], viewing_angle = 30,
                  light_intensity = [0.4, 0.8], ambient = [0.3, 0.6], light_jitter = 30,
                  rendering_set = "packaged" | "path/to/set.json" (optional, see below)
    [victims]     names = ["efficientnet_lite0"] (required), weights = {densenet121 = "densenet121.pth"}
                  (weights files for victims that need them, relative to the file; the path is part of the job),
                  configurations = {efficientnet_lite2 = 4} (per-victim cap on render.configurations)
    [attack]      perturbations = ["shape", "texture"] (the old key ``types`` is read too), targets = "others" | [...],
                  benign_correct_only = true
    [attack.shape] / [attack.texture]   keyword arguments of ShapeAttack / TextureAttack (steps, lr, ...)
    [attack.protocols.<name>]   extra attack settings on a subset: configurations = 2 (first configurations per
                  class), victims = [...] (default all), shape = {...}, texture = {...}; their jobs carry
                  ``"protocol": "<name>"`` and the tables report them as separate rows
    [multiview]   enabled = false, view_counts = [5, 10, 15], azimuth_ranges = [[45, 60], [35, 70], [15, 75]],
                  grid = false (true: every view count with every range, the paper's 3 x 3 Table 2; false: pairs),
                  eval_views = 20, perturbations = ["shape", "texture"] (or ``types``), classes = [...],
                  targets = [...] | {chair = "sofa", ...} (one target per class), victims = [...] (default all),
                  elevation = 20, distance = 4.0
    [runner]      job = "meshadv.experiments.jobs:run_attack_job", max_attempts = 2, timeout = 0, workers = 0,
                  threads_per_job = 0, max_jobs_per_worker = 0

Rendering configurations are drawn once from ``config_seed`` (so every mesh, victim and target sees the same
configurations): camera distance, azimuth and elevation uniform in their ranges, one directional light from the
camera side jittered by up to ``light_jitter`` degrees, light intensity and ambient uniform in their ranges. Each is a
one-view ``ViewSet`` record (``meshadv.render.ViewSet.from_records``). Meshes are normalised into ``[-1, 1]``, so
with a 30° field of view the camera must be about ``1 / tan(15°) + 1 ≈ 4.7`` away to keep the whole object in the
frame; the default distances (3.6 to 4.4) show it nearly whole and large.

With ``render.rendering_set`` the configurations come from a PASCAL3D+ rendering set instead
(:mod:`meshadv.datasets.rendering_set`; ``"packaged"`` = the set shipped with meshadv, built with EfficientNet-Lite0
and -Lite2): for each class in ``meshes.classes`` the first ``render.configurations`` kept renderings (restricted to
``meshes.models`` when given), each with its own mesh and view, exactly as the paper picks its 72 configurations per
class. The sampling keys above are then unused; ``render.image_size`` still sets the attack's render size.

Jobs (one attack each) are the product mesh x configuration x victim x perturbation type x target x seed (Table 1),
plus, when ``[multiview]`` is enabled, mesh x victim x type x target x (view count, azimuth range) x seed attacks
over several views, evaluated on unseen views (Table 2).

Order (the order a fresh sweep runs them in; job ids are hashes of the spec and do not depend on it): the main
setting, then each protocol, then the multi-view jobs. Within a setting the jobs are configuration-major, then
victim: configuration 0 of every class (mesh) for the first victim, then for the next victim, then configuration 1,
and so on (per class: perturbation types, then targets), so a sweep stopped part-way has covered every class about
equally instead of the first classes only. The multi-view jobs are cell-major the same way: the first (view count,
azimuth range) cell of every class, then the next. :func:`select_parts` keeps only some of these parts (``meshadv
sweep --only multiview``), to run one table first.
"""

from __future__ import annotations

import os
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

from meshadv.experiments.config_keys import check_attack_values, check_keys
from meshadv.util.spherical import spherical_direction

__all__ = [
    "SweepConfig",
    "load_config",
    "parse_config",
    "expand_jobs",
    "job_part",
    "select_parts",
    "view_record",
    "PASCAL3D_CLASSES",
    "DEFAULT_JOB",
]

#: The 7 PASCAL3D+ classes of the paper, in its order.
PASCAL3D_CLASSES = ("aeroplane", "bicycle", "boat", "bottle", "chair", "diningtable", "sofa")

#: The attack job function used unless ``[runner] job`` says otherwise.
DEFAULT_JOB = "meshadv.experiments.jobs:run_attack_job"

_SECTIONS = ("experiment", "meshes", "render", "victims", "attack", "multiview", "runner")
def _perturbations_key(table: Dict[str, Any], section: str) -> Tuple[Dict[str, Any], str]:
    """``table`` with the perturbation list under its one name, and the key the user wrote (for messages).

    Configs written before issue 13 call it ``types``; giving both is an error.
    """
    if "types" not in table:
        return table, f"{section}.perturbations"
    if "perturbations" in table:
        raise ValueError(f"{section}.types is the old name of {section}.perturbations; give only one of them")
    table["perturbations"] = table.pop("types")
    return table, f"{section}.types"


@dataclass(frozen=True)
class SweepConfig:
    """A parsed sweep file.

    Attributes:
        name: experiment name. seeds: attack seeds.
        output: artefact root folder. db: results database path.
        meshes, render, victims, attack, multiview, runner: the sections (dicts, defaults filled in).
        raw: the file's parsed content, text: its text (stored in the database for the report).
    """

    name: str
    seeds: Tuple[int, ...]
    output: Path
    db: Path
    meshes: Dict[str, Any]
    render: Dict[str, Any]
    victims: Tuple[str, ...]
    victim_weights: Dict[str, str]
    attack: Dict[str, Any]
    multiview: Dict[str, Any]
    runner: Dict[str, Any]
    raw: Dict[str, Any] = field(repr=False)
    text: str = field(default="", repr=False)


def _range(section: Dict[str, Any], key: str, default: Sequence[float]) -> Tuple[float, float]:
    value = section.get(key, default)
    if isinstance(value, (int, float)):
        return float(value), float(value)
    if not isinstance(value, (list, tuple)) or len(value) != 2 or not all(isinstance(v, (int, float)) for v in value):
        raise ValueError(f"render.{key} must be a number or a [low, high] pair, got {value!r}")
    low, high = float(value[0]), float(value[1])
    if high < low:
        raise ValueError(f"render.{key} must have low <= high, got {value!r}")
    return low, high


def parse_config(raw: Dict[str, Any], *, base_dir: Union[str, Path] = ".", text: str = "") -> SweepConfig:
    """Validate a parsed sweep file and fill in defaults.

    Args:
        raw: the parsed TOML/YAML mapping.
        base_dir: folder that relative ``output`` / ``db`` / mesh paths are resolved against.
        text: the file's text (kept for the report).

    Returns:
        The :class:`SweepConfig`.

    Raises:
        ValueError: unknown sections, missing victims, bad types or values (the message names the key).
    """
    if not isinstance(raw, dict):
        raise ValueError(f"a sweep config must be a mapping, got {type(raw).__name__}")
    from meshadv.attacks.families import PERTURBATIONS as _FAMILIES

    check_keys(raw, _FAMILIES)  # misspelt keys fail here, with the closest valid key
    base = Path(base_dir)
    exp = dict(raw.get("experiment", {}))
    name = str(exp.get("name", "sweep"))
    seeds = exp.get("seeds", [0])
    if isinstance(seeds, int):
        seeds = [seeds]
    if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) for s in seeds):
        raise ValueError(f"experiment.seeds must be a non-empty list of ints, got {seeds!r}")
    output = Path(os.path.normpath(base / str(exp.get("output", f"runs/{name}"))))
    db = Path(exp["db"]) if "db" in exp else output / "results.db"
    if not db.is_absolute() and "db" in exp:
        db = Path(os.path.normpath(base / db))

    meshes = {"source": "pascal3d", "classes": list(PASCAL3D_CLASSES), "models_per_class": 1, "models": None,
              "builtin": [], "files": [], "target_faces": 0, "max_faces": 20000, **raw.get("meshes", {})}
    if meshes["source"] not in ("pascal3d", "builtin", "files"):
        raise ValueError(f"meshes.source must be pascal3d, builtin or files, got {meshes['source']!r}")
    bad = [c for c in meshes["classes"] if c not in PASCAL3D_CLASSES]
    if meshes["source"] == "pascal3d" and bad:
        raise ValueError(f"meshes.classes must be PASCAL3D+ classes {list(PASCAL3D_CLASSES)}, got {bad}")
    if meshes["models"] is not None and not isinstance(meshes["models"], (list, dict)):
        raise ValueError(f"meshes.models must be a list of model numbers or a class -> list table, "
                         f"got {meshes['models']!r}")
    if int(meshes["models_per_class"]) < 1:
        raise ValueError(f"meshes.models_per_class must be >= 1, got {meshes['models_per_class']}")
    for entry in meshes["builtin"] + meshes["files"]:
        if not isinstance(entry, dict) or "class" not in entry or not ({"name", "path"} & set(entry)):
            raise ValueError(f"meshes.builtin / meshes.files entries need 'name' or 'path' and 'class', got {entry!r}")
    meshes["files"] = [{**e, "path": str((base / e["path"]).resolve())} for e in meshes["files"]]

    render = {"image_size": 224, "configurations": 72, "config_seed": 0, "viewing_angle": 30.0,
              "light_jitter": 30.0, **raw.get("render", {})}
    if int(render["image_size"]) < 8:
        raise ValueError(f"render.image_size must be >= 8, got {render['image_size']}")
    if int(render["configurations"]) < 1:
        raise ValueError(f"render.configurations must be >= 1, got {render['configurations']}")
    if render.get("rendering_set") is not None:
        if not isinstance(render["rendering_set"], str):
            raise ValueError(f"render.rendering_set must be 'packaged' or a file path, got {render['rendering_set']!r}")
        if meshes["source"] != "pascal3d":
            raise ValueError("render.rendering_set needs meshes.source = 'pascal3d'")
        if render["rendering_set"] != "packaged":
            render["rendering_set"] = str((base / render["rendering_set"]).resolve())
    for key, default in (("distance", (3.6, 4.4)), ("azimuth", (0.0, 360.0)), ("elevation", (0.0, 30.0)),
                         ("light_intensity", (0.4, 0.8)), ("ambient", (0.3, 0.6))):
        render[key] = _range(render, key, default)

    victims = raw.get("victims", {}).get("names")
    if not isinstance(victims, list) or not victims or not all(isinstance(v, str) for v in victims):
        raise ValueError(f"victims.names must be a non-empty list of victim names, got {victims!r}")
    weights = raw.get("victims", {}).get("weights", {})
    if not isinstance(weights, dict) or not all(isinstance(v, str) for v in weights.values()):
        raise ValueError(f"victims.weights must map victim names to weights files, got {weights!r}")
    weights = {k: str((base / v).resolve()) for k, v in weights.items()}
    caps = raw.get("victims", {}).get("configurations", {})
    if not isinstance(caps, dict) or not all(isinstance(v, int) and v >= 1 for v in caps.values()):
        raise ValueError(f"victims.configurations must map victim names to counts >= 1, got {caps!r}")
    render["victim_configurations"] = dict(caps)

    from meshadv.attacks.families import PERTURBATIONS, perturbations

    attack_raw, attack_key = _perturbations_key(dict(raw.get("attack", {})), "attack")
    attack = {"perturbations": perturbations(), "targets": "others", "benign_correct_only": True, "shape": {},
              "texture": {}, "protocols": {}, **attack_raw}
    for pname, proto in attack["protocols"].items():
        if not isinstance(proto, dict) or int(proto.get("configurations", 1)) < 1:
            raise ValueError(f"attack.protocols.{pname} must be a table with configurations >= 1, got {proto!r}")
    bad = [t for t in attack["perturbations"] if t not in PERTURBATIONS]
    if bad or not attack["perturbations"]:
        raise ValueError(f"{attack_key} must be a non-empty subset of {perturbations()}, "
                         f"got {attack['perturbations']!r}")
    if attack["targets"] != "others" and not isinstance(attack["targets"], list):
        raise ValueError(f"attack.targets must be 'others' or a list of classes, got {attack['targets']!r}")
    check_attack_values(attack, PERTURBATIONS)

    multiview_raw, _ = _perturbations_key(dict(raw.get("multiview", {})), "multiview")
    multiview = {"enabled": False, "view_counts": [5, 10, 15], "azimuth_ranges": [[45, 60], [35, 70], [15, 75]],
                 "grid": False, "eval_views": 20, "perturbations": perturbations(), "classes": None,
                 "targets": None, "victims": None, "elevation": 20.0, "distance": 4.0, **multiview_raw}
    if not multiview["grid"] and len(multiview["view_counts"]) != len(multiview["azimuth_ranges"]):
        raise ValueError("multiview.view_counts and multiview.azimuth_ranges must have the same length")
    for rng in multiview["azimuth_ranges"]:
        if len(rng) != 2 or rng[1] <= rng[0]:
            raise ValueError(f"multiview.azimuth_ranges entries must be [low, high] with low < high, got {rng!r}")

    runner = {"job": DEFAULT_JOB, "max_attempts": 2, "timeout": 0.0, "workers": 0, "threads_per_job": 0,
              "max_jobs_per_worker": 0, **raw.get("runner", {})}
    if int(runner["max_attempts"]) < 1:
        raise ValueError(f"runner.max_attempts must be >= 1, got {runner['max_attempts']}")
    return SweepConfig(name=name, seeds=tuple(int(s) for s in seeds), output=output, db=db, meshes=meshes,
                       render=render, victims=tuple(victims), victim_weights=weights, attack=attack,
                       multiview=multiview, runner=runner,
                       raw=raw, text=text)


def load_config(path: Union[str, Path]) -> SweepConfig:
    """Read a sweep file (``.toml``, ``.yaml`` or ``.yml``).

    Raises:
        FileNotFoundError: no such file. ValueError: unknown extension or invalid content.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file {path} does not exist")
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".toml":
        try:
            import tomllib
        except ImportError:  # pragma: no cover - Python < 3.11
            import tomli as tomllib  # type: ignore[no-redef]
        try:
            raw = tomllib.loads(text)
        except tomllib.TOMLDecodeError as err:
            raise ValueError(f"config {path}: invalid TOML: {err}") from err
    elif path.suffix in (".yaml", ".yml"):
        import yaml

        try:
            raw = yaml.safe_load(text)
        except yaml.YAMLError as err:
            raise ValueError(f"config {path}: invalid YAML: {err}") from err
    else:
        raise ValueError(f"config must be a .toml, .yaml or .yml file, got {path}")
    return parse_config(raw, base_dir=path.parent, text=text)


def _direction(azimuth: float, elevation: float) -> List[float]:
    return list(spherical_direction(azimuth, elevation))


def view_record(distance: float, azimuth: float, elevation: float, *, viewing_angle: float = 30.0,
                light_azimuth: Optional[float] = None, light_elevation: Optional[float] = None,
                light_intensity: float = 0.6, ambient: float = 0.5) -> Dict[str, Any]:
    """One view as a ``ViewSet`` record: a spherical camera and one white directional light plus ambient.

    The light direction points from the surface toward the light (the contract's convention); by default the light
    sits at the camera.
    """
    la = azimuth if light_azimuth is None else light_azimuth
    le = elevation if light_elevation is None else light_elevation
    return {
        "distance": round(float(distance), 6),
        "azimuth": round(float(azimuth), 6),
        "elevation": round(float(elevation), 6),
        "tilt": 0.0,
        "viewing_angle": float(viewing_angle),
        "light_directions": [[round(v, 6) for v in _direction(la, le)]],
        "light_colors": [[round(float(light_intensity), 6)] * 3],
        "ambient": [round(float(ambient), 6)] * 3,
    }


def rendering_configurations(render: Dict[str, Any]) -> List[Dict[str, Any]]:
    """Draw the ``render.configurations`` one-view records from ``render.config_seed`` (see module docstring)."""
    rng = random.Random(int(render["config_seed"]))
    out = []
    jitter = float(render["light_jitter"])
    for _ in range(int(render["configurations"])):
        az = rng.uniform(*render["azimuth"])
        el = rng.uniform(*render["elevation"])
        dist = rng.uniform(*render["distance"])
        out.append(view_record(dist, az, el, viewing_angle=float(render["viewing_angle"]),
                               light_azimuth=az + rng.uniform(-jitter, jitter),
                               light_elevation=min(89.0, max(-89.0, el + rng.uniform(-jitter, jitter))),
                               light_intensity=rng.uniform(*render["light_intensity"]),
                               ambient=rng.uniform(*render["ambient"])))
    return out


def _mesh_common(meshes: Dict[str, Any]) -> Dict[str, int]:
    return {"target_faces": int(meshes["target_faces"]), "max_faces": int(meshes["max_faces"])}


def rendering_set_instances(config: SweepConfig) -> List[Tuple[Dict[str, Any], int, Dict[str, Any]]]:
    """The ``(mesh entry, configuration index, view record)`` instances a rendering-set sweep attacks.

    Raises:
        FileNotFoundError: the rendering-set file does not exist. ValueError: not a rendering-set file, or a class
            with fewer kept renderings than ``render.configurations``.
    """
    from meshadv.datasets.rendering_set import load_rendering_set, packaged_rendering_set_path

    spec = config.render["rendering_set"]
    doc = load_rendering_set(packaged_rendering_set_path() if spec == "packaged" else spec)
    count = int(config.render["configurations"])
    models = config.meshes["models"]
    out = []
    for cls in config.meshes["classes"]:
        wanted = models.get(cls) if isinstance(models, dict) else models
        records = [r for r in doc["renderings"] if r["class"] == cls
                   and (not wanted or Path(r["mesh"]).stem in [str(m) for m in wanted])]
        if len(records) < count:
            raise ValueError(f"render.rendering_set {spec}: class {cls} has {len(records)} kept renderings"
                             f"{' of models ' + str(wanted) if wanted else ''}, fewer than render.configurations = "
                             f"{count}")
        for ci, rec in enumerate(records[:count]):
            if Path(rec["mesh"]).is_absolute():
                raise ValueError(f"render.rendering_set {spec}: mesh paths must be relative to the shared data "
                                 f"folder (build it with mesh_root), got {rec['mesh']}")
            mesh = {"source": "pascal3d", "path": rec["mesh"], "class": cls, **_mesh_common(config.meshes)}
            out.append((mesh, ci, rec["view"]))
    return out


def _mesh_entries(meshes: Dict[str, Any]) -> List[Dict[str, Any]]:
    common = _mesh_common(meshes)
    if meshes["source"] == "builtin":
        return [{"source": "builtin", "name": e["name"], "class": e["class"], **common} for e in meshes["builtin"]]
    if meshes["source"] == "files":
        return [{"source": "files", "path": e["path"], "class": e["class"], **common} for e in meshes["files"]]
    out = []
    for cls in meshes["classes"]:
        models = meshes["models"]
        if isinstance(models, dict):
            models = models.get(cls)
        models = models or [f"{i + 1:02d}" for i in range(int(meshes["models_per_class"]))]
        for model in models:
            out.append({"source": "pascal3d", "path": f"pascal3d/{cls}/{model}.ply", "class": cls, **common})
    return out


def _targets(spec: Any, source: str, classes: Sequence[str]) -> List[str]:
    if isinstance(spec, dict):  # one target per source class
        return [spec[source]] if source in spec and spec[source] != source else []
    if spec in (None, "others"):
        return [c for c in classes if c != source]
    return [c for c in spec if c != source]


def expand_jobs(config: SweepConfig) -> List[Dict[str, Any]]:
    """Expand a sweep into its job specs (deterministic order and content; the order is in the module docstring).

    Returns:
        JSON-able job dicts with keys ``kind`` (``"single"`` or ``"multiview"``), ``mesh``, ``source_class``,
        ``target``, ``victim``, ``perturbation``, ``views``, ``eval_views``, ``image_size``, ``attack``, ``seed``,
        ``config_index`` (single) or ``num_views`` / ``azimuth_range`` (multiview), ``benign_correct_only``, and
        ``victim_weights`` when the config gives weights for the victim.
    """
    meshes = _mesh_entries(config.meshes)
    classes = sorted({m["class"] for m in meshes}, key=lambda c: (PASCAL3D_CLASSES + (c,)).index(c))
    if config.render.get("rendering_set") is not None:
        instances = rendering_set_instances(config)
    else:
        configs = rendering_configurations(config.render)
        instances = [(mesh, ci, view) for mesh in meshes for ci, view in enumerate(configs)]
    size = int(config.render["image_size"])
    caps = config.render.get("victim_configurations", {})
    # the main setting, then every protocol on its subset: (name or None, config cap, victims, attack options)
    settings: List[Tuple[Optional[str], Dict[str, int], Sequence[str], Dict[str, Any]]] = [
        (None, caps, config.victims, config.attack)]
    for pname, proto in sorted(config.attack["protocols"].items()):
        settings.append((pname, {v: int(proto.get("configurations", 1)) for v in config.victims},
                         proto.get("victims") or config.victims, proto))
    jobs: List[Dict[str, Any]] = []
    for protocol, limit, victims, options in settings:
        setting: List[Dict[str, Any]] = []
        for mesh, ci, view in instances:
            for victim in (v for v in victims if ci < limit.get(v, ci + 1)):
                for perturbation in config.attack["perturbations"]:
                    for target in _targets(config.attack["targets"], mesh["class"], classes):
                        for seed in config.seeds:
                            job = {
                                "kind": "single", "mesh": mesh, "source_class": mesh["class"], "target": target,
                                "victim": victim, "perturbation": perturbation, "views": [view], "eval_views": [],
                                "image_size": size, "attack": dict(options.get(perturbation, {})), "seed": seed,
                                "config_index": ci,
                                "benign_correct_only": bool(config.attack["benign_correct_only"]),
                            }
                            if protocol is not None:
                                job["protocol"] = protocol
                            setting.append(job)
        # configuration-major, then victim; stable, so classes, types and targets keep their order (module docstring)
        jobs += sorted(setting, key=lambda j: (j["config_index"], list(victims).index(j["victim"])))
    jobs += _multiview_jobs(config, meshes, classes, size)
    for job in jobs:
        if job["victim"] in config.victim_weights:
            job["victim_weights"] = config.victim_weights[job["victim"]]
    return jobs


def _multiview_jobs(config: SweepConfig, meshes: Sequence[Dict[str, Any]], classes: Sequence[str],
                    size: int) -> List[Dict[str, Any]]:
    """The Table 2 jobs of ``config.multiview`` (none when disabled), cell-major: the first (view count, azimuth
    range) cell of every class, then the next cell, so a sweep stopped part-way has every class's first cells."""
    mv = config.multiview
    jobs: List[Dict[str, Any]] = []
    if mv["enabled"]:
        mv_classes = mv["classes"] or classes
        for mesh in meshes:
            if mesh["class"] not in mv_classes:
                continue
            for victim in mv["victims"] or config.victims:
                for perturbation in mv["perturbations"]:
                    targets = _targets(mv["targets"] or config.attack["targets"], mesh["class"], classes)
                    for target in targets:
                        if mv["grid"]:
                            cells = [(c, r) for c in mv["view_counts"] for r in mv["azimuth_ranges"]]
                        else:
                            cells = list(zip(mv["view_counts"], mv["azimuth_ranges"]))
                        for count, (lo, hi) in cells:
                            for seed in config.seeds:
                                rng = random.Random(f"{seed}:{count}:{lo}:{hi}")
                                views = [view_record(mv["distance"], rng.uniform(lo, hi), mv["elevation"],
                                                     viewing_angle=float(config.render["viewing_angle"]))
                                         for _ in range(int(count))]
                                unseen = [view_record(mv["distance"], rng.uniform(lo, hi), mv["elevation"],
                                                      viewing_angle=float(config.render["viewing_angle"]))
                                          for _ in range(int(mv["eval_views"]))]
                                jobs.append({
                                    "kind": "multiview", "mesh": mesh, "source_class": mesh["class"],
                                    "target": target, "victim": victim, "perturbation": perturbation, "views": views,
                                    "eval_views": unseen, "image_size": size,
                                    "attack": dict(config.attack.get(perturbation, {})), "seed": seed,
                                    "num_views": int(count), "azimuth_range": [float(lo), float(hi)],
                                    "benign_correct_only": False,
                                })
    # cells in the order each mesh's jobs list them; stable, so within a cell classes, victims, types and targets
    # keep their order
    cells = list(dict.fromkeys((j["num_views"], tuple(j["azimuth_range"])) for j in jobs))
    return sorted(jobs, key=lambda j: cells.index((j["num_views"], tuple(j["azimuth_range"]))))


def job_part(job: Dict[str, Any]) -> str:
    """The part of a sweep a job belongs to: ``"main"``, a protocol's name, or ``"multiview"`` (Table 2)."""
    if job["kind"] == "multiview":
        return "multiview"
    return str(job.get("protocol", "main"))


def select_parts(jobs: Sequence[Dict[str, Any]], parts: Sequence[str]) -> List[Dict[str, Any]]:
    """The jobs of ``jobs`` in the named parts (:func:`job_part`), in their order.

    Raises:
        ValueError: naming ``parts`` when one is not a part of this sweep (the message lists those that are).
    """
    known = list(dict.fromkeys(job_part(j) for j in jobs))
    unknown = [p for p in parts if p not in known]
    if unknown:
        raise ValueError(f"parts {unknown} are not in this sweep; its parts are {known}")
    return [j for j in jobs if job_part(j) in parts]
