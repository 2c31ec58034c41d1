"""Insert an object into a real photograph: a scene of one mesh, a camera that places it, and the photo behind it."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional, Tuple, Union

import torch

from meshadv.mesh import Mesh
from meshadv.render import Lights
from meshadv.scenes.attack import SceneSetup
from meshadv.scenes.composite import estimate_sky_light, load_photo
from meshadv.scenes.scene import Scene, SceneCamera, SceneObject

#: Fixed pinhole camera used to insert objects into photos: eye on +z looking at the origin, 50 degrees wide.
PHOTO_EYE = (0.0, 0.0, 4.0)
PHOTO_FOV = 50.0


def placement_transform(
    mesh: Mesh, camera: SceneCamera, center_uv: Tuple[float, float], height_fraction: float
) -> torch.Tensor:
    """Model-to-world matrix that puts ``mesh`` at image position ``center_uv`` with a given on-screen height.

    Args:
        mesh: the object (any scale, any centre).
        camera: the photo's scene camera (any eye and look-at point; the object is placed in the plane through
            ``camera.at`` facing the camera).
        center_uv: (u, v) in [0, 1], u to the right, v downward, where the object's centre should appear.
        height_fraction: the object's height as a fraction of the image height.

    Returns:
        (4, 4) float32 matrix: scale, then translate to the point of the look-at plane that meshadv's image shows at
        ``center_uv`` (see :meth:`SceneCamera.image_axes` for the image's right).
    """
    u, v = center_uv
    if not (0.0 <= u <= 1.0 and 0.0 <= v <= 1.0):
        raise ValueError(f"center_uv must lie in [0, 1]^2, got {center_uv}")
    if not 0.0 < height_fraction <= 1.0:
        raise ValueError(f"height_fraction must be in (0, 1], got {height_fraction}")
    verts = mesh.vertices
    lo, hi = verts.min(0).values, verts.max(0).values
    centre = (lo + hi) / 2
    depth = float((torch.tensor(camera.eye) - torch.tensor(camera.at)).norm())
    half_width_world = depth * math.tan(math.radians(camera.fov) / 2)
    pixel_world = 2 * half_width_world / camera.width
    scale = height_fraction * camera.height * pixel_world / float((hi - lo)[1].clamp_min(1e-9))
    right, up = camera.image_axes()
    offset = ((u - 0.5) * camera.width * pixel_world) * right + ((0.5 - v) * camera.height * pixel_world) * up
    matrix = torch.eye(4)
    matrix[:3, :3] *= scale
    matrix[:3, 3] = (torch.tensor(camera.at, dtype=torch.float64) + offset).float() - scale * centre
    return matrix


def photo_setup(
    photo_path: Union[str, Path],
    mesh: Mesh,
    *,
    center_uv: Tuple[float, float] = (0.5, 0.75),
    height_fraction: float = 0.3,
    lights: Optional[Lights] = None,
    width: Optional[int] = None,
) -> SceneSetup:
    """A ``SceneSetup`` that renders ``mesh`` over the photograph ``photo_path``.

    Args:
        photo_path: the background photo; its size becomes the image size (height cropped to keep an even
            difference with the width, see ``SceneCamera``).
        mesh: the inserted object (``name`` in the scene: ``"object"``).
        center_uv: where the object's centre appears, (u, v) in [0, 1], v downward.
        height_fraction: the object's on-screen height relative to the image height.
        lights: lights of batch 1; default: a sky light estimated from the photo (``estimate_sky_light``).
        width: optional width to resize the photo to (aspect kept).
    """
    photo = load_photo(photo_path)
    h, w = photo.shape[2:]
    if width is not None:
        h, w = int(round(h * width / w)), int(width)
        photo = load_photo(photo_path, size=(w, h))
    if h > w:
        raise ValueError(f"portrait photos are not supported (got {w}x{h}); crop or rotate {photo_path}")
    if (w - h) % 2:
        h -= 1
        photo = photo[:, :, :h, :]
    camera = SceneCamera(eye=PHOTO_EYE, at=(0.0, 0.0, 0.0), fov=PHOTO_FOV, width=w, height=h)
    if lights is None:
        direction, color, ambient = estimate_sky_light(photo)
        lights = Lights(directions=direction.view(1, 1, 3), colors=color.view(1, 1, 3), ambient=ambient.view(1, 3))
    transform = placement_transform(mesh, camera, center_uv, height_fraction)
    scene = Scene((SceneObject(name="object", mesh=mesh, transform=transform),))
    return SceneSetup(scene=scene, object_name="object", camera=camera, lights=lights, photo=photo)
