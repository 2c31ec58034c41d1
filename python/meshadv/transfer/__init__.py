"""Transfer of adversarial meshes to Mitsuba 3, a photorealistic, non-differentiable renderer.

Rendering:

* :mod:`~meshadv.transfer.mitsuba_spec`: what Mitsuba renders (camera, lights, meshes, scene settings) as picklable
  numpy values.
* :mod:`~meshadv.transfer.mitsuba_scene`: the Mitsuba scene built from them (in the rendering child), and a
  procedural sky.
* :mod:`~meshadv.transfer.mitsuba_process`: rendering in an isolated child process
  (:mod:`~meshadv.transfer.mitsuba_worker`) with the best working Mitsuba variant.
* :mod:`~meshadv.transfer.mitsuba_check`: Mitsuba's images compared with meshadv's.

Controlled transfer (same camera and lights): :mod:`~meshadv.transfer.controlled`, with the victim's readings of
:mod:`~meshadv.transfer.scoring`.

Black-box transfer (estimated camera and lights): :mod:`~meshadv.transfer.setups` (the hidden worlds),
:mod:`~meshadv.transfer.photos` (Mitsuba's photos of them), :mod:`~meshadv.transfer.estimation` (camera and lights
from a photo), :mod:`~meshadv.transfer.robust` (EOT, margin, pixel noise; the attack) and
:mod:`~meshadv.transfer.blackbox` (the pipelines).

Results: :mod:`~meshadv.transfer.results` (typed rows, their table in the sweep's database, the transfer tables).

Importing this package does not import torch or mitsuba.
"""

from meshadv.transfer.mitsuba_process import (
    MitsubaImage,
    MitsubaRenderError,
    best_variant,
    probe_variant,
    render_mask,
    render_scene,
    render_scenes,
)
from meshadv.transfer.mitsuba_scene import outdoor_environment
from meshadv.transfer.mitsuba_spec import MeshObject, MitsubaCamera, MitsubaLights, SceneSpec, scene_spec

__all__ = [
    "MeshObject",
    "MitsubaCamera",
    "MitsubaImage",
    "MitsubaLights",
    "MitsubaRenderError",
    "SceneSpec",
    "best_variant",
    "outdoor_environment",
    "probe_variant",
    "render_mask",
    "render_scene",
    "render_scenes",
    "scene_spec",
]
