"""A parsed sweep expanded into its attack jobs, in the order a fresh sweep runs them, and split into parts.

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
equally instead of the first classes only. The multi-view jobs are cell-major the same way: the first (view count,
azimuth range) cell of every class, then the next. :func:`select_parts` keeps only some of these parts (``meshadv
sweep --only multiview``), to run one table first.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple

from meshadv.experiments.sweep_file import PASCAL3D_CLASSES, SweepConfig
from meshadv.experiments.sweep_views import multiview_views, rendering_configurations

__all__ = ["expand_jobs", "job_part", "parse_where", "rendering_set_instances", "select_parts", "select_where"]

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


def _mesh_common(meshes: Dict[str, Any]) -> Dict[str, int]:
    """The resampling keys every mesh entry carries."""
    return {"target_faces": int(meshes["target_faces"]), "max_faces": int(meshes["max_faces"])}


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


def _targets(spec: Any, source: str, classes: Sequence[str]) -> List[str]:
    """The target classes of source class ``source``: ``"others"``/None (every other class), a list, or a
    ``{source: target}`` table."""
    if isinstance(spec, dict):  # one target per source class
        return [spec[source]] if source in spec and spec[source] != source else []
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
    """The Table 2 jobs of ``config.multiview`` (none when disabled), cell-major: the first (view count, azimuth
    range) cell of every class, then the next cell, so a sweep stopped part-way has every class's first cells."""
    mv = config.multiview
    if not mv["enabled"]:
        return []
    if mv["grid"]:
        cells = [(c, r) for c in mv["view_counts"] for r in mv["azimuth_ranges"]]
    else:
        cells = list(zip(mv["view_counts"], mv["azimuth_ranges"]))
    mv_classes = mv["classes"] or classes
    jobs: List[Dict[str, Any]] = []
    for mesh in meshes:
        if mesh["class"] not in mv_classes:
            continue
        for victim in mv["victims"] or config.victims:
            for perturbation in mv["perturbations"]:
                for target in _targets(mv["targets"] or config.attack["targets"], mesh["class"], classes):
                    for count, (lo, hi) in cells:
                        for seed in config.seeds:
                            views, unseen = multiview_views(mv, float(config.render["viewing_angle"]), seed,
                                                            count, (lo, hi))
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
    order = list(dict.fromkeys((j["num_views"], tuple(j["azimuth_range"])) for j in jobs))
    return sorted(jobs, key=lambda j: order.index((j["num_views"], tuple(j["azimuth_range"]))))
