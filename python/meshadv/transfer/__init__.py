"""Transfer of adversarial meshes to Mitsuba 3, a photorealistic, non-differentiable renderer.

Rendering:

* :mod:`~meshadv.transfer.variants` picks the best working Mitsuba variant (probed in a child process).
* :mod:`~meshadv.transfer.spec` holds what Mitsuba renders (camera, lights, meshes, scene settings) as picklable
  numpy values, the camera in :mod:`~meshadv.transfer.camera_spec`; :mod:`~meshadv.transfer.scene` builds the
  Mitsuba scene from it (optionally merged into a larger scene file); :mod:`~meshadv.transfer.environment` makes a
  procedural sky.
* :mod:`~meshadv.transfer.render` renders in an isolated child process; :mod:`~meshadv.transfer.check` compares its
  images with meshadv's.

Controlled transfer (same camera and lights):

* :mod:`~meshadv.transfer.cases` reads a sweep's adversarial meshes; :mod:`~meshadv.transfer.controlled` re-renders
  and scores them; :mod:`~meshadv.transfer.images` saves the renders and their index.

Black-box transfer (estimated camera and lights):

* :mod:`~meshadv.transfer.hidden` is the hidden world; :mod:`~meshadv.transfer.estimate` estimates camera
  (:mod:`~meshadv.transfer.camera_estimate`) and lights (:mod:`~meshadv.transfer.light_estimate`) from an image,
  :mod:`~meshadv.transfer.photo` does so from Mitsuba's photo of the hidden world;
  :mod:`~meshadv.transfer.objects` handles scenes of several known objects; :mod:`~meshadv.transfer.robust` (EOT,
  margin, pixel noise) and :mod:`~meshadv.transfer.object_attacks` make the attack;
  :mod:`~meshadv.transfer.compositing` renders it under the estimates; :mod:`~meshadv.transfer.blackbox` runs the
  pipelines (:mod:`~meshadv.transfer.classifier_pipeline`, :mod:`~meshadv.transfer.detector_pipeline`);
  :mod:`~meshadv.transfer.setups` holds the paper's hidden worlds.

Results: :mod:`~meshadv.transfer.results` (typed rows), :mod:`~meshadv.transfer.database` (their table in the
sweep's database) and :mod:`~meshadv.transfer.tables` (the paper's tables).

Importing this package does not import torch or mitsuba.
"""

from meshadv.transfer.environment import outdoor_environment
from meshadv.transfer.render import MitsubaImage, MitsubaRenderError, render_mask, render_scene, render_scenes
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
