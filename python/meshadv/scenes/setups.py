"""Build a ``SceneSetup`` from a command-line scene description: 'indoor', a Mitsuba XML file, or a photograph."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Optional

from meshadv.scenes.attack import SceneSetup

if TYPE_CHECKING:
    from meshadv.mesh import Mesh

PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png")


def _parse_place(place: str) -> tuple:
    try:
        u, v, h = (float(x) for x in place.split(","))
    except ValueError:
        raise ValueError(f"place must be 'u,v,height_fraction', got {place!r}") from None
    return (u, v), h


def build_setup(scene: str, obj: str, place: str = "0.5,0.75,0.3", width: Optional[int] = None) -> SceneSetup:
    """Turn a scene description into a ``SceneSetup``.

    Args:
        scene: ``"indoor"``, a path to a Mitsuba scene XML, or a photo (.jpg/.jpeg/.png).
        obj: for XML scenes the name of the object to perturb; for photos a mesh file, or ``"bunny"`` for the
            shared Stanford Bunny (falling back to a built-in shape when the shared data is missing).
        place: photos only, ``"u,v,height_fraction"``.
        width: optional image width to render at (the height follows the aspect ratio).

    Raises:
        ValueError / FileNotFoundError: unknown scene, object or unreadable files.
    """
    from meshadv.scenes.indoor import indoor_lights, load_indoor_scene
    from meshadv.scenes.mitsuba_xml import read_mitsuba_scene

    if scene == "indoor" or scene.endswith(".xml"):
        info = load_indoor_scene() if scene == "indoor" else read_mitsuba_scene(Path(scene))
        camera = info.camera if width is None else info.camera.resized(width)
        return SceneSetup(scene=info.scene, object_name=obj, camera=camera, lights=indoor_lights())
    path = Path(scene)
    if path.suffix.lower() not in PHOTO_SUFFIXES:
        raise ValueError(
            f"scene must be 'indoor', a .xml scene or a photo ({', '.join(PHOTO_SUFFIXES)}), got {scene!r}"
        )
    from meshadv.scenes.photo import photo_setup

    mesh = _photo_object(obj)
    center, height = _parse_place(place)
    return photo_setup(path, mesh, center_uv=center, height_fraction=height, width=width)


def _photo_object(obj: str) -> "Mesh":
    """The mesh to insert into a photo: a file, or the shared bunny (built-in sphere when absent)."""
    from meshadv.data import shared_data_dir
    from meshadv.mesh import builtin_mesh, load_mesh

    if obj != "bunny":
        return load_mesh(Path(obj))
    root = shared_data_dir()
    if root is not None and (root / "scenes/indoor/meshes/bunny.ply").is_file():
        return load_mesh(root / "scenes/indoor/meshes/bunny.ply", default_color=(0.6, 0.6, 0.6))
    return builtin_mesh("sphere")
