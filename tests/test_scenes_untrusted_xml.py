"""Scene XML from other people is parsed with defusedxml: entity expansion and external entities are refused."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from meshadv.scenes.mitsuba_xml import read_mitsuba_scene

BILLION_LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE lolz [<!ENTITY lol "lol"><!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">]>
<scene version="3.0.0"><integer name="x" value="&lol2;"/></scene>
"""

EXTERNAL_ENTITY = """<?xml version="1.0"?>
<!DOCTYPE scene [<!ENTITY secret SYSTEM "file:///etc/passwd">]>
<scene version="3.0.0"><string name="x" value="&secret;"/></scene>
"""


@pytest.mark.parametrize("text", [BILLION_LAUGHS, EXTERNAL_ENTITY])
def test_entities_in_scene_files_are_refused(tmp_path: Path, text: str) -> None:
    path = tmp_path / "scene.xml"
    path.write_text(text)
    with pytest.raises(ValueError, match="uses entities/DTDs"):
        read_mitsuba_scene(path)


PLAIN_SCENE = """<?xml version="1.0" encoding="utf-8"?>
<!-- a comment is fine; only entities and DTDs are refused -->
<scene version="3.0.0">
  <bsdf type="diffuse" id="grey"><rgb name="reflectance" value="0.25, 0.5, 0.75"/></bsdf>
  <shape type="rectangle"><ref id="grey"/></shape>
  <sensor type="perspective">
    <float name="fov" value="39.5"/>
    <transform name="to_world"><lookat origin="0, 1, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="64"/><integer name="height" value="48"/></film>
  </sensor>
</scene>
"""


def test_a_plain_scene_still_parses(tmp_path: Path) -> None:
    """A scene with an XML declaration and a comment but no DTD reads in full: its shape, colour and camera."""
    path = tmp_path / "scene.xml"
    path.write_text(PLAIN_SCENE)
    info = read_mitsuba_scene(path)
    assert [obj.name for obj in info.scene.objects] == ["rectangle"]
    colors = info.scene.objects[0].mesh.face_colors
    assert torch.allclose(colors, torch.tensor([0.25, 0.5, 0.75]).expand_as(colors))
    camera = info.camera
    assert (camera.eye, camera.at, camera.up) == ((0.0, 1.0, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    assert (camera.fov, camera.width, camera.height) == (39.5, 64, 48)
