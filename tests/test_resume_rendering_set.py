"""``meshadv rendering-set build`` killed with SIGTERM mid-build: exit 130, the file on disk is a complete JSON
document of the finished batches, and the same command resumes from it instead of starting over.

A real subprocess, a real signal and the real EfficientNet-Lite0 on two PASCAL3D+ sofas at a small size.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, Dict, Optional
from signal_fixtures import terminate_when



def _load(path: Path) -> Optional[Dict[str, Any]]:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def test_sigterm_mid_build_keeps_finished_batches_and_resumes(tmp_path: Path, shared_data: Path,
                                                               lite0_victim: Any) -> None:
    out = tmp_path / "set.json"
    # 50 kept per class is out of reach: the build runs until its 24 candidates (12 batches of 2) are spent
    args = [sys.executable, "-m", "meshadv", "rendering-set", "build", "-o", str(out), "--victims",
            "efficientnet_lite0", "--classes", "sofa", "--per-class", "50", "--max-candidates", "24",
            "--batch-size", "2", "--threads", "1"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1", "RAYON_NUM_THREADS": "1"}
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    def four_tried() -> bool:
        doc = _load(out)
        return doc is not None and doc["classes"]["sofa"]["tried"] >= 4

    _, stderr = terminate_when(proc, four_tried, timeout=180)
    assert proc.returncode == 130, stderr
    assert "interrupted: the finished batches are kept in" in stderr and "Traceback" not in stderr
    partial = _load(out)
    assert partial is not None, "the file is complete JSON after the kill"
    tried = partial["classes"]["sofa"]["tried"]
    assert not partial["complete"] and 4 <= tried < 24 and tried % 2 == 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "no temporary files left behind"

    resumed = subprocess.run(args, capture_output=True, text=True, env=env, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    first = next(line for line in resumed.stderr.splitlines() if line.startswith("sofa: kept "))
    assert first.endswith(f"of {tried + 2} tried"), first  # the first batch of the rerun continues the count
    doc = _load(out)
    assert doc is not None and doc["complete"] and doc["classes"]["sofa"]["tried"] == 24
    assert doc["renderings"][: len(partial["renderings"])] == partial["renderings"]
