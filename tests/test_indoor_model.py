"""One model of the indoor scene: the black-box detector setup's known objects are the scene model's objects."""

from __future__ import annotations

from pathlib import Path

import torch


def test_transfer_indoor_setup_uses_the_scene_model(shared_data: Path) -> None:
    from meshadv.scenes.indoor import load_indoor_scene
    from meshadv.transfer.setups import indoor_detector_setup

    scene = load_indoor_scene().scene
    setup = indoor_detector_setup()
    for name, mesh in zip(("desk", "chair", "bunny"), setup.objects):
        assert torch.equal(mesh.vertices, scene[name].world_vertices())
        assert torch.equal(mesh.faces, scene[name].mesh.faces)
        assert torch.equal(mesh.face_colors, scene[name].mesh.face_colors)
    scaled = indoor_detector_setup(object_scale=0.5).objects[2]
    assert float(scaled.vertices[:, 1].min()) == float(setup.objects[2].vertices[:, 1].min())  # stays on the desk
