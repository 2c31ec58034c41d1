"""benchmarks/paper_cost.py: the projection's step counts (early stopping or the whole budget) and borrowing rules."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import pytest
from benchmark_scripts import load_benchmark

CONFIG = """
[meshes]
source = "builtin"
builtin = [{name = "chair", class = "chair"}, {name = "sofa", class = "sofa"}]
[render]
configurations = 1
[victims]
names = ["efficientnet_lite0"]
[attack]
perturbations = ["shape", "texture"]
[attack.shape]
method = "adam"
steps = 100
early_stop = 3
[attack.texture]
method = "ddn"
steps = 50
"""


def _paper_cost() -> ModuleType:
    return load_benchmark("paper_cost")


def test_projection_steps_and_borrowing(tmp_path: Path) -> None:
    pc = _paper_cost()
    config = tmp_path / "c.toml"
    config.write_text(CONFIG)
    adam_shape = ("efficientnet_lite0", "shape", "single", "adam")
    costs = {adam_shape: {"per_step_image": 0.5, "steps": 20.0, "n": 1},
             ("efficientnet_lite0", "texture", "single", "adam"): {"per_step_image": 9.0, "steps": 1.0, "n": 1}}
    p = pc.project(config, costs)
    assert p["jobs"] == 4  # 2 meshes x 2 types x 1 target
    # shape (early_stop): expected 2 jobs x 0.5 s x min(100, 20) steps, at most the whole budget of 100
    assert p["cpu_hours"] * 3600 == pytest.approx(2 * 0.5 * 20)
    assert p["upper_cpu_hours"] * 3600 == pytest.approx(2 * 0.5 * 100)
    # ddn texture: an Adam measurement is not borrowed across update rules
    assert p["missing"] == {("efficientnet_lite0", "texture", "single", "ddn"): 2}
    costs[("efficientnet_lite2", "texture", "single", "ddn")] = {"per_step_image": 0.2, "steps": 10.0, "n": 1}
    p = pc.project(config, costs)
    assert p["missing"] == {} and p["borrowed"] == [("efficientnet_lite0", "texture", "single", "ddn")]
    # ddn runs every step: its expected cost is the whole budget, not the measured mean steps
    texture = 2 * 0.2 * 50
    assert p["cpu_hours"] * 3600 == pytest.approx(2 * 0.5 * 20 + texture)
    assert p["upper_cpu_hours"] * 3600 == pytest.approx(2 * 0.5 * 100 + texture)


def test_projection_counts_each_retry_at_the_measured_failure_rate(tmp_path: Path) -> None:
    pc = _paper_cost()
    config = tmp_path / "c.toml"
    config.write_text(CONFIG + "[attack.retry]\ntexture = { steps = 200 }\n")
    costs = {("efficientnet_lite0", "shape", "single", "adam"): {"per_step_image": 0.5, "steps": 20.0, "n": 1,
                                                                 "failure_rate": 0.0},
             ("efficientnet_lite0", "texture", "single", "ddn"): {"per_step_image": 0.2, "steps": 50.0, "n": 1,
                                                                  "failure_rate": 0.25}}
    p = pc.project(config, costs)
    retry = p["groups"]["efficientnet_lite0 texture single ddn [retry]"]
    # 2 texture attacks, each retried with 200 steps: a quarter of them expected, every one at most
    assert retry[0] * 3600 == pytest.approx(0.25 * 2 * 0.2 * 200)
    assert retry[1] * 3600 == pytest.approx(2 * 0.2 * 200)
    assert p["upper_cpu_hours"] * 3600 == pytest.approx(2 * 0.5 * 100 + 2 * 0.2 * 50 + 2 * 0.2 * 200)
    assert not any("shape" in label and "retry" in label for label in p["groups"])  # shape is not retried


def test_projection_counts_each_retry_stage_at_the_failure_rates_before_it(tmp_path: Path) -> None:
    pc = _paper_cost()
    config = tmp_path / "c.toml"
    config.write_text(CONFIG + "[[attack.retry]]\ntexture = { steps = 200 }\n"
                      "[[attack.retry]]\ntexture = { method = \"adam\", steps = 100, binary_search_steps = 2 }\n")
    costs = {("efficientnet_lite0", "shape", "single", "adam"): {"per_step_image": 0.5, "steps": 20.0, "n": 1},
             ("efficientnet_lite0", "texture", "single", "ddn"): {"per_step_image": 0.2, "steps": 50.0, "n": 1,
                                                                  "failure_rate": 0.25,
                                                                  "retry_failure_rates": {1: 0.5}},
             ("efficientnet_lite0", "texture", "single", "adam"): {"per_step_image": 9.0, "steps": 1.0, "n": 1}}
    p = pc.project(config, costs)
    first = p["groups"]["efficientnet_lite0 texture single ddn [retry]"]
    second = p["groups"]["efficientnet_lite0 texture single adam [retry 2]"]
    assert first[0] * 3600 == pytest.approx(0.25 * 2 * 0.2 * 200)
    # stage 2: Adam's own cost, 2 rounds x 100 steps, for the quarter of the attacks whose retry failed half the time
    assert second[0] * 3600 == pytest.approx(0.25 * 0.5 * 2 * 9.0 * 100 * 2)
    assert second[1] * 3600 == pytest.approx(2 * 9.0 * 100 * 2)
