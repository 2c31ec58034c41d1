"""Scene XML from other people is parsed with defusedxml: entity expansion and external entities are refused."""

from __future__ import annotations

from pathlib import Path

import pytest

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


def test_a_plain_scene_still_parses(tmp_path: Path) -> None:
    path = tmp_path / "scene.xml"
    path.write_text('<scene version="3.0.0"><sensor type="perspective"/></scene>')
    try:
        read_mitsuba_scene(path)
    except ValueError as exc:  # no shapes: refused for content, not for parsing
        assert "not valid XML" not in str(exc)
