"""Shared pytest fixtures: the shared data folder, skipping with a clear reason when it is missing."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

from meshadv.data import DATA_ENV_VAR, shared_data_dir

#: The test helpers (probe jobs, the local Ray cluster, stand-in victims) are importable in every process a test
#: starts: spawned workers, Ray nodes and command-line subprocesses.
_TESTS = str(Path(__file__).resolve().parent)
if _TESTS not in os.environ.get("PYTHONPATH", "").split(os.pathsep):
    os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (_TESTS, os.environ.get("PYTHONPATH", "")) if p)

try:  # the property-based suite's budget: bounded and derandomised so CI time and results are repeatable
    from hypothesis import HealthCheck, settings

    settings.register_profile(
        "ci", max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
    )
    settings.register_profile("fuzz", max_examples=2000, deadline=None)  # HYPOTHESIS_PROFILE=fuzz for long runs
    import os as _os

    settings.load_profile(_os.environ.get("HYPOTHESIS_PROFILE", "ci"))
except ImportError:  # hypothesis is a test dependency; test_properties.py skips without it
    pass


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The shared data folder; the test is skipped when it is absent."""
    root = shared_data_dir()
    if root is None:
        pytest.skip(f"shared data not found (set {DATA_ENV_VAR} or provide ../shared/data)")
    return root


@pytest.fixture(scope="session")
def lite0_victim() -> Any:
    """The real EfficientNet-Lite0 victim; skipped when the renderer or the victim's package is missing."""
    from meshadv.render import native_available

    if not native_available():
        pytest.skip("native module meshadv._raster is not built (run `maturin develop --release`)")
    try:
        from meshadv.victims import load_victim

        return load_victim("efficientnet_lite0")
    except ImportError as exc:
        pytest.skip(f"victim efficientnet_lite0 unavailable: {exc}")


def load_shared_pascal_mesh(shared_data: Path, category: str, model: str) -> Any:
    """A shared PASCAL3D+ mesh, Z-up turned Y-up and normalised to [-1, 1]; skips the test when the file is missing."""
    from meshadv.mesh import load_mesh, normalize_mesh

    path = shared_data / "pascal3d" / category / f"{model}.ply"
    if not path.is_file():
        pytest.skip(f"shared mesh {path} is missing")
    return normalize_mesh(load_mesh(path), z_up=True)[0]
