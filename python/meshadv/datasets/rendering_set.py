"""The "PASCAL3D+ renderings" set: random views of each class's meshes that every chosen victim gets right.

For each class, candidates ``0, 1, 2, ...`` are drawn deterministically: candidate ``i`` uses mesh ``i mod M`` (the
class's meshes in the given order) and a NumPy generator seeded with ``SeedSequence([seed, class_index, i])``, which
samples, in this order:

- azimuth ``U[0, 360)``, elevation ``U[0, 90]`` degrees (configurable);
- a distance that frames the object: the mesh (normalised into ``[-1, 1]``) is placed so that its widest projected
  half-extent is a fraction ``fill ~ U[fill_range]`` of the image (exact perspective framing,
  :func:`meshadv.render.views.frame_distance`);
- one directional light within ``light_max_angle`` (60 degrees) of the view direction (uniform on that spherical cap
  around the object-to-camera direction), grey intensity ``U[light_range]``, plus grey ambient ``U[ambient_range]``.

The mesh is rendered untextured (its file colours, light grey by default) on a constant background. A candidate is
kept when **every** victim classifies it as its class (classifiers: top-1 ImageNet label in the class's group,
:data:`~meshadv.victims.labels.PASCAL3D_TO_IMAGENET`; detectors: a detection of the class's COCO label with score
``>= detector_threshold``). The set holds the first ``per_class`` kept candidates of each class in candidate order,
so the result depends only on the configuration and the seed, never on batching or on interruptions: the file is
rewritten atomically after every batch and a run with the same configuration resumes from it.

Defaults and why: a white background (as NMR/MeshAdv renderings; ImageNet photos of furniture, bottles and aircraft
are often product shots on white, and white keeps the silhouette, the strongest cue for an untextured shape, at full
contrast), the mesh's own colours (light grey 0.7 for the uncoloured PASCAL3D+ files), ambient ``U[0.45, 0.65]`` plus
a light ``U[0.35, 0.55]`` near the view direction so that the faces the camera sees are lit without saturating and
shading shows the 3-D shape, and ``fill`` ``U[0.7, 0.95]`` so the object fills most of the frame as in ImageNet
photos. The packaged set (``meshadv/datasets/data/pascal3d_renderings_v1.json``, :func:`packaged_rendering_set_path`;
made by ``meshadv rendering-set build -o ...`` with these defaults, seed 0, EfficientNet-Lite0 and -Lite2) kept 72 per
class after 175 (aeroplane), 663 (bicycle), 1335 (boat), 263 (bottle), 205 (chair), 1119 (dining table) and 505 (sofa)
candidates: both victims right on 41%, 11%, 5%, 27%, 35%, 6% and 14%. Low elevations pass most (a table seen from
above is an "envelope"), so the kept set leans toward them (median kept elevation 11 degrees for dining tables, 19-40
for the other classes, against 45 sampled), as any set filtered by the victims must. A 24-candidate pilot had measured
white 16% vs light grey (0.85) 15%, mid grey 5% and black 11% (mean pass rate over classes), so white stays. The pass
rates per class and victim of a build are stored in the file (``classes[c]["pass_rate"]``) and printed by
:func:`pass_rate_table`; ``docs/results/rendering_set`` shows them with a contact sheet.

File format (JSON, ``format = "meshadv-rendering-set"``, ``version = 1``)::

    {"format", "version", "complete": bool, "config": {...},
     "classes": {class: {"next_candidate", "tried", "kept", "passed": {victim: n, "all": n},
                         "pass_rate": {victim: p, "all": p}, "exhausted": bool}},
     "renderings": [{"class", "mesh", "mesh_index", "candidate", "seed", "view": ViewSet record,
                     "predictions": {victim: label}}]}

Example:
    >>> doc = build_rendering_set({"chair": ["01.ply"]}, ["efficientnet_lite0"], 4, 0, "set.json")  # doctest: +SKIP
    >>> print(pass_rate_table(doc))  # doctest: +SKIP
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Union

import numpy as np
import torch

from meshadv.render.views import frame_distance
from meshadv.util.atomic import write_json_atomic
from meshadv.util.json_file import read_json
from meshadv.util.markdown import markdown_table
from meshadv.util.spherical import spherical_direction
from meshadv.victims.base import ClassifierVictim, DetectorVictim, Victim
from meshadv.victims.labels import PASCAL3D_CLASSES, PASCAL3D_TO_COCO, PASCAL3D_TO_IMAGENET, imagenet_class_names

__all__ = [
    "FORMAT",
    "VERSION",
    "RenderingSetConfig",
    "build_rendering_set",
    "candidate_seed",
    "load_rendering_set",
    "pascal3d_mesh_paths",
    "rendering_mesh_path",
    "pass_rate_table",
    "record_views",
    "render_records",
    "sample_view",
    "sampling_config",
]

FORMAT = "meshadv-rendering-set"
VERSION = 1
#: File name of the rendering set shipped in ``meshadv/victims/data`` (EfficientNet-Lite0 and -Lite2, 72 per class).
PACKAGED_FILE = "pascal3d_renderings_v1.json"

PathLike = Union[str, Path]


@dataclass(frozen=True)
class RenderingSetConfig:
    """Sampling and rendering options of the rendering set (all ranges are inclusive-low, uniform).

    Attributes:
        azimuth_range: degrees.
        elevation_range: degrees.
        fill_range: the mesh's widest projected half-extent as a fraction of the half image (NDC), in ``(0, 1]``.
        light_max_angle: maximum angle in degrees between the light direction and the view direction.
        light_range: grey intensity of the directional light.
        ambient_range: grey ambient intensity.
        viewing_angle: camera field of view in degrees.
        background: RGB background colour.
        image_size: rendered image size (square).
        antialias: supersampling factor of the renderer.
        z_up: the meshes are Z-up (PASCAL3D+) and are rotated to the renderer's Y-up on load.
        detector_threshold: minimum detection score for a detector victim to count the class as found.
        max_candidates_per_class: stop a class (``exhausted``) after this many candidates; ``0`` = 50 x per_class.
            Not part of the set's identity: resuming with a larger budget continues the exhausted classes and yields
            the same set as a run that had the larger budget from the start.
    """

    azimuth_range: tuple[float, float] = (0.0, 360.0)
    elevation_range: tuple[float, float] = (0.0, 90.0)
    fill_range: tuple[float, float] = (0.7, 0.95)
    light_max_angle: float = 60.0
    light_range: tuple[float, float] = (0.35, 0.55)
    ambient_range: tuple[float, float] = (0.45, 0.65)
    viewing_angle: float = 30.0
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    image_size: int = 224
    antialias: int = 2
    z_up: bool = True
    detector_threshold: float = 0.3
    max_candidates_per_class: int = 0

    def __post_init__(self) -> None:
        for name in ("azimuth_range", "elevation_range", "fill_range", "light_range", "ambient_range"):
            lo, hi = getattr(self, name)
            if not lo <= hi:
                raise ValueError(f"{name} must be (low, high) with low <= high, got {(lo, hi)}")
        lo, hi = self.elevation_range
        if lo < -90 or hi > 90:
            raise ValueError(f"elevation_range must lie in [-90, 90], got {(lo, hi)}")
        lo, hi = self.fill_range
        if lo <= 0 or hi > 1:
            raise ValueError(f"fill_range must lie in (0, 1], got {(lo, hi)}")
        if not 0 <= self.light_max_angle <= 90:
            raise ValueError(f"light_max_angle must be in [0, 90], got {self.light_max_angle}")
        if not 0 < self.viewing_angle < 180:
            raise ValueError(f"viewing_angle must be in (0, 180), got {self.viewing_angle}")
        if self.image_size < 8:
            raise ValueError(f"image_size must be >= 8, got {self.image_size}")
        if len(self.background) != 3:
            raise ValueError(f"background must have 3 values, got {self.background}")
        if self.max_candidates_per_class < 0:
            raise ValueError(f"max_candidates_per_class must be >= 0, got {self.max_candidates_per_class}")

    def to_json(self) -> dict[str, Any]:
        """JSON-able dict (tuples become lists)."""
        return json.loads(json.dumps(asdict(self)))


def candidate_seed(seed: int, class_index: int, candidate: int) -> int:
    """The 32-bit seed of candidate ``candidate`` of class number ``class_index`` (independent of batching)."""
    return int(np.random.SeedSequence([int(seed), int(class_index), int(candidate)]).generate_state(1)[0])


def sample_view(rng: np.random.Generator, vertices: np.ndarray, config: RenderingSetConfig) -> dict[str, Any]:
    """Draw one camera + lighting configuration as a ViewSet record (see the module docstring for the law).

    Args:
        rng: the candidate's generator.
        vertices: ``(N, 3)`` world-space vertices of the (normalised, centred) mesh, for framing.
        config: sampling ranges.

    Returns:
        A record accepted by :meth:`meshadv.render.ViewSet.from_records`.
    """
    azimuth = float(rng.uniform(*config.azimuth_range))
    elevation = float(rng.uniform(*config.elevation_range))
    fill = float(rng.uniform(*config.fill_range))
    to_eye = np.array(spherical_direction(azimuth, elevation))
    distance = frame_distance(vertices, to_eye, fill, config.viewing_angle)
    # uniform direction on the cap of half-angle light_max_angle around to_eye
    cos_max = math.cos(math.radians(config.light_max_angle))
    cos_t = float(rng.uniform(cos_max, 1.0))
    phi = float(rng.uniform(0.0, 2.0 * math.pi))
    sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
    helper = np.array([0.0, 1.0, 0.0]) if abs(to_eye[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(helper, to_eye)
    u /= np.linalg.norm(u)
    v = np.cross(to_eye, u)
    light_dir = cos_t * to_eye + sin_t * (math.cos(phi) * u + math.sin(phi) * v)
    light = float(rng.uniform(*config.light_range))
    ambient = float(rng.uniform(*config.ambient_range))
    return {
        "distance": distance,
        "azimuth": azimuth,
        "elevation": elevation,
        "tilt": 0.0,
        "viewing_angle": float(config.viewing_angle),
        "near": 0.1,
        "far": 100.0,
        "orthographic": False,
        "ortho_scale": 1.0,
        "light_directions": [light_dir.tolist()],
        "light_colors": [[light, light, light]],
        "ambient": [ambient, ambient, ambient],
    }


def packaged_rendering_set_path() -> Path:
    """Path of the rendering set shipped with meshadv (its mesh paths are relative to the shared data folder).

    Raises:
        FileNotFoundError: this installation does not include it.
    """
    from importlib import resources

    path = Path(str(resources.files("meshadv.datasets").joinpath("data").joinpath(PACKAGED_FILE)))
    if not path.is_file():
        raise FileNotFoundError(f"the packaged rendering set {path} is missing from this installation")
    return path


def load_rendering_set(path: PathLike) -> dict[str, Any]:
    """Read a rendering-set file and check its format and version.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: not a rendering-set file, or an unsupported version.
    """
    doc = read_json(Path(path), "path")
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"path {path} is not a {FORMAT} file")
    if doc.get("version") != VERSION:
        raise ValueError(f"path {path} has version {doc.get('version')}, this meshadv reads version {VERSION}")
    return doc


def _identity(config_json: Mapping[str, Any]) -> dict[str, Any]:
    """The part of a set's configuration that decides its content (everything but the candidate budget)."""
    sampling = {k: v for k, v in config_json["sampling"].items() if k != "max_candidates_per_class"}
    return {**config_json, "sampling": sampling}


def _stored_path(path: str, root: Optional[Path]) -> str:
    if root is None:
        return path
    resolved = Path(path).resolve()
    try:
        return resolved.relative_to(root).as_posix()
    except ValueError:
        raise ValueError(f"mesh_paths_by_class: mesh {path} is not inside mesh_root {root}") from None


def rendering_mesh_path(record: Mapping[str, Any], mesh_root: Optional[PathLike] = None) -> Path:
    """The mesh file of a rendering-set record (absolute paths as stored; relative ones under ``mesh_root``).

    Args:
        record: an entry of ``doc["renderings"]``.
        mesh_root: folder the stored relative paths refer to; default the shared data folder
            (:func:`meshadv.data.shared_data_dir`).

    Raises:
        FileNotFoundError: the mesh file does not exist, or a relative path and no ``mesh_root`` / shared data.
    """
    stored = Path(record["mesh"])
    if not stored.is_absolute():
        if mesh_root is None:
            from meshadv.data import require_shared_data

            mesh_root = require_shared_data()
        stored = Path(mesh_root) / stored
    if not stored.is_file():
        raise FileNotFoundError(f"record: mesh file {stored} does not exist (pass mesh_root=the folder it is under)")
    return stored


def _render_mesh_views(mesh: Any, view_set: Any, config: RenderingSetConfig) -> torch.Tensor:
    from meshadv.render import render

    with torch.no_grad():
        return render(
            mesh.vertices,
            mesh.faces,
            mesh.face_colors,
            view_set.camera,
            view_set.lights,
            image_size=config.image_size,
            background=config.background,
            antialias=config.antialias,
        ).image


def sampling_config(doc: Mapping[str, Any]) -> RenderingSetConfig:
    """The :class:`RenderingSetConfig` a rendering-set document was built with."""
    raw = dict(doc["config"]["sampling"])
    return RenderingSetConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in raw.items()})


def render_records(
    doc: Mapping[str, Any], records: Sequence[Mapping[str, Any]], mesh_root: Optional[PathLike] = None
) -> torch.Tensor:
    """Re-render rendering-set records exactly as the set was built (same mesh normalisation, views, options).

    Args:
        doc: the rendering-set document (for its sampling options).
        records: entries of ``doc["renderings"]``.
        mesh_root: folder of relative mesh paths (see :func:`rendering_mesh_path`).

    Returns:
        ``(len(records), 3, S, S)`` images in ``[0, 1]``.
    """
    from meshadv.mesh import load_mesh, normalize_mesh

    if not records:
        raise ValueError("records must not be empty")
    config = sampling_config(doc)
    images: list[Optional[torch.Tensor]] = [None] * len(records)
    by_mesh: dict[Path, list[int]] = {}
    for i, rec in enumerate(records):
        by_mesh.setdefault(rendering_mesh_path(rec, mesh_root), []).append(i)
    for path, indices in by_mesh.items():
        mesh, _ = normalize_mesh(load_mesh(path), z_up=config.z_up)
        rendered = _render_mesh_views(mesh, record_views([records[i] for i in indices]), config)
        for j, i in enumerate(indices):
            images[i] = rendered[j]
    return torch.stack([img for img in images if img is not None])


def record_views(records: Sequence[Mapping[str, Any]]) -> Any:
    """The :class:`meshadv.render.ViewSet` of rendering-set records (their ``"view"`` entries).

    Args:
        records: entries of ``doc["renderings"]`` (typically those of one mesh).
    """
    from meshadv.render import ViewSet

    return ViewSet.from_records([rec["view"] for rec in records])


@dataclass
class _Judge:
    victim: Victim
    threshold: float
    imagenet_names: tuple[str, ...] = field(default_factory=tuple)

    def __call__(self, images: torch.Tensor, cls: str) -> tuple[list[bool], list[str]]:
        with torch.no_grad():
            if isinstance(self.victim, ClassifierVictim):
                top1 = self.victim(images).argmax(dim=1).tolist()
                group = set(PASCAL3D_TO_IMAGENET[cls])
                return [i in group for i in top1], [self.imagenet_names[i] for i in top1]
            if isinstance(self.victim, DetectorVictim):
                label = self.victim.class_index(PASCAL3D_TO_COCO[cls])
                scores = self.victim(images).scores()
                best_score, best_label = scores.max(dim=1).values.max(dim=1)
                own = scores[:, :, label].max(dim=1).values
                passed = [float(s) >= self.threshold for s in own]
                labels = [
                    f"{self.victim.class_names[int(lab)]}:{float(s):.3f}" for s, lab in zip(best_score, best_label)
                ]
                return passed, labels
        raise ValueError(f"victims: unsupported victim kind {self.victim.kind!r}")


def _resolve_victims(victims: Sequence[Union[str, Victim]]) -> list[Victim]:
    from meshadv.victims.registry import load_victim

    if isinstance(victims, (str, Victim)) or not victims:
        raise ValueError("victims must be a non-empty sequence of victim names or Victim objects")
    resolved = [load_victim(v) if isinstance(v, str) else v for v in victims]
    names = [v.name for v in resolved]
    if len(set(names)) != len(names):
        raise ValueError(f"victims must have distinct names, got {names}")
    return resolved


def _new_doc(config_json: dict[str, Any], classes: Sequence[str], victim_names: Sequence[str]) -> dict[str, Any]:
    zero = {name: 0 for name in [*victim_names, "all"]}
    return {
        "format": FORMAT,
        "version": VERSION,
        "complete": False,
        "config": config_json,
        "classes": {
            c: {
                "next_candidate": 0,
                "tried": 0,
                "kept": 0,
                "passed": dict(zero),
                "pass_rate": {k: None for k in zero},
                "exhausted": False,
            }
            for c in classes
        },
        "renderings": [],
    }


def pascal3d_mesh_paths(
    root: Optional[PathLike] = None, classes: Optional[Sequence[str]] = None
) -> dict[str, list[Path]]:
    """Mesh files per class of a PASCAL3D+ folder, ready for :func:`build_rendering_set`.

    Args:
        root: a PASCAL3D+ folder (``<root>/<class>/NN.ply`` or a release with ``CAD/``); default the shared data's.
        classes: the classes to list; default all of :data:`~meshadv.victims.labels.PASCAL3D_CLASSES` present.

    Raises:
        FileNotFoundError: no such folder (or no shared data).
        ValueError: an unknown class.
    """
    from meshadv.mesh import Pascal3DCatalog

    catalog = Pascal3DCatalog.shared() if root is None else Pascal3DCatalog(root)
    wanted = list(classes) if classes is not None else [c for c in PASCAL3D_CLASSES if c in catalog.classes()]
    for cls in wanted:
        if cls not in PASCAL3D_CLASSES:
            raise ValueError(f"classes: unknown class {cls!r}; classes: {', '.join(PASCAL3D_CLASSES)}")
    return {cls: list(catalog.models(cls)) for cls in wanted}


def build_rendering_set(
    mesh_paths_by_class: Mapping[str, Sequence[PathLike]],
    victims: Sequence[Union[str, Victim]],
    per_class: int = 72,
    seed: int = 0,
    out_path: PathLike = "rendering_set.json",
    *,
    config: Optional[RenderingSetConfig] = None,
    batch_size: int = 16,
    mesh_root: Optional[PathLike] = None,
    progress: Optional[Callable[[str, dict[str, Any]], None]] = None,
) -> dict[str, Any]:
    """Build (or resume) the rendering set and write it to ``out_path`` (atomically, after every batch).

    Args:
        mesh_paths_by_class: PASCAL3D+ class name -> mesh files of that class.
        victims: victim names (loaded with :func:`~meshadv.victims.load_victim`) or victim objects.
        per_class: kept renderings wanted per class (the paper: 72).
        seed: master seed.
        out_path: the JSON file; if it exists with the same configuration the run resumes from it.
        config: sampling / rendering options (default :class:`RenderingSetConfig`).
        batch_size: candidates rendered and classified together.
        mesh_root: when given, mesh paths are stored relative to this folder (every mesh must lie inside it), so the
            file is portable between machines; resolve them with :func:`rendering_mesh_path`.
        progress: called as ``progress(class_name, class_stats)`` after each batch.

    Returns:
        The document written to ``out_path`` (see the module docstring).

    Raises:
        ValueError: unknown class, no meshes for a class, ``per_class`` / ``batch_size`` < 1, bad victims, a mesh
            outside ``mesh_root``, or an existing ``out_path`` written with a different configuration.
        FileNotFoundError: a mesh file does not exist.
    """
    from meshadv.mesh import load_mesh, normalize_mesh
    from meshadv.render import ViewSet

    config = config or RenderingSetConfig()
    if per_class < 1:
        raise ValueError(f"per_class must be >= 1, got {per_class}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    if not mesh_paths_by_class:
        raise ValueError("mesh_paths_by_class must name at least one class")
    meshes_by_class: dict[str, list[str]] = {}
    stored_by_class: dict[str, list[str]] = {}
    root = Path(mesh_root).resolve() if mesh_root is not None else None
    if root is not None and not root.is_dir():
        raise FileNotFoundError(f"mesh_root {mesh_root} is not a folder")
    for cls, paths in mesh_paths_by_class.items():
        if cls not in PASCAL3D_TO_IMAGENET:
            raise ValueError(f"mesh_paths_by_class: unknown class {cls!r}; classes: {', '.join(PASCAL3D_CLASSES)}")
        paths = [str(p) for p in paths]
        if not paths:
            raise ValueError(f"mesh_paths_by_class[{cls!r}] is empty")
        for p in paths:
            if not Path(p).is_file():
                raise FileNotFoundError(f"mesh_paths_by_class[{cls!r}]: mesh file {p} does not exist")
        meshes_by_class[cls] = paths
        stored_by_class[cls] = [_stored_path(p, root) for p in paths]
    resolved = _resolve_victims(victims)
    victim_names = [v.name for v in resolved]
    max_candidates = config.max_candidates_per_class or 50 * per_class
    config_json = {
        "per_class": int(per_class),
        "seed": int(seed),
        "victims": victim_names,
        "meshes": stored_by_class,
        "sampling": config.to_json(),
    }
    out_path = Path(out_path)
    if out_path.exists():
        doc = load_rendering_set(out_path)
        if _identity(doc["config"]) != _identity(config_json):
            raise ValueError(
                f"out_path {out_path} holds a rendering set with a different configuration; "
                "remove it or choose another out_path"
            )
        # the candidate budget only says when to give up: a larger one continues exhausted classes
        doc["config"]["sampling"]["max_candidates_per_class"] = config.max_candidates_per_class
    else:
        out_path.parent.mkdir(parents=True, exist_ok=True)
        doc = _new_doc(config_json, list(meshes_by_class), victim_names)
    if doc["complete"] and not any(
        s["kept"] < per_class and s["next_candidate"] < max_candidates for s in doc["classes"].values()
    ):
        return doc
    doc["complete"] = False

    imagenet_names = imagenet_class_names()
    judges = [_Judge(v, config.detector_threshold, imagenet_names) for v in resolved]

    def load_class_meshes(paths: Sequence[str]) -> list[tuple[Any, np.ndarray]]:
        loaded = []
        for path in paths:
            mesh, _ = normalize_mesh(load_mesh(path), z_up=config.z_up)
            loaded.append((mesh, mesh.vertices.detach().double().numpy()))
        return loaded

    for class_index, cls in enumerate(PASCAL3D_CLASSES):
        if cls not in meshes_by_class:
            continue
        stats = doc["classes"][cls]
        paths = meshes_by_class[cls]
        if stats["kept"] >= per_class or stats["next_candidate"] >= max_candidates:
            stats["exhausted"] = stats["kept"] < per_class
            continue
        class_meshes = load_class_meshes(paths)
        while stats["kept"] < per_class and stats["next_candidate"] < max_candidates:
            start = stats["next_candidate"]
            stop = min(start + batch_size, max_candidates)
            candidates = list(range(start, stop))
            by_mesh: dict[int, list[int]] = {}
            for cand in candidates:
                by_mesh.setdefault(cand % len(paths), []).append(cand)
            results: dict[int, tuple[dict[str, Any], list[bool], dict[str, str]]] = {}
            for mesh_index, cands in by_mesh.items():
                mesh, verts_np = class_meshes[mesh_index]
                views = [
                    sample_view(np.random.default_rng(candidate_seed(seed, class_index, c)), verts_np, config)
                    for c in cands
                ]
                images = _render_mesh_views(mesh, ViewSet.from_records(views), config)
                verdicts = [judge(images, cls) for judge in judges]
                for j, cand in enumerate(cands):
                    passed = [v[0][j] for v in verdicts]
                    preds = {name: v[1][j] for name, v in zip(victim_names, verdicts)}
                    results[cand] = (views[j], passed, preds)
            for cand in candidates:  # candidate order: the set does not depend on batching
                view, passed, preds = results[cand]
                stats["tried"] += 1
                stats["next_candidate"] = cand + 1
                for name, ok in zip(victim_names, passed):
                    stats["passed"][name] += int(ok)
                if all(passed):
                    stats["passed"]["all"] += 1
                    stats["kept"] += 1
                    doc["renderings"].append(
                        {
                            "class": cls,
                            "mesh": stored_by_class[cls][cand % len(paths)],
                            "mesh_index": cand % len(paths),
                            "candidate": cand,
                            "seed": candidate_seed(seed, class_index, cand),
                            "view": view,
                            "predictions": preds,
                        }
                    )
                    if stats["kept"] >= per_class:
                        break
            stats["pass_rate"] = {k: n / stats["tried"] for k, n in stats["passed"].items()}
            stats["exhausted"] = stats["kept"] < per_class and stats["next_candidate"] >= max_candidates
            write_json_atomic(doc, out_path, indent=1)
            if progress is not None:
                progress(cls, stats)
    doc["complete"] = True
    write_json_atomic(doc, out_path, indent=1)
    return doc


def pass_rate_table(doc: Mapping[str, Any], *, markdown: bool = False) -> str:
    """A table of the pass rate per class and victim (and of all victims together).

    Args:
        doc: a rendering-set document.
        markdown: a Markdown table instead of aligned plain text.
    """
    victims = list(doc["config"]["victims"])
    header = ["class", "kept", "tried", *victims, "all"]
    rows = [header]
    for cls, stats in doc["classes"].items():
        rates = stats["pass_rate"]
        rows.append(
            [cls, str(stats["kept"]), str(stats["tried"])]
            + ["-" if rates[k] is None else f"{100 * rates[k]:.1f}%" for k in [*victims, "all"]]
        )
    if markdown:
        return markdown_table(header, rows[1:])
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    return "\n".join("  ".join(cell.ljust(w) for cell, w in zip(row, widths)) for row in rows)
