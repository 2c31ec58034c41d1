"""Transfer of adversarial meshes to Mitsuba 3, a photorealistic, non-differentiable renderer.

* :mod:`~meshadv.transfer.variants` picks the best working Mitsuba variant (probed in a child process).
* :mod:`~meshadv.transfer.spec` holds what Mitsuba renders (camera, lights, meshes, scene settings) as picklable
  numpy values; :mod:`~meshadv.transfer.scene` builds the Mitsuba scene from it (optionally merged into a larger
  scene file); :mod:`~meshadv.transfer.environment` makes a procedural sky.
* :mod:`~meshadv.transfer.render` renders in an isolated child process.
* :mod:`~meshadv.transfer.estimate` estimates camera and lights from an image (needs torch and meshadv.render).
* :mod:`~meshadv.transfer.controlled` re-renders a sweep's adversarial meshes under their own camera and lights.
* :mod:`~meshadv.transfer.blackbox` runs the black-box pipeline (estimated camera and lights, attack, re-render), with
  :mod:`~meshadv.transfer.robust` (EOT, margin, pixel noise) and :mod:`~meshadv.transfer.object_attacks` (attacks on
  one object of a scene).

Importing this package does not import torch or mitsuba.
"""

from meshadv.transfer.render import MitsubaImage, MitsubaRenderError, render_mask, render_scene, render_scenes
from meshadv.transfer.environment import outdoor_environment
from meshadv.transfer.spec import MeshObject, MitsubaCamera, MitsubaLights, SceneSpec, scene_spec
from meshadv.transfer.variants import best_variant, probe_variant

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
