"""The style rules that tools can check: ruff (pyproject's rules: types on every signature, a doc comment on every
public item, pyflakes, pycodestyle) over the Python, and rustfmt over the Rust."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(command: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)


def test_ruff_passes_on_python_tests_and_benchmarks() -> None:
    ruff = shutil.which("ruff")
    if ruff is None:
        pytest.skip("ruff is not installed (requirements.txt pins it; scripts/install.sh installs it)")
    done = _run([ruff, "check", "--no-cache", "python", "tests", "benchmarks"])
    assert done.returncode == 0, done.stdout + done.stderr


def test_rust_sources_are_rustfmt_formatted() -> None:
    cargo = shutil.which("cargo")
    if cargo is None or _run([cargo, "fmt", "--version"]).returncode != 0:
        pytest.skip("cargo fmt (rustfmt) is not installed")
    done = _run([cargo, "fmt", "--all", "--check"])
    assert done.returncode == 0, done.stdout + done.stderr
