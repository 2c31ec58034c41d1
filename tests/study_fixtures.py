"""A tiny sweep results database for the perceptual-study tests (synthetic attacks, no renderer, no victim)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from meshadv.experiments.config import expand_jobs, parse_config
from sweep_fixtures import run_probe_sweep

#: Three classes, one configuration, shape and texture: 12 jobs; every fourth one fails, so 9 succeed.
TINY_STUDY_SWEEP = {
    "experiment": {"name": "tiny-study"},
    "meshes": {"classes": ["boat", "chair", "sofa"]},
    "render": {"configurations": 1, "image_size": 32},
    "victims": {"names": ["v1"]},
    "attack": {"types": ["shape", "texture"]},
}


def make_study_db(root: Path, classes: Sequence[str] = ("boat", "chair", "sofa")) -> Path:
    """Run the synthetic sweep (:func:`probe_jobs.mesh_probe_job`) over ``classes`` into ``root``;
    return the db. Every fourth job fails."""
    raw = {**TINY_STUDY_SWEEP, "meshes": {"classes": list(classes)}}
    jobs = [{**j, "success": i % 4 != 3} for i, j in enumerate(expand_jobs(parse_config(raw)))]
    return run_probe_sweep(root / "results.db", jobs, root / "run")
