"""``meshadv transfer render`` frames a mesh as ``meshadv attack`` does by default."""

from __future__ import annotations

from typing import Any, Dict

import typer

from meshadv.cli import app


def _defaults(*path: str) -> Dict[str, Any]:
    command = typer.main.get_command(app)
    for name in path:
        command = command.commands[name]  # type: ignore[attr-defined]
    return {p.name: p.default for p in command.params}


def test_transfer_render_defaults_are_the_attacks() -> None:
    attack = _defaults("attack")
    render = _defaults("transfer", "render")
    low, high = (float(x) for x in attack["azimuths"].split(":"))
    assert render["size"] == attack["image_size"]
    assert render["distance"] == attack["distance"] and render["elevation"] == attack["elevation"]
    assert render["azimuth"] == (low + high) / 2  # the centre of the attack's views
