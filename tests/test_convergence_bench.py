"""benchmarks/convergence_bench.py: per-setting options, instance selection and the curves it stores (no attack run)."""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path
from types import ModuleType

import pytest


def _bench() -> ModuleType:
    path = Path(__file__).parents[1] / "benchmarks" / "convergence_bench.py"
    spec = importlib.util.spec_from_file_location("convergence_bench", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_method_and_attack_options_reach_the_attack() -> None:
    cb = _bench()
    attack = cb.make_attack("ddn", "shape", {"momentum": 0.5, "smoothness": 0.3}, {"loss": "cw"})
    config = attack.config()
    assert config["method"] == "ddn" and config["steps"] == 300 and config["loss"] == "cw"
    assert config["method_options"]["momentum"] == 0.5 and config["method_options"]["smoothness"] == 0.3
    assert cb.make_attack("ddn", "shape").config()["method_options"]["momentum"] == 0.0
    with pytest.raises(ValueError, match="method_options"):
        cb.make_attack("small", "shape", {"momentum": 0.5})
    with pytest.raises(ValueError, match="momentum"):
        cb.make_attack("ddn", "shape", {"momentum": 2.0}).config()


def test_command_line_parsers_reject_bad_values() -> None:
    cb = _bench()
    assert cb._instance("sofa/1") == ("sofa", 1)
    assert cb._json_object('{"momentum": 0.9}') == {"momentum": 0.9}
    for bad in ("sofa", "car/0", "sofa/x"):
        with pytest.raises(argparse.ArgumentTypeError, match="CLASS/INDEX"):
            cb._instance(bad)
    for bad in ("[1]", "{momentum: 1}"):
        with pytest.raises(argparse.ArgumentTypeError):
            cb._json_object(bad)


def test_options_need_their_own_database(tmp_path: Path) -> None:
    cb = _bench()
    with pytest.raises(SystemExit, match="own --db"):
        cb.main(["--methods", "ddn", "--method-options", '{"momentum": 0.9}'])


def test_only_keeps_the_chosen_instances() -> None:
    cb = _bench()
    every = cb.instances(2, cb.CLASSES)
    chosen = cb.instances(2, cb.CLASSES, [("sofa", 1), ("bottle", 0)])
    assert [(c, i) for c, i, _ in chosen] == [("bottle", 0), ("sofa", 1)]  # the benchmark's order
    assert all(job in every for job in chosen)


def test_curves_record_first_success_improvements_and_best_margin() -> None:
    cb = _bench()
    history = [{"margin": [-2.0, -1.0], "distance": [0.5, 0.1]},
               {"margin": [0.3, -0.4], "distance": [0.4, 0.2]},
               {"margin": [0.1, -0.9], "distance": [0.2, 0.3]},
               {"margin": [0.2, None], "distance": [0.3, None]}]
    first, second = cb._curves(history, 2)
    assert first == {"first": 2, "improvements": [[2, 0.4], [3, 0.2]], "best_margin": 0.3}
    assert second == {"first": None, "improvements": [], "best_margin": -0.4}
