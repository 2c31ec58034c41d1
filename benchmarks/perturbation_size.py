"""What keeping each attack's perturbation costs a results database, and what regenerating a job instead costs.

Regenerates ``--jobs`` finished jobs of ``DB`` (one shape and one texture attack by default, the first of each) with
one thread into a temporary folder, times each, packs the regenerated attack's perturbation
(:class:`meshadv.experiments.perturbation.Perturbation`) and reports its compressed size; the database-wide estimate
scales each packed size by the vertices (shape) or faces (texture) of every finished, not skipped job of ``DB``.

    OMP_NUM_THREADS=1 RAYON_NUM_THREADS=1 python benchmarks/perturbation_size.py docs/results/paper_small/results.db \\
        --estimate docs/results/paper_medium/results.db
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Dict, List

import torch


def _first_jobs(db: Path) -> List[str]:
    """The first finished, not skipped job of each perturbation type."""
    from meshadv.experiments import ResultStore

    chosen: Dict[str, str] = {}
    with ResultStore(db, read_only=True) as store:
        for row in store.rows("done"):
            if not (row.record or {}).get("skipped"):
                chosen.setdefault(row.spec["perturbation"], row.job_id)
    return list(chosen.values())


def main() -> None:
    """Measure (module docstring) and print a Markdown table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("db", type=Path)
    parser.add_argument("--jobs", nargs="*", default=None, help="job ids (default: the first of each type)")
    parser.add_argument("--estimate", type=Path, default=None, help="another database to estimate the size for")
    args = parser.parse_args()
    torch.set_num_threads(1)

    from meshadv.experiments import ResultStore
    from meshadv.experiments.perturbation import Perturbation
    from meshadv.experiments.regenerate import regenerate_job
    from meshadv.mesh import load_mesh

    per_element: Dict[str, float] = {}
    print("| job | type | vertices | faces | regeneration wall s | reproduces the record | packed bytes |")
    print("|---|---|---|---|---|---|---|")
    for job in args.jobs or _first_jobs(args.db):
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            done = regenerate_job(args.db, job, Path(tmp) / "job", threads=1)
            wall = time.perf_counter() - start
            benign = load_mesh(done.out_dir / done.record["artifacts"]["benign_mesh"])
            adversarial = load_mesh(done.out_dir / done.record["artifacts"]["adversarial_mesh"])
        packed = Perturbation.between(benign, adversarial)
        kind = done.record.get("attack_config", {}).get("perturbation") or packed.kind
        rows = benign.num_vertices if packed.kind == "vertices" else benign.num_faces
        per_element[packed.kind] = len(packed.data) / rows
        print(f"| {job} | {kind} | {benign.num_vertices} | {benign.num_faces} | {wall:.1f} | "
              f"{'yes' if done.matches else 'no: ' + '; '.join(done.differences)} | {len(packed.data)} |")
    if args.estimate is not None:
        total, counted = 0.0, 0
        with ResultStore(args.estimate, read_only=True) as store:
            for row in store.rows("done"):
                rec = row.record or {}
                if rec.get("skipped"):
                    continue
                kind = "vertices" if row.spec["perturbation"] == "shape" else "face_colors"
                if kind in per_element:
                    total += per_element[kind] * rec[f"num_{'vertices' if kind == 'vertices' else 'faces'}"]
                    counted += 1
        print(f"\nestimated perturbations of {args.estimate}: {counted} jobs, {total / 1e6:.1f} MB "
              f"(the file: {args.estimate.stat().st_size / 1e6:.1f} MB)")


if __name__ == "__main__":
    main()
