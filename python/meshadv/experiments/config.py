"""The declarative sweep file (TOML or YAML): read it, check every section and key, fill in the defaults, and expand it
into its attack jobs.

A sweep file has these sections (every key optional unless noted; see ``configs/paper_small.toml``)::

    [experiment]  name, seeds = [0], output = "runs/<name>" (relative to the file), db = "<output>/results.db"
    [meshes]      source = "pascal3d" | "builtin" | "files"
                  classes = [...] (PASCAL3D+ classes; default all 7), models_per_class = 1 (models 01, 02, ...),
                  or models = ["01", ...] (every class) or models = {chair = ["03"], ...} (per class)
                  builtin = [{name = "sphere", class = "bottle"}], files = [{path = "x.ply", class = "chair"}]
                  target_faces = 0 (uniform resampling, 0 = keep), max_faces = 20000,
                  shading = "flat" | "smooth" (default: what each file asks for; shape jobs only: texture jobs draw
                  per-face colours flat). A file's texture and vertex colours are attacked as they are, as
                  ``meshadv attack`` takes them (:func:`meshadv.experiments.jobs.load_job_mesh`)
    [render]      image_size = 224, configurations = 72, config_seed = 0, distance = [3.6, 4.4],
                  azimuth = [0, 360], elevation = [0, 30], viewing_angle = 30,
                  light_intensity = [0.4, 0.8], ambient = [0.3, 0.6], light_jitter = 30,
                  rendering_set = "packaged" | "path/to/set.json" (optional, see
                  below)
    [victims]     names = ["efficientnet_lite0"] (required), weights = {densenet121 = "densenet121.pth"}
                  (weights files for victims that need them, relative to the file; the path is part of the job),
                  configurations = {efficientnet_lite2 = 4} (per-victim cap on render.configurations)
    [attack]      perturbations = ["shape", "texture"] (``types`` is read as the same key), targets = "others" | [...],
                  benign_correct_only = true
    [attack.shape] / [attack.texture]   keyword arguments of ShapeAttack / TextureAttack (steps, lr, ...); a table
                  that names no ``method`` runs ``RECOMMENDED_METHOD`` ("ddn", written into its jobs), unless it sets
                  one of Adam's own options (``ADAM_ONLY_OPTIONS``: lr, lambda_perceptual, binary_search_steps,
                  smoothing), which runs the paper's Adam
    [attack.protocols.<name>]   extra attack settings on a subset: configurations = 2 (first configurations per
                  class), victims = [...] (default all), shape = {...}, texture = {...}; their jobs carry
                  ``"protocol": "<name>"`` and the tables report them as separate rows
    [attack.retry]  shape = {steps = 1000}, texture = {...}: each main-setting attack of these types that fails runs
                  again from its benign mesh with these options over its own (:mod:`meshadv.experiments.retries`);
                  ``[[attack.retry]]`` tables are stages: a retry that fails runs again with the next stage's options
                  over its own (``attack["retry"]`` is the list of stages either way)
    [multiview]   enabled = false, view_counts = [5, 10, 15], azimuth_ranges = [[45, 60], [35, 70], [15, 75]],
                  grid = false (true: every view count with every range, the paper's 3 x 3 Table 2; false: pairs),
                  eval_views = 20, perturbations = ["shape", "texture"] (or ``types``), classes = [...],
                  targets = [...] | {chair = "sofa", ...} (each class's target, or list of targets),
                  victims = [...] (default all),
                  elevation = 20, distance = 4.0, benign_correct_only = false (true: attack only meshes whose
                  benign render is the source class on every attack view and every unseen view of the job)
    [runner]      job = "meshadv.experiments.jobs:run_attack_job", max_attempts = 2, timeout = 0, workers = 0,
                  threads_per_job = 0, max_jobs_per_worker = 0

Keys (:func:`check_keys`): every key not listed is refused at load, naming its full dotted path and suggesting the
closest valid key; the keys of ``[attack.shape]`` / ``[attack.texture]`` (and of protocols) are the keyword arguments
of the attack classes in the family registry, read from their signatures. What the render keys mean is in
:mod:`meshadv.experiments.sweep_views`.

Jobs (:func:`expand_jobs`): a parsed sweep expanded into its attack jobs, in the order a fresh sweep runs them, and
split into parts (:func:`select_parts`, :func:`select_where`).

Jobs (one attack each) are the product mesh x configuration x victim x perturbation type x target x seed (Table 1),
plus, when ``[multiview]`` is enabled, mesh x victim x type x target x (view count, azimuth range) x seed attacks
over several views, evaluated on unseen views (Table 2).

With ``render.rendering_set`` the configurations come from a PASCAL3D+ rendering set instead of being drawn
(:mod:`meshadv.datasets.rendering_set`; ``"packaged"`` = the set shipped with meshadv, built with EfficientNet-Lite0
and -Lite2): for each class in ``meshes.classes`` the first ``render.configurations`` kept renderings (restricted to
``meshes.models`` when given), each with its own mesh and view, exactly as the paper picks its 72 configurations per
class. The sampling keys of ``[render]`` are then unused; ``render.image_size`` still sets the attack's render size.

Order (the order a fresh sweep runs them in; job ids are hashes of the spec and do not depend on it): the main
setting, then each protocol, then the multi-view jobs. Within a setting the jobs are configuration-major, then
victim: configuration 0 of every class (mesh) for the first victim, then for the next victim, then configuration 1,
and so on (per class: perturbation types, then targets), so a sweep stopped part-way has covered every class about
equally instead of the first classes only. The multi-view jobs the same way: the first mesh of every class in the
first (view count, azimuth range) cell, then in the next cell, and so on, then the second mesh of every class in every
cell (with one mesh per class: cell-major). :func:`select_parts` keeps only some of these parts (``meshadv
sweep --only multiview``), to run one table first.

Example:
    >>> jobs = expand_jobs(load_config("configs/paper_small.toml"))  # doctest: +SKIP
"""

from __future__ import annotations

import inspect
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple, Union

from meshadv._validate import setting_flag, suggest
from meshadv.data import PASCAL3D_CLASSES
from meshadv.experiments.retries import RETRY_PART
from meshadv.experiments.sweep_views import multiview_views, rendering_configurations
from meshadv.render.setup import SETUP_OPTIONS

__all__ = [
    "ADAM_ONLY_OPTIONS", "DEFAULT_JOB", "SECTION_KEYS", "SweepConfig", "attack_option_keys", "check_attack_values",
    "check_keys", "expand_jobs", "job_part", "load_config", "parse_config", "parse_where", "raw_from_text",
    "rendering_set_instances", "select_parts", "select_where", "stored_retry_stages",
]


#: Allowed keys of each top-level section (``attack`` also takes one table per perturbation name).
SECTION_KEYS: Dict[str, frozenset] = {
    "experiment": frozenset({"name", "seeds", "output", "db"}),
    "meshes": frozenset(
        {"source", "classes", "models_per_class", "models", "builtin", "files", "target_faces", "max_faces",
         "shading"}
    ),
    "render": frozenset(
        {
            "image_size",
            "configurations",
            "config_seed",
            "distance",
            "azimuth",
            "elevation",
            "viewing_angle",
            "light_intensity",
            "ambient",
            "light_jitter",
            "rendering_set",
        }
    ),  # fmt: skip
    "victims": frozenset({"names", "weights", "configurations"}),
    "attack": frozenset({"perturbations", "types", "targets", "benign_correct_only", "protocols", "retry"}),
    "multiview": frozenset(
        {
            "enabled",
            "view_counts",
            "azimuth_ranges",
            "grid",
            "eval_views",
            "perturbations",
            "types",
            "classes",
            "targets",
            "victims",
            "elevation",
            "distance",
            "benign_correct_only",
        }
    ),  # fmt: skip
    "runner": frozenset({"job", "max_attempts", "timeout", "workers", "threads_per_job", "max_jobs_per_worker"}),
}
#: Allowed keys of an ``[attack.protocols.<name>]`` table besides the perturbation tables.
PROTOCOL_KEYS = frozenset({"configurations", "victims"})
#: Attack options the job runner reads itself (not passed to the attack class): the criterion's margin and the
#: render setup's options (``antialias``, ...).
JOB_ATTACK_OPTIONS = frozenset({"required_margin", *SETUP_OPTIONS})


def attack_option_keys(attack_class: type) -> List[str]:
    """The keyword arguments accepted by ``attack_class`` and its bases (``**kwargs`` forwarded up the MRO)."""
    keys = set()
    for klass in attack_class.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        for param in inspect.signature(init).parameters.values():
            if param.name != "self" and param.kind in (param.KEYWORD_ONLY, param.POSITIONAL_OR_KEYWORD):
                keys.add(param.name)
    return sorted(keys | JOB_ATTACK_OPTIONS)


def _refuse(path: str, key: str, allowed: Iterable[str]) -> None:
    allowed = sorted(allowed)
    hint = suggest(key, allowed)
    if not path:
        extra = f"; did you mean [{hint}]?" if hint else ""
        raise ValueError(f"unknown config section [{key}]{extra} (valid sections: {', '.join(allowed)})")
    extra = f"; did you mean {path + '.' + hint!r}?" if hint else ""
    raise ValueError(f"unknown config key {path + '.' + key!r}{extra} (valid keys here: {', '.join(allowed)})")


def _check_table(value: Any, path: str, allowed: Iterable[str]) -> None:
    if not isinstance(value, Mapping):
        raise ValueError(f"config section [{path}] must be a table, got {type(value).__name__}")
    allowed = set(allowed)
    for key in value:
        if key not in allowed:
            _refuse(path, str(key), allowed)


def _check_attack_options(table: Mapping[str, Any], path: str, families: Mapping[str, type]) -> None:
    for perturbation, cls in families.items():
        if perturbation in table:
            _check_table(table[perturbation], f"{path}.{perturbation}", attack_option_keys(cls))


def check_keys(raw: Mapping[str, Any], families: Mapping[str, type]) -> None:
    """Refuse any key of a parsed sweep file that the loader does not read.

    Args:
        raw: the parsed TOML/YAML mapping.
        families: perturbation name -> attack class (``meshadv.attacks.families.PERTURBATIONS``).

    Raises:
        ValueError: the first unknown section or key, with its dotted path and the closest valid key.
    """
    _check_table(raw, "", SECTION_KEYS)
    for section, allowed in SECTION_KEYS.items():
        if section not in raw:
            continue
        extra = set(families) if section == "attack" else set()
        _check_table(raw[section], section, allowed | extra)
    attack = raw.get("attack", {})
    _check_attack_options(attack, "attack", families)
    protocols = attack.get("protocols", {})
    if not isinstance(protocols, Mapping):
        raise ValueError(f"attack.protocols must be a table of named protocols, got {type(protocols).__name__}")
    for name, proto in protocols.items():
        _check_table(proto, f"attack.protocols.{name}", PROTOCOL_KEYS | set(families))
        _check_attack_options(proto, f"attack.protocols.{name}", families)
    for path, stage in _retry_stage_tables(attack):
        _check_table(stage, path, families)
        _check_attack_options(stage, path, families)


def _retry_stage_tables(attack: Mapping[str, Any]) -> List[Tuple[str, Any]]:
    """``(path, table)`` of each retry stage: ``[attack.retry]`` is one, ``[[attack.retry]]`` a list of them."""
    retry = attack.get("retry", {})
    if isinstance(retry, list):
        if len(retry) == 1:
            return [("attack.retry", retry[0])]
        return [(f"attack.retry[{i}]", stage) for i, stage in enumerate(retry)]
    return [("attack.retry", retry)] if retry else []


def check_attack_values(attack: Mapping[str, Any], families: Mapping[str, type]) -> None:
    """Build every attack the sweep will build, so bad option values (``steps = "10"``) fail at load.

    Args:
        attack: the ``[attack]`` table after defaults (``perturbations``, one options table per perturbation,
            ``protocols`` and ``retry``).
        families: perturbation name -> attack class.

    Raises:
        ValueError: the attack class refused an option; the message names the table.
    """
    tables = [("attack", attack)] + [(f"attack.protocols.{n}", p) for n, p in attack.get("protocols", {}).items()]
    # a retry runs with its stage's options over its parent's: the main setting's and the earlier stages'
    options = {p: dict(attack.get(p, {})) for p in families}
    for path, stage in _retry_stage_tables(attack):
        options = {p: {**o, **dict(stage.get(p, {}))} for p, o in options.items()}
        tables.append((path, {p: options[p] for p in stage}))
    for path, table in tables:
        for perturbation in attack.get("perturbations", []):
            options = {k: v for k, v in dict(table.get(perturbation, {})).items() if k not in JOB_ATTACK_OPTIONS}
            try:
                families[perturbation](**options).config()  # config() builds the update rule: method_options
            except (TypeError, ValueError) as exc:
                raise ValueError(f"[{path}.{perturbation}]: {exc}") from None


#: Options of an attack table that only the paper's update rule (``method="adam"``) has: a table that sets one and
#: names no method keeps Adam (:func:`_with_method`).
ADAM_ONLY_OPTIONS = frozenset({"lr", "lambda_perceptual", "binary_search_steps", "smoothing"})

#: The attack job function used unless ``[runner] job`` says otherwise.
DEFAULT_JOB = "meshadv.experiments.jobs:run_attack_job"


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


def load_config(path: Union[str, Path]) -> SweepConfig:
    """Read a sweep file (``.toml``, ``.yaml`` or ``.yml``).

    Raises:
        FileNotFoundError: no such file. ValueError: a folder, an unknown extension or invalid content.
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"config file {path} is a folder; give a sweep file (.toml, .yaml or .yml)")
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
    from meshadv.attacks.families import PERTURBATIONS

    check_keys(raw, PERTURBATIONS)  # misspelt keys fail here, with the closest valid key
    base = Path(base_dir)
    name, seeds, output, db = _experiment_section(raw, base)
    meshes = _meshes_section(raw, base)
    render = _render_section(raw, meshes["source"], base)
    victims, weights, caps = _victims_section(raw, base)
    attack, multiview = _attack_section(raw), _multiview_section(raw)
    _check_shading(meshes, attack, multiview)
    render["victim_configurations"] = dict(caps)
    return SweepConfig(name=name, seeds=tuple(int(s) for s in seeds), output=output, db=db, meshes=meshes,
                       render=render, victims=tuple(victims), victim_weights=weights, attack=attack,
                       multiview=multiview, runner=_runner_section(raw),
                       raw=raw, text=text)


def _experiment_section(raw: Dict[str, Any], base: Path) -> Tuple[str, List[int], Path, Path]:
    """``[experiment]``: the name, the seeds, the output folder and the database path."""
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
    return name, seeds, output, db


def _meshes_section(raw: Dict[str, Any], base: Path) -> Dict[str, Any]:
    """``[meshes]`` with its defaults; file paths resolved against ``base``."""
    meshes = {"source": "pascal3d", "classes": list(PASCAL3D_CLASSES), "models_per_class": 1, "models": None,
              "builtin": [], "files": [], "target_faces": 0, "max_faces": 20000, **raw.get("meshes", {})}
    if meshes["source"] not in ("pascal3d", "builtin", "files"):
        raise ValueError(f"meshes.source must be pascal3d, builtin or files, got {meshes['source']!r}")
    if not isinstance(meshes["classes"], list) or not all(isinstance(c, str) for c in meshes["classes"]):
        raise ValueError(f"meshes.classes must be a list of class names, got {meshes['classes']!r}")
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
    if meshes.get("shading") not in (None, "flat", "smooth"):
        raise ValueError(f"meshes.shading must be flat or smooth, got {meshes['shading']!r}")
    return meshes


def _check_shading(meshes: Dict[str, Any], attack: Dict[str, Any], multiview: Dict[str, Any]) -> None:
    """``meshes.shading = "smooth"`` with no per-face colour (``texture``) jobs, which draw flat.

    Raises:
        ValueError: naming ``meshes.shading`` and the section that runs ``texture``.
    """
    if meshes.get("shading") != "smooth":
        return
    for section, table in (("attack", attack), ("multiview", multiview)):
        if "texture" in table["perturbations"] and (section == "attack" or table["enabled"]):
            raise ValueError(f"meshes.shading = 'smooth' needs {section}.perturbations without 'texture': the "
                             "per-face colour attack draws its faces flat (run it from a sweep file without shading)")


def _render_section(raw: Dict[str, Any], mesh_source: str, base: Path) -> Dict[str, Any]:
    """``[render]`` with its defaults; every sampling range as a ``(low, high)`` pair."""
    render = {"image_size": 224, "configurations": 72, "config_seed": 0, "viewing_angle": 30.0,
              "light_jitter": 30.0, **raw.get("render", {})}
    for key, low in (("image_size", 8), ("configurations", 1), ("config_seed", 0)):
        value = render[key]
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(f"render.{key} must be an integer >= {low}, got {value!r}")
    if render.get("rendering_set") is not None:
        if not isinstance(render["rendering_set"], str):
            raise ValueError(f"render.rendering_set must be 'packaged' or a file path, got {render['rendering_set']!r}")
        if mesh_source != "pascal3d":
            raise ValueError("render.rendering_set needs meshes.source = 'pascal3d'")
        if render["rendering_set"] != "packaged":
            render["rendering_set"] = str((base / render["rendering_set"]).resolve())
    for key, default in (("distance", (3.6, 4.4)), ("azimuth", (0.0, 360.0)), ("elevation", (0.0, 30.0)),
                         ("light_intensity", (0.4, 0.8)), ("ambient", (0.3, 0.6))):
        render[key] = _range(render, key, default)
    return render


def _range(section: Dict[str, Any], key: str, default: Sequence[float]) -> Tuple[float, float]:
    """``render.<key>`` (a number or a ``[low, high]`` pair, default ``default``) as a ``(low, high)`` pair."""
    value = section.get(key, default)
    if isinstance(value, (int, float)):
        return float(value), float(value)
    if not isinstance(value, (list, tuple)) or len(value) != 2 or not all(isinstance(v, (int, float)) for v in value):
        raise ValueError(f"render.{key} must be a number or a [low, high] pair, got {value!r}")
    low, high = float(value[0]), float(value[1])
    if high < low:
        raise ValueError(f"render.{key} must have low <= high, got {value!r}")
    return low, high


def _victims_section(raw: Dict[str, Any], base: Path) -> Tuple[List[str], Dict[str, str], Dict[str, int]]:
    """``[victims]``: the names, the weights files (resolved against ``base``) and the per-victim caps."""
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
    return victims, weights, caps


def _attack_section(raw: Dict[str, Any]) -> Dict[str, Any]:
    """``[attack]`` with its defaults, its protocols and its per-family options checked."""
    from meshadv.attacks.families import MESH_PERTURBATIONS, PERTURBATIONS, perturbations

    attack_raw, attack_key = _perturbations_key(dict(raw.get("attack", {})), "attack")
    attack = {"perturbations": list(MESH_PERTURBATIONS), "targets": "others", "benign_correct_only": True, "shape": {},
              "texture": {}, "protocols": {}, "retry": {}, **attack_raw}
    for pname, proto in attack["protocols"].items():
        if not isinstance(proto, dict) or int(proto.get("configurations", 1)) < 1:
            raise ValueError(f"attack.protocols.{pname} must be a table with configurations >= 1, got {proto!r}")
        if pname == RETRY_PART:
            raise ValueError(f"attack.protocols.{pname}: the name {RETRY_PART!r} is the retry pass's "
                             "([attack.retry]); name the protocol otherwise")
    setting_flag("attack.benign_correct_only", attack["benign_correct_only"])
    attack["retry"] = _retry_stages(attack["retry"])
    for table in [attack, *attack["protocols"].values()]:
        for perturbation in PERTURBATIONS:
            table[perturbation] = _with_method(table.get(perturbation, {}))
    bad = [t for t in attack["perturbations"] if t not in PERTURBATIONS]
    if bad or not attack["perturbations"]:
        raise ValueError(f"{attack_key} must be a non-empty subset of {perturbations()}, "
                         f"got {attack['perturbations']!r}")
    if attack["targets"] != "others" and not isinstance(attack["targets"], list):
        raise ValueError(f"attack.targets must be 'others' or a list of classes, got {attack['targets']!r}")
    check_attack_values(attack, PERTURBATIONS)
    return attack


def _with_method(options: Any) -> Any:
    """A perturbation's attack table with ``method`` set to :data:`~meshadv.attacks.update.RECOMMENDED_METHOD` where
    it names none and sets none of :data:`ADAM_ONLY_OPTIONS` (such a table is the paper's Adam, the attacks' own
    default, and is returned unchanged so that its jobs keep their ids); a table that is not a mapping is returned
    as it is, for :func:`check_attack_values` to refuse."""
    from meshadv.attacks.update import RECOMMENDED_METHOD

    if not isinstance(options, dict) or "method" in options or ADAM_ONLY_OPTIONS & set(options):
        return options
    return {"method": RECOMMENDED_METHOD, **options}


def _retry_stages(retry: Any) -> List[Dict[str, Any]]:
    """``attack.retry`` as the list of stages: ``[attack.retry]`` is one stage, ``[[attack.retry]]`` stages in order."""
    if isinstance(retry, dict):
        return [retry] if retry else []
    return list(retry or [])


def raw_from_text(text: str) -> Dict[str, Any]:
    """The tables of a sweep file's text: TOML, else YAML (a stored config text does not say which).

    Raises:
        ValueError: ``text`` is neither, or not a mapping.
    """
    import tomllib
    import yaml

    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        try:
            raw = yaml.safe_load(text)
        except yaml.YAMLError as err:
            raise ValueError(f"config text is neither TOML nor YAML: {err}") from err
    if not isinstance(raw, dict):
        raise ValueError(f"a sweep config must be a mapping, got {type(raw).__name__}")
    return raw


def stored_retry_stages(text: Optional[str]) -> Optional[List[Dict[str, Any]]]:
    """The retry stages (``attack["retry"]``) of the config text a sweep stored in its database (meta
    ``config_text``: the text of its latest run); ``None`` when there is none or it does not parse."""
    if not text:
        return None
    try:
        attack = raw_from_text(text).get("attack") or {}
        return _retry_stages(attack.get("retry") if isinstance(attack, dict) else None)
    except (ValueError, TypeError):
        return None


def _multiview_section(raw: Dict[str, Any]) -> Dict[str, Any]:
    """``[multiview]`` with its defaults (Table 2's view counts and azimuth ranges)."""
    from meshadv.attacks.families import MESH_PERTURBATIONS

    multiview_raw, _ = _perturbations_key(dict(raw.get("multiview", {})), "multiview")
    multiview = {"enabled": False, "view_counts": [5, 10, 15], "azimuth_ranges": [[45, 60], [35, 70], [15, 75]],
                 "grid": False, "eval_views": 20, "perturbations": list(MESH_PERTURBATIONS), "classes": None,
                 "targets": None, "victims": None, "elevation": 20.0, "distance": 4.0, "benign_correct_only": False,
                 **multiview_raw}
    setting_flag("multiview.benign_correct_only", multiview["benign_correct_only"])
    _check_multiview_targets(multiview["targets"])
    if not multiview["grid"] and len(multiview["view_counts"]) != len(multiview["azimuth_ranges"]):
        raise ValueError("multiview.view_counts and multiview.azimuth_ranges must have the same length")
    for rng in multiview["azimuth_ranges"]:
        if len(rng) != 2 or rng[1] <= rng[0]:
            raise ValueError(f"multiview.azimuth_ranges entries must be [low, high] with low < high, got {rng!r}")
    return multiview


def _runner_section(raw: Dict[str, Any]) -> Dict[str, Any]:
    """``[runner]`` with its defaults."""
    runner = {"job": DEFAULT_JOB, "max_attempts": 2, "timeout": 0.0, "workers": 0, "threads_per_job": 0,
              "max_jobs_per_worker": 0, **raw.get("runner", {})}
    if int(runner["max_attempts"]) < 1:
        raise ValueError(f"runner.max_attempts must be >= 1, got {runner['max_attempts']}")
    return runner


def _perturbations_key(table: Dict[str, Any], section: str) -> Tuple[Dict[str, Any], str]:
    """``table`` with the perturbation list under its one name, and the key the user wrote (for messages).

    ``types`` is read as the same key; giving both is an error.
    """
    if "types" not in table:
        return table, f"{section}.perturbations"
    if "perturbations" in table:
        raise ValueError(f"{section}.types is the old name of {section}.perturbations; give only one of them")
    table["perturbations"] = table.pop("types")
    return table, f"{section}.types"


#: A configuration a sweep attacks: ``(mesh entry, configuration index, view record)``.
Instance = Tuple[Dict[str, Any], int, Dict[str, Any]]
#: One setting of a sweep: ``(protocol name or None, per-victim configuration cap, victims, attack options)``.
Setting = Tuple[Optional[str], Dict[str, int], Sequence[str], Dict[str, Any]]


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
    jobs: List[Dict[str, Any]] = []
    for setting in _settings(config):
        jobs += _single_view_jobs(config, setting, instances, classes, size)
    jobs += _multiview_jobs(config, meshes, classes, size)
    for job in jobs:
        if job["victim"] in config.victim_weights:
            job["victim_weights"] = config.victim_weights[job["victim"]]
    return jobs


def job_part(job: Dict[str, Any]) -> str:
    """The part of a sweep a job belongs to: ``"main"``, a protocol's name, or ``"multiview"`` (Table 2)."""
    if job["kind"] == "multiview":
        return "multiview"
    return str(job.get("protocol", "main"))


def select_parts(jobs: Sequence[Dict[str, Any]], parts: Sequence[str], *,
                 also_known: Sequence[str] = ()) -> List[Dict[str, Any]]:
    """The jobs of ``jobs`` in the named parts (:func:`job_part`), in their order.

    Args:
        jobs: job specs. parts: the parts to keep.
        also_known: parts of the sweep that may have no job yet (``"retry"``: retries exist once attacks fail).

    Raises:
        ValueError: naming ``parts`` when one is not a part of this sweep (the message lists those that are).
    """
    known = list(dict.fromkeys([*(job_part(j) for j in jobs), *also_known]))
    unknown = [p for p in parts if p not in known]
    if unknown:
        raise ValueError(f"parts {unknown} are not in this sweep; its parts are {known}")
    return [j for j in jobs if job_part(j) in parts]


def parse_where(conditions: Sequence[str]) -> List[Tuple[str, str]]:
    """``KEY=VALUE`` conditions on job specs as ``(key, value)`` pairs (see :func:`select_where`).

    Raises:
        ValueError: a condition without ``=`` or with an empty key.
    """
    pairs = []
    for text in conditions:
        key, sep, value = text.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"expected KEY=VALUE (e.g. source_class=sofa, target=bicycle), got {text!r}")
        pairs.append((key.strip(), value.strip()))
    return pairs


def _spec_value(job: Dict[str, Any], key: str) -> Any:
    """The value of a dotted ``key`` (``mesh.class``) in ``job``, or ``None`` when it has no such entry."""
    value: Any = job
    for part in key.split("."):
        if not isinstance(value, dict) or part not in value:
            return None
        value = value[part]
    return value


def select_where(jobs: Sequence[Dict[str, Any]], conditions: Sequence[Tuple[str, str]]) -> List[Dict[str, Any]]:
    """The jobs of ``jobs`` whose spec has every ``(key, value)`` of ``conditions``, in their order.

    A key is a spec entry, dotted for nested ones (``source_class``, ``target``, ``perturbation``, ``config_index``,
    ``victim``, ``mesh.class``, ``attack.method``); a value matches the entry's text (``config_index=0``), and
    ``protocol=main`` matches the jobs of the main setting, which have no protocol entry. A job is kept when it
    matches all conditions.

    Raises:
        ValueError: naming a key that no job of ``jobs`` has (the message lists the top-level keys).
    """

    def text(job: Dict[str, Any], key: str) -> Optional[str]:
        value = _spec_value(job, key)
        if value is None and key == "protocol":
            return "main" if job["kind"] == "single" else None
        return None if value is None else str(value)

    for key, _ in conditions:
        if jobs and all(text(j, key) is None for j in jobs):
            known = sorted({k for j in jobs for k in j})
            raise ValueError(f"no job of this sweep has {key!r}; its jobs' keys are {known} (dotted for nested "
                             "ones, e.g. mesh.class)")
    return [j for j in jobs if all(text(j, key) == value for key, value in conditions)]


def rendering_set_instances(config: SweepConfig) -> List[Instance]:
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


def _mesh_common(meshes: Dict[str, Any]) -> Dict[str, Any]:
    """The resampling keys every mesh entry carries, and ``shading`` when the file sets one (absent, the jobs and
    their ids are those of a sweep file without it)."""
    common: Dict[str, Any] = {"target_faces": int(meshes["target_faces"]), "max_faces": int(meshes["max_faces"])}
    if meshes.get("shading") is not None:
        common["shading"] = meshes["shading"]
    return common


def _mesh_entries(meshes: Dict[str, Any]) -> List[Dict[str, Any]]:
    """The job's ``mesh`` entries of ``[meshes]`` (PASCAL3D+ models ``01``, ``02``, ... unless named)."""
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


def _check_multiview_targets(targets: Any) -> None:
    """Refuse a ``multiview.targets`` that is none of: absent, a list of classes, a table of each class's target
    or non-empty list of targets."""
    def names(value: Any) -> bool:
        return isinstance(value, list) and bool(value) and all(isinstance(t, str) for t in value)

    if targets is None or names(targets):
        return
    if isinstance(targets, dict) and all(isinstance(v, str) or names(v) for v in targets.values()):
        return
    raise ValueError("multiview.targets must be a list of classes or a table of each class's target (a class or a "
                     f"non-empty list of classes), got {targets!r}")


def _targets(spec: Any, source: str, classes: Sequence[str]) -> List[str]:
    """The target classes of source class ``source``: ``"others"``/None (every other class), a list, or a
    ``{source: target or [targets]}`` table."""
    if isinstance(spec, dict):  # the targets of each source class
        chosen = spec.get(source, [])
        return [c for c in ([chosen] if isinstance(chosen, str) else chosen) if c != source]
    if spec in (None, "others"):
        return [c for c in classes if c != source]
    return [c for c in spec if c != source]


def _settings(config: SweepConfig) -> List[Setting]:
    """The main setting, then every protocol on its subset (sorted by name)."""
    caps = config.render.get("victim_configurations", {})
    settings: List[Setting] = [(None, caps, config.victims, config.attack)]
    for pname, proto in sorted(config.attack["protocols"].items()):
        settings.append((pname, {v: int(proto.get("configurations", 1)) for v in config.victims},
                         proto.get("victims") or config.victims, proto))
    return settings


def _single_view_jobs(config: SweepConfig, setting: Setting, instances: Sequence[Instance], classes: Sequence[str],
                      size: int) -> List[Dict[str, Any]]:
    """The one-view jobs of one setting, configuration-major, then victim (module docstring)."""
    protocol, limit, victims, options = setting
    jobs: List[Dict[str, Any]] = []
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
                        jobs.append(job)
    # stable, so classes, types and targets keep their order within a (configuration, victim)
    return sorted(jobs, key=lambda j: (j["config_index"], list(victims).index(j["victim"])))


def _multiview_jobs(config: SweepConfig, meshes: Sequence[Dict[str, Any]], classes: Sequence[str],
                    size: int) -> List[Dict[str, Any]]:
    """The Table 2 jobs of ``config.multiview`` (none when disabled), mesh-rank-major, then cell-major: the first
    mesh of every class in the first (view count, azimuth range) cell, then in the next cell, ..., then the second
    mesh of every class in every cell, so a sweep stopped part-way has every class in every cell."""
    mv = config.multiview
    if not mv["enabled"]:
        return []
    if mv["grid"]:
        cells = [(c, r) for c in mv["view_counts"] for r in mv["azimuth_ranges"]]
    else:
        cells = list(zip(mv["view_counts"], mv["azimuth_ranges"]))
    mv_classes = mv["classes"] or classes
    ranked: List[Tuple[int, Dict[str, Any]]] = []  # (the rank of the job's mesh among its class's meshes, job)
    seen_per_class: Dict[str, int] = {}
    for mesh in meshes:
        if mesh["class"] not in mv_classes:
            continue
        mesh_rank = seen_per_class.get(mesh["class"], 0)
        seen_per_class[mesh["class"]] = mesh_rank + 1
        for victim in mv["victims"] or config.victims:
            for perturbation in mv["perturbations"]:
                for target in _targets(mv["targets"] or config.attack["targets"], mesh["class"], classes):
                    for count, (lo, hi) in cells:
                        for seed in config.seeds:
                            views, unseen = multiview_views(mv, float(config.render["viewing_angle"]), seed,
                                                            count, (lo, hi))
                            ranked.append((mesh_rank, {
                                "kind": "multiview", "mesh": mesh, "source_class": mesh["class"],
                                "target": target, "victim": victim, "perturbation": perturbation, "views": views,
                                "eval_views": unseen, "image_size": size,
                                "attack": dict(config.attack.get(perturbation, {})), "seed": seed,
                                "num_views": int(count), "azimuth_range": [float(lo), float(hi)],
                                "benign_correct_only": mv["benign_correct_only"],
                            }))
    # cells in the order each mesh's jobs list them; stable, so within a cell classes, victims, types and targets
    # keep their order
    order = {cell: i for i, cell in enumerate(dict.fromkeys((j["num_views"], tuple(j["azimuth_range"]))
                                                            for _, j in ranked))}
    ranked.sort(key=lambda rj: (rj[0], order[(rj[1]["num_views"], tuple(rj[1]["azimuth_range"]))]))
    return [job for _, job in ranked]
