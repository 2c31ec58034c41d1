"""A tiny sweep results database for the perceptual-study tests (synthetic attacks, no renderer, no victim)."""

from __future__ import annotations

from pathlib import Path

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


def make_study_db(root: Path) -> Path:
    """Run the synthetic sweep (:func:`meshadv.experiments.probes.mesh_probe_job`) into ``root``; return the db."""
    jobs = [{**j, "success": i % 4 != 3} for i, j in enumerate(expand_jobs(parse_config(TINY_STUDY_SWEEP)))]
    return run_probe_sweep(root / "results.db", jobs, root / "run")
