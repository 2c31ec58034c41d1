"""The paper's indoor detection scene: a desk, a chair and the Stanford Bunny on the desk, with floor and walls.

Read from ``<shared data>/scenes/indoor/scene.xml`` (the same meshes and layout as the Mitsuba scene, so a transfer
re-render sees the same geometry). Lighting follows the paper: one directional light and a low ambient.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import torch

from meshadv.data import require_shared_data
from meshadv.render import Lights
from meshadv.scenes.mitsuba_xml import MitsubaSceneInfo, read_mitsuba_scene

#: Direction toward the indoor light (from the ceiling lamp, slightly in front of the desk), its colour and the ambient.
INDOOR_LIGHT_DIRECTION = (0.2, 1.0, 0.45)
INDOOR_LIGHT_COLOR = (0.75, 0.75, 0.75)
INDOOR_AMBIENT = (0.35, 0.35, 0.35)


def indoor_scene_path(root: Optional[Path] = None) -> Path:
    """Path of the indoor scene file (``scenes/indoor/scene.xml`` in the shared data, or under ``root``)."""
    if root is not None:
        path = Path(root) / "scene.xml"
        if not path.is_file():
            raise FileNotFoundError(f"indoor scene file not found: {path}")
        return path
    return require_shared_data("scenes/indoor/scene.xml")


def load_indoor_scene(root: Optional[Path] = None) -> MitsubaSceneInfo:
    """Load the indoor scene (objects ``desk``, ``chair``, ``bunny``, the floor and two walls) and its camera."""
    return read_mitsuba_scene(indoor_scene_path(root))


def indoor_lights() -> Lights:
    """The indoor scene's lights: one directional light and a low ambient (batch 1)."""
    return Lights(
        directions=torch.tensor([[INDOOR_LIGHT_DIRECTION]], dtype=torch.float32),
        colors=torch.tensor([[INDOOR_LIGHT_COLOR]], dtype=torch.float32),
        ambient=torch.tensor([INDOOR_AMBIENT], dtype=torch.float32),
    )
