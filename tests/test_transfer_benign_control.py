"""The benign control of controlled transfer: the benign mesh is rendered by Mitsuba too, and untargeted transfer
counts only on views whose benign Mitsuba render is right (stand-in victim, fake Mitsuba renders: no Mitsuba)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, List, Tuple

import numpy as np
import pytest
import torch

from meshadv.mesh import builtin_mesh, save_mesh
from meshadv.render import ViewSet, native_available
from meshadv.transfer import controlled
from meshadv.transfer.controlled import TransferCase, controlled_transfer, evaluate_case
from meshadv.transfer.mitsuba_process import MitsubaImage
from meshadv.transfer.results import transfer_table

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


def _fake(color: Tuple[float, float, float]) -> MitsubaImage:
    image = np.empty((32, 32, 3), dtype=np.float32)
    image[:] = color  # a flat colour: the stand-in victim's class differs between pure red and pure green
    return MitsubaImage(image, np.ones((32, 32), dtype=np.float32), "fake")


def _two_classes(victim: Any) -> Tuple[MitsubaImage, MitsubaImage, int, int]:
    """Two fake renders the stand-in victim puts in different classes, and those classes."""
    from meshadv.transfer.scoring import images_tensor

    candidates = [_fake(c) for c in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))]
    with torch.no_grad():
        top = victim(images_tensor(candidates)).argmax(dim=1).tolist()
    other = next(i for i in range(1, len(top)) if top[i] != top[0])
    return candidates[0], candidates[other], top[0], top[other]


def _case(true_class: int, benign: Any = "same") -> TransferCase:
    mesh = builtin_mesh("bottle")
    views = ViewSet.orbit([20.0, 60.0], elevation=15.0, distance=3.0).to_records()
    return TransferCase("c", mesh, tuple(views), "stand_in", str(true_class), image_size=32,
                        benign_mesh=mesh if benign == "same" else benign)


@needs_native
def test_a_wrong_benign_render_takes_its_view_out_of_the_untargeted_count() -> None:
    from stand_in_victims import PooledLinearClassifier

    victim = PooledLinearClassifier()
    right, other, true_class, _ = _two_classes(victim)
    case = _case(true_class)
    adversarial = [other, other]  # untargeted-adversarial on both views
    honest = evaluate_case(case, victim, adversarial, [right, right])
    fooled = evaluate_case(case, victim, adversarial, [right, other])  # the benign mesh is wrong on view 1 already
    assert [r.untargeted_mitsuba for r in fooled] == [True, True]
    assert [r.benign_correct_mitsuba for r in fooled] == [True, False]
    assert [r.untargeted_counted for r in fooled] == [True, None]
    assert fooled[1].top1_benign_mitsuba == victim.class_names[_two_classes(victim)[3]]
    table_honest = transfer_table([r.to_record() for r in honest])[0]
    table_fooled = transfer_table([r.to_record() for r in fooled])[0]
    assert table_honest["untargeted_mitsuba"] == 1.0 and table_honest["n_benign_mitsuba_correct"] == 2
    # the same adversarial renders: 2 of 2 views without the control, 1 of 1 counted view with it
    assert table_fooled["untargeted_mitsuba_uncontrolled"] == 1.0 and table_fooled["n_benign_mitsuba_correct"] == 1
    all_wrong = transfer_table([r.to_record() for r in evaluate_case(case, victim, adversarial, [other, other])])[0]
    assert all_wrong["untargeted_mitsuba"] is None and all_wrong["untargeted_mitsuba_uncontrolled"] == 1.0
    with pytest.raises(ValueError, match="benign_images"):
        evaluate_case(case, victim, adversarial, [right])


@needs_native
def test_controlled_transfer_renders_the_benign_mesh_in_the_same_call(monkeypatch: pytest.MonkeyPatch,
                                                                       tmp_path: Path) -> None:
    from stand_in_victims import PooledLinearClassifier

    victim = PooledLinearClassifier()
    right, other, true_class, _ = _two_classes(victim)
    calls: List[int] = []

    def render(specs: list, **kwargs: Any) -> list:
        calls.append(len(specs))
        return [other, other, right, other][:len(specs)]  # adversarial views, then the benign ones

    monkeypatch.setattr(controlled, "render_scenes", render)
    rows = controlled_transfer([_case(true_class)], victim_loader=lambda name: victim, image_dir=tmp_path)
    assert calls == [4] and [r.benign_correct_mitsuba for r in rows] == [True, False]
    assert (tmp_path / "c_benign_v1.png").is_file() and (tmp_path / "c_v1.png").is_file()
    bare = controlled_transfer([_case(true_class, benign=None)], victim_loader=lambda name: victim)
    assert calls[-1] == 2 and all(r.benign_correct_mitsuba is None for r in bare)
    assert "benign_correct_mitsuba" not in bare[0].to_record()  # rows without the control keep the old keys


def test_an_attack_folder_gives_its_saved_benign_mesh(tmp_path: Path) -> None:
    from meshadv.transfer.benign_control import benign_mesh_of_attack_folder

    mesh = builtin_mesh("chair")
    save_mesh(mesh, tmp_path / "benign.ply")
    got = benign_mesh_of_attack_folder(tmp_path, {}, mesh.num_vertices)
    assert torch.allclose(got.vertices, mesh.vertices)
    with pytest.raises(ValueError, match="vertices"):
        benign_mesh_of_attack_folder(tmp_path, {}, mesh.num_vertices + 1)
    (tmp_path / "benign.ply").unlink()
    rebuilt = benign_mesh_of_attack_folder(tmp_path, {"input": {"mesh": "builtin:chair"}}, mesh.num_vertices)
    assert torch.allclose(rebuilt.vertices, mesh.vertices)
    with pytest.raises(FileNotFoundError, match="benign"):
        benign_mesh_of_attack_folder(tmp_path, json.loads("{}"), mesh.num_vertices)
