"""Scenes of several meshes: joint rendering with occlusion, the indoor desk scene, photo compositing, scene attacks."""

from meshadv.scenes.composite import composite_over_photo, load_photo
from meshadv.scenes.scene import Scene, SceneCamera, SceneObject, SceneRender

__all__ = [
    "Scene",
    "SceneCamera",
    "SceneObject",
    "SceneRender",
    "composite_over_photo",
    "load_photo",
]
