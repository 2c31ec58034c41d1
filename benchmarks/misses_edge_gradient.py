"""A sweep's missed single-view shape attacks run again with ddn's ``edge_gradient`` (issue 14's new default) in
place of the weight they ran with: how many of the main setting's misses the new default reaches, at what distortion
(benchmarks/RESULTS.md, "paper_medium's shape misses with edge_gradient 0.1").

Each failed main-setting (no protocol, no retry) shape job of ``--victim`` is rerun as
:func:`meshadv.experiments.regenerate.regenerate_job` would, from its stored spec and seed with the options its record
says it ran with, except ``method_options.edge_gradient`` = ``--edge-gradient``. One JSON line per job goes to
``--out`` as it finishes (a rerun skips the jobs already there, so the benchmark resumes); the summary table is
printed at the end. The database is only read.

    OMP_NUM_THREADS=1 RAYON_NUM_THREADS=1 python benchmarks/misses_edge_gradient.py \
        docs/results/paper_medium/results.db --out benchmarks/paper_medium_misses_eg01.jsonl
"""

from __future__ import annotations

import argparse
import copy
import json
import tempfile
from pathlib import Path
from typing import Any, Dict, List, Tuple

from meshadv.experiments.regenerate import pinned_spec, stored_job_ref
from meshadv.experiments.retries import is_main_single
from meshadv.experiments.store import ResultStore
from meshadv.experiments.worker import execute


def missed_main_shape_jobs(db: Path, victim: str) -> Tuple[List[Any], str]:
    """The finished main-setting single-view shape jobs of ``victim`` in ``db`` whose attack failed (in job order),
    and the database's job function."""
    with ResultStore(db, read_only=True) as store:
        rows = store.rows()
        ref = stored_job_ref(store)
    missed = [row for row in rows if row.state == "done" and row.record is not None
              and not row.record.get("success") and not row.record.get("skipped") and is_main_single(row.spec)
              and row.spec.get("perturbation") == "shape" and row.spec.get("victim") == victim]
    return missed, ref


def rerun(row: Any, ref: str, edge_gradient: float) -> Dict[str, Any]:
    """Run ``row``'s job again with ``edge_gradient``; its outcome beside the stored one."""
    spec, _ = pinned_spec(row.spec, row.record)
    spec = copy.deepcopy(spec)
    spec.setdefault("attack", {}).setdefault("method_options", {})["edge_gradient"] = edge_gradient
    with tempfile.TemporaryDirectory() as tmp:
        outcome = execute(ref, row.job_id, spec, tmp, threads=1)
    if not outcome.ok or outcome.record is None:
        raise RuntimeError(f"job {row.job_id} failed:\n{outcome.error}")
    new, old = outcome.record, row.record
    return {"job_id": row.job_id, "instance": f"{row.spec['source_class']}/{row.spec.get('config_index')}",
            "target": row.spec["target"], "edge_gradient": edge_gradient,
            "stored": {"success": old["success"], "pair_mean": old["distances"].get("laplacian_pair_mean")},
            "success": bool(new["success"]), "steps_to_success": new.get("steps_to_success"),
            "pair_mean": new["distances"].get("laplacian_pair_mean"),
            "max_displacement": new["distances"].get("max_displacement"), "cpu_time": new.get("cpu_time")}


def main() -> None:
    """Rerun the misses not yet in ``--out``, then print the table of all of them."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("db", type=Path, help="a sweep's results database (read only)")
    parser.add_argument("--out", type=Path, required=True, help="JSON lines, one per rerun job (resumable)")
    parser.add_argument("--victim", default="efficientnet_lite0")
    parser.add_argument("--edge-gradient", type=float, default=0.1)
    args = parser.parse_args()
    done = {}
    if args.out.is_file():
        done = {r["job_id"]: r for r in map(json.loads, args.out.read_text().splitlines()) if r}
    missed, ref = missed_main_shape_jobs(args.db, args.victim)
    for row in missed:
        if row.job_id in done:
            continue
        result = rerun(row, ref, args.edge_gradient)
        with args.out.open("a") as f:
            f.write(json.dumps(result) + "\n")
        done[row.job_id] = result
        print(json.dumps(result), flush=True)
    results = sorted(done.values(), key=lambda r: (r["instance"], r["target"]))
    print("| instance -> target | reached (first step) | pair mean | largest vertex move (% of diagonal) | CPU s |")
    print("|---|---|---|---|---:|")
    for r in results:
        reached = f"yes ({r['steps_to_success']})" if r["success"] else "no"
        move = "-" if r["max_displacement"] is None else f"{100 * r['max_displacement']:.2g}"
        print(f"| {r['instance']} -> {r['target']} | {reached} | {r['pair_mean']:.2g} | {move} | {r['cpu_time']:.0f} |")
    print(f"\n{sum(r['success'] for r in results)} of {len(results)} reached")


if __name__ == "__main__":
    main()
