"""The "PASCAL3D+ renderings" set: random views of each class's meshes that every chosen victim gets right.

One job per module: :mod:`.sampling` (the options and the law below), :mod:`.set_file` (format, packaged set,
reading), :mod:`.mesh_paths` (which meshes, how they are stored), :mod:`.rendering` (rendering a set's views),
:mod:`.judging` (the victims' verdicts), :mod:`.build` (building and resuming) and :mod:`.pass_rates` (the table).
Import the names from here.

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
photos. The packaged set (``meshadv/datasets/data/pascal3d_renderings_v1.json``, :func:`packaged_rendering_set_path`)
was made by ``meshadv rendering-set build -o ...`` with these defaults, seed 0, EfficientNet-Lite0 and -Lite2: 72
configurations per class. Low elevations pass most, so a set filtered by the victims leans toward them. The pass
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

from meshadv.datasets.rendering_set.build import build_rendering_set
from meshadv.datasets.rendering_set.mesh_paths import pascal3d_mesh_paths, rendering_mesh_path
from meshadv.datasets.rendering_set.pass_rates import pass_rate_table
from meshadv.datasets.rendering_set.rendering import record_views, render_records
from meshadv.datasets.rendering_set.sampling import RenderingSetConfig, candidate_seed, sample_view, sampling_config
from meshadv.datasets.rendering_set.set_file import (
    FORMAT,
    PACKAGED_FILE,
    VERSION,
    load_rendering_set,
    packaged_rendering_set_path,
)

__all__ = [
    "FORMAT",
    "VERSION",
    "PACKAGED_FILE",
    "RenderingSetConfig",
    "build_rendering_set",
    "candidate_seed",
    "load_rendering_set",
    "packaged_rendering_set_path",
    "pascal3d_mesh_paths",
    "rendering_mesh_path",
    "pass_rate_table",
    "record_views",
    "render_records",
    "sample_view",
    "sampling_config",
]
