"""Tiny sweep configurations on the built-in chair and sofa, shared by the sweep tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, Iterable, List, Sequence

from meshadv.experiments import ResultStore, SerialBackend, run_sweep
from meshadv.experiments.config import expand_jobs, parse_config


def tiny_builtin_config(name: str, *, image_size: int = 32, steps: int = 3,
                        perturbations: Sequence[str] = ("shape", "texture")) -> Dict[str, Any]:
    """A sweep config (as parsed TOML) attacking the built-in chair and sofa with EfficientNet-Lite0 for ``steps``
    steps at ``image_size`` px, one configuration each, every job run whether or not the benign render is right."""
    return {
        "experiment": {"name": name},
        "meshes": {"source": "builtin", "builtin": [{"name": "chair", "class": "chair"},
                                                    {"name": "sofa", "class": "sofa"}]},
        "render": {"image_size": image_size, "configurations": 1, "distance": 2.4, "elevation": [15, 25]},
        "victims": {"names": ["efficientnet_lite0"]},
        "attack": {"perturbations": list(perturbations), "benign_correct_only": False,
                   "shape": {"steps": steps, "lr": 0.01}, "texture": {"steps": steps}},
    }


def run_probe_sweep(db: Path, jobs: Iterable[Dict[str, Any]], out_root: Path) -> Path:
    """Run synthetic attack jobs (:func:`meshadv.experiments.probes.mesh_probe_job`: no renderer, no victim; each
    job's ``success`` key decides its outcome) serially into the database ``db``; return ``db``."""
    with ResultStore(db) as store:
        run_sweep(store, jobs, "meshadv.experiments.probes:mesh_probe_job", out_root=out_root,
                  backend=SerialBackend(), progress=False)
    return db


def probe_jobs(classes: Sequence[str], *, configurations: int = 1) -> List[Dict[str, Any]]:
    """The job specs of a shape-attack sweep of the PASCAL3D+ ``classes`` (``configurations`` drawn views each, the
    stand-in victim name ``"v"``, every other listed class a target), for :func:`run_probe_sweep`."""
    return expand_jobs(parse_config({"meshes": {"classes": list(classes)},
                                     "render": {"configurations": configurations},
                                     "victims": {"names": ["v"]}, "attack": {"types": ["shape"]}}))
