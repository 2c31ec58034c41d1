"""Misspelt sweep-file keys fail at load with the closest valid key; bad attack options fail before any job."""

from __future__ import annotations

import copy
from typing import Any

import pytest

from meshadv.experiments.config import parse_config

BASE: dict[str, Any] = {
    "experiment": {"name": "t", "output": "out"},
    "meshes": {"source": "builtin", "builtin": [{"name": "sphere", "class": "bottle"}]},
    "render": {"image_size": 32, "configurations": 1},
    "victims": {"names": ["efficientnet_lite0"]},
    "attack": {"perturbations": ["shape"], "targets": ["chair"], "shape": {"steps": 2}},
    "multiview": {"enabled": False},
    "runner": {"workers": 1},
}


def _with(path: str, value: Any) -> dict[str, Any]:
    raw = copy.deepcopy(BASE)
    *parents, key = path.split(".")
    table = raw
    for name in parents:
        table = table.setdefault(name, {})
    table[key] = value
    return raw


def _renamed(path: str, new_key: str) -> dict[str, Any]:
    raw = copy.deepcopy(BASE)
    *parents, key = path.split(".")
    table = raw
    for name in parents:
        table = table[name]
    table[new_key] = table.pop(key)
    return raw


# Misspellings of real keys plus misspelt section names.
MISSPELLINGS = [
    (_renamed("attack.shape", "shap"), "'attack.shap'", "'attack.shape'"),
    (_with("render.image_sise", 64), "'render.image_sise'", "'render.image_size'"),
    (_renamed("runner.workers", "worker"), "'runner.worker'", "'runner.workers'"),
    (_renamed("experiment.output", "outptu"), "'experiment.outptu'", "'experiment.output'"),
    (_with("meshes.clases", ["chair"]), "'meshes.clases'", "'meshes.classes'"),
    (_renamed("attack.perturbations", "tpyes"), "'attack.tpyes'", "'attack.types'"),
    (_with("multiview.enabeld", True), "'multiview.enabeld'", "'multiview.enabled'"),
    (_with("attack.shape.stepz", 10), "'attack.shape.stepz'", "'attack.shape.steps'"),
    (_renamed("render", "rendr"), "[rendr]", "[render]"),
    (_renamed("victims", "victim"), "[victim]", "[victims]"),
    (
        _with("attack.protocols", {"p": {"configurations": 1, "texture": {"lrr": 0.1}}}),
        "'attack.protocols.p.texture.lrr'",
        "'attack.protocols.p.texture.lr'",
    ),
]


@pytest.mark.parametrize(("raw", "key", "hint"), MISSPELLINGS)
def test_misspelt_keys_fail_at_load_with_a_suggestion(raw: dict[str, Any], key: str, hint: str) -> None:
    with pytest.raises(ValueError, match="unknown config") as info:
        parse_config(raw)
    message = str(info.value)
    assert key in message and f"did you mean {hint}" in message


def test_the_base_config_and_job_options_load() -> None:
    cfg = parse_config(_with("attack.shape.required_margin", 5.0))
    assert cfg.attack["shape"]["steps"] == 2


def test_bad_attack_option_values_fail_at_load() -> None:
    with pytest.raises(ValueError, match=r"^\[attack\.shape\]: "):
        parse_config(_with("attack.shape.lr", -1.0))


def test_a_table_without_a_method_runs_the_recommended_one_unless_it_sets_adam_options() -> None:
    from meshadv.attacks.update import RECOMMENDED_METHOD
    from meshadv.experiments.config import expand_jobs

    def methods(raw: dict[str, Any]) -> set:
        return {j["attack"].get("method") for j in expand_jobs(parse_config(raw))}

    assert RECOMMENDED_METHOD == "ddn"
    assert methods(BASE) == {"ddn"}  # {"steps": 2}: the recommended rule, written into the jobs
    assert methods(_with("attack.shape.method", "adam")) == {"adam"}
    # a table with one of Adam's own options is the paper's rule (the attacks' default), its jobs unchanged
    for key, value in (("lr", 0.01), ("lambda_perceptual", 0.1), ("binary_search_steps", 5), ("smoothing", 0)):
        assert methods(_with(f"attack.shape.{key}", value)) == {None}, key
    raw = _with("attack.protocols", {"p": {"configurations": 1, "shape": {"steps": 3},
                                           "texture": {"lr": 0.05}}})
    raw["attack"]["perturbations"] = ["shape", "texture"]
    by_protocol = {(j.get("protocol"), j["perturbation"]): j["attack"].get("method")
                   for j in expand_jobs(parse_config(raw))}
    assert by_protocol == {(None, "shape"): "ddn", (None, "texture"): "ddn", ("p", "shape"): "ddn",
                           ("p", "texture"): None}
