"""Does the packaged rendering set's "every victim gets it right" survive the sweep's mesh resampling?

The packaged PASCAL3D+ rendering set (:mod:`meshadv.datasets.rendering_set`) keeps a configuration when every victim
classifies the render of the class's *original* mesh right. A sweep with ``meshes.target_faces`` (paper_medium:
4,000, the paper's uniform MeshLab resampling) attacks the *resampled* mesh, and its jobs judge the benign render of
that mesh again (``benign_correct_only``: a wrong one is skipped). This script renders each instance of a sweep's
main setting both ways, as the job does (its mesh loader, render setup and benign check), and records both verdicts.

    OMP_NUM_THREADS=1 RAYON_NUM_THREADS=1 python benchmarks/resampled_benign_check.py configs/paper_medium.toml \
        -o benchmarks/resampling/paper_medium.jsonl
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path
from typing import Any, Dict, List

import torch

from meshadv.experiments import jobs
from meshadv.experiments.config import expand_jobs, load_config


def instances(config: Path) -> List[Dict[str, Any]]:
    """One shape job per (victim, class, configuration) of the sweep's main setting: the instances it attacks."""
    seen, out = set(), []
    for spec in expand_jobs(load_config(config)):
        key = (spec["victim"], spec["source_class"], spec.get("config_index"))
        if spec["kind"] == "single" and not spec.get("protocol") and key not in seen:
            seen.add(key)
            out.append(spec)
    return out


def check(spec: Dict[str, Any]) -> Dict[str, Any]:
    """Benign verdicts of one instance on the original mesh (``target_faces`` 0) and on the sweep's mesh."""
    context = jobs.JobContext.from_spec(spec)  # the job's own views, victim, render settings and benign check
    row: Dict[str, Any] = {"victim": spec["victim"], "class": spec["source_class"], "config": spec["config_index"],
                           "mesh": spec["mesh"]["path"]}
    for name, target_faces in (("original", 0), ("sweep", int(spec["mesh"].get("target_faces", 0)))):
        mesh = jobs.load_job_mesh({**spec["mesh"], "target_faces": target_faces})
        verdict = context.benign_verdict(mesh)
        row[name] = {"faces": int(mesh.faces.shape[0]), "correct": verdict.correct, "top1": verdict.top1[0]}
    return row


def main() -> None:
    """Check every instance of the sweep, append one JSON line each to ``-o``, print the summary."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("config", type=Path, help="sweep file (its main setting's instances are checked)")
    parser.add_argument("-o", "--output", type=Path, required=True, help="JSON lines, one per instance")
    args = parser.parse_args()
    torch.set_num_threads(1)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    rows = []
    with open(args.output, "w", encoding="utf-8") as fh:
        for spec in instances(args.config):
            rows.append(check(spec))
            fh.write(json.dumps(rows[-1]) + "\n")
            fh.flush()
    summary = Counter((r["victim"], r["original"]["correct"], r["sweep"]["correct"]) for r in rows)
    for (victim, original, resampled), n in sorted(summary.items()):
        print(f"{victim}: original mesh {'right' if original else 'wrong'}, sweep mesh "
              f"{'right' if resampled else 'wrong'}: {n}")
    for r in rows:
        if r["original"]["correct"] != r["sweep"]["correct"]:
            print(f"  {r['victim']} {r['class']}/{r['config']} ({r['mesh']}): {r['original']['top1']} "
                  f"({r['original']['faces']} faces) -> {r['sweep']['top1']} ({r['sweep']['faces']} faces)")


if __name__ == "__main__":
    main()
