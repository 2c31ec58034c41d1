"""The declarative sweep file (TOML or YAML): read it, check every section and fill in the defaults.

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
                  rendering_set = "packaged" | "path/to/set.json" (optional, see
                  :mod:`meshadv.experiments.job_expansion`)
    [victims]     names = ["efficientnet_lite0"] (required), weights = {densenet121 = "densenet121.pth"}
                  (weights files for victims that need them, relative to the file; the path is part of the job),
                  configurations = {efficientnet_lite2 = 4} (per-victim cap on render.configurations)
    [attack]      perturbations = ["shape", "texture"] (the old key ``types`` is read too), targets = "others" | [...],
                  benign_correct_only = true
    [attack.shape] / [attack.texture]   keyword arguments of ShapeAttack / TextureAttack (steps, lr, ...); a table
                  that names no ``method`` runs ``RECOMMENDED_METHOD`` ("ddn", written into its jobs), unless it sets
                  one of Adam's own options (``ADAM_ONLY_OPTIONS``: lr, lambda_perceptual, binary_search_steps,
                  smoothing), which keeps the paper's Adam as before ddn was the default (its jobs unchanged)
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
                  targets = [...] | {chair = "sofa", ...} (one target per class), victims = [...] (default all),
                  elevation = 20, distance = 4.0
    [runner]      job = "meshadv.experiments.jobs:run_attack_job", max_attempts = 2, timeout = 0, workers = 0,
                  threads_per_job = 0, max_jobs_per_worker = 0

Misspelt keys are refused by :mod:`meshadv.experiments.config_keys`; what the render keys mean is in
:mod:`meshadv.experiments.sweep_views`, how the sections become jobs in :mod:`meshadv.experiments.job_expansion`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

from meshadv.data import PASCAL3D_CLASSES
from meshadv.experiments.config_keys import check_attack_values, check_keys
from meshadv.experiments.retries import RETRY_PART

__all__ = ["ADAM_ONLY_OPTIONS", "DEFAULT_JOB", "PASCAL3D_CLASSES", "SweepConfig", "load_config", "parse_config",
           "raw_from_text", "stored_retry_stages"]


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
    render["victim_configurations"] = dict(caps)
    return SweepConfig(name=name, seeds=tuple(int(s) for s in seeds), output=output, db=db, meshes=meshes,
                       render=render, victims=tuple(victims), victim_weights=weights, attack=_attack_section(raw),
                       multiview=_multiview_section(raw), runner=_runner_section(raw),
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
    return meshes


def _render_section(raw: Dict[str, Any], mesh_source: str, base: Path) -> Dict[str, Any]:
    """``[render]`` with its defaults; every sampling range as a ``(low, high)`` pair."""
    render = {"image_size": 224, "configurations": 72, "config_seed": 0, "viewing_angle": 30.0,
              "light_jitter": 30.0, **raw.get("render", {})}
    if int(render["image_size"]) < 8:
        raise ValueError(f"render.image_size must be >= 8, got {render['image_size']}")
    if int(render["configurations"]) < 1:
        raise ValueError(f"render.configurations must be >= 1, got {render['configurations']}")
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
    from meshadv.attacks.families import PERTURBATIONS, perturbations

    attack_raw, attack_key = _perturbations_key(dict(raw.get("attack", {})), "attack")
    attack = {"perturbations": perturbations(), "targets": "others", "benign_correct_only": True, "shape": {},
              "texture": {}, "protocols": {}, "retry": {}, **attack_raw}
    for pname, proto in attack["protocols"].items():
        if not isinstance(proto, dict) or int(proto.get("configurations", 1)) < 1:
            raise ValueError(f"attack.protocols.{pname} must be a table with configurations >= 1, got {proto!r}")
        if pname == RETRY_PART:
            raise ValueError(f"attack.protocols.{pname}: the name {RETRY_PART!r} is the retry pass's "
                             "([attack.retry]); name the protocol otherwise")
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
    from meshadv.attacks.families import perturbations

    multiview_raw, _ = _perturbations_key(dict(raw.get("multiview", {})), "multiview")
    multiview = {"enabled": False, "view_counts": [5, 10, 15], "azimuth_ranges": [[45, 60], [35, 70], [15, 75]],
                 "grid": False, "eval_views": 20, "perturbations": perturbations(), "classes": None,
                 "targets": None, "victims": None, "elevation": 20.0, "distance": 4.0, **multiview_raw}
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
