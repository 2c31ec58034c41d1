"""Projected CPU time of a sweep from measured per-step costs (paper_medium, paper_full).

1. ``--measure``: run a stratified sample of a config's jobs (the first ``--per-group`` jobs of each victim x
   perturbation type x kind) one at a time in this process into ``<out>/results.db`` (resumable), with 1 thread.
2. Project: per group, the measured CPU seconds (the record's ``cpu_time``; wall time for older records) per
   optimisation step and image (a step renders and classifies ``views`` images) and the mean number of steps an
   attack ran (early stopping), applied to every job of each config: expected ``seconds = per_step_image x views x
   rounds x min(steps budget, measured mean steps)``, upper bound ``per_step_image x views x rounds x steps budget``
   (no early stop at all); the multi-view jobs' unseen views (one forward pass each) are negligible. Groups without a
   measurement borrow the nearest one (same type and kind with the other victim, else the same victim and type)
   and say so.

    python benchmarks/paper_cost.py --measure --config configs/paper_medium.toml --out out/cost
    python benchmarks/paper_cost.py --db out/cost/results.db --config configs/paper_medium.toml configs/paper_full.toml

CPU time, not wall time, is projected: on a loaded machine the wall time of a job is several times its CPU time.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any, Dict, List, Tuple

from meshadv.experiments import ResultStore, SerialBackend, run_sweep
from meshadv.experiments.config import expand_jobs, load_config

Group = Tuple[str, str, str]  # victim, perturbation, kind


def _group(spec: Dict[str, Any]) -> Group:
    return spec["victim"], spec["perturbation"], spec.get("kind", "single")


def _budget(spec: Dict[str, Any]) -> Tuple[int, int]:
    attack = spec.get("attack", {})
    return int(attack.get("steps", 100)), int(attack.get("binary_search_steps", 1))


def sample_jobs(config: Path, per_group: int) -> List[Dict[str, Any]]:
    """The first ``per_group`` jobs of each group (main setting only), spread over classes."""
    jobs = [j for j in expand_jobs(load_config(config)) if "protocol" not in j]
    by_group: Dict[Group, List[Dict[str, Any]]] = defaultdict(list)
    for job in jobs:
        by_group[_group(job)].append(job)
    out = []
    for group_jobs in by_group.values():
        step = max(1, len(group_jobs) // per_group)
        out += group_jobs[::step][:per_group]
    return out


def measured(db: Path) -> Dict[Group, Dict[str, float]]:
    """Per group: seconds per step and image, fraction of the budget used, attacks measured."""
    with ResultStore(db) as store:
        rows = [r for r in store.rows("done") if not r.record.get("skipped") and r.record.get("steps")]
    acc: Dict[Group, List[Tuple[float, float]]] = defaultdict(list)
    for r in rows:
        steps, rounds = _budget(r.spec)
        views = len(r.spec["views"])
        seconds = r.record.get("cpu_time") or r.record["time"]  # CPU time when recorded: robust to a loaded machine
        per_step_image = seconds / (r.record["steps"] * views)
        acc[_group(r.spec)].append((per_step_image, r.record["steps"] / rounds))
    return {g: {"per_step_image": statistics.median(v[0] for v in vals),
                "steps": statistics.mean(v[1] for v in vals), "n": len(vals)} for g, vals in acc.items()}


def project(config: Path, costs: Dict[Group, Dict[str, float]]) -> Dict[str, Any]:
    """Expected and upper-bound CPU-hours of every job of ``config`` (see the module docstring)."""
    total = upper = 0.0
    per_group: Dict[str, List[float]] = defaultdict(lambda: [0.0, 0.0])
    borrowed = set()
    jobs = expand_jobs(load_config(config))
    for job in jobs:
        g = _group(job)
        cost = costs.get(g)
        if cost is None:  # borrow: same type and kind (another victim), else same victim and type, else same type
            for same in (lambda k: k[1:] == g[1:], lambda k: k[:2] == g[:2], lambda k: k[1] == g[1]):
                cost = next((c for k, c in sorted(costs.items()) if same(k)), None)
                if cost is not None:
                    break
            borrowed.add(g)
        if cost is None:
            continue
        steps, rounds = _budget(job)
        step_cost = cost["per_step_image"] * len(job["views"]) * rounds
        seconds, most = step_cost * min(steps, cost["steps"]), step_cost * steps
        total += seconds
        upper += most
        label = f"{g[0]} {g[1]} {g[2]}" + (f" [{job['protocol']}]" if job.get("protocol") else "")
        per_group[label][0] += seconds
        per_group[label][1] += most
    return {"config": str(config), "jobs": len(jobs), "cpu_hours": total / 3600.0, "upper_cpu_hours": upper / 3600.0,
            "groups": {k: (v[0] / 3600.0, v[1] / 3600.0) for k, v in sorted(per_group.items())},
            "borrowed": sorted(borrowed)}


def main(argv: List[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--config", type=Path, nargs="+", required=True)
    parser.add_argument("--measure", action="store_true", help="run the sample jobs of the first config first")
    parser.add_argument("--per-group", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("out/cost"))
    parser.add_argument("--db", type=Path, default=None, help="measured database (default <out>/results.db)")
    args = parser.parse_args(argv)
    db = args.db or args.out / "results.db"
    if args.measure:
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        sample = sample_jobs(args.config[0], args.per_group)
        with ResultStore(db) as store:
            run_sweep(store, sample, "meshadv.experiments.jobs:run_attack_job", out_root=args.out,
                      backend=SerialBackend(threads_per_job=1), max_attempts=1, progress=False)
    costs = measured(db)
    print("| victim | type | kind | attacks measured | CPU s per step and image | mean steps per round |")
    print("|---|---|---|---|---|---|")
    for (victim, ptype, kind), c in sorted(costs.items()):
        print(f"| {victim} | {ptype} | {kind} | {c['n']} | {c['per_step_image']:.3f} | {c['steps']:.0f} |")
    for config in args.config:
        p = project(config, costs)
        print(f"\n{p['config']}: {p['jobs']} jobs, {p['cpu_hours']:.1f} CPU-hours expected, "
              f"{p['upper_cpu_hours']:.1f} at most"
              + (f" (borrowed costs for {p['borrowed']})" if p["borrowed"] else ""))
        print("| group | expected CPU-hours | at most (no early stop) |\n|---|---|---|")
        for label, (hours, most) in p["groups"].items():
            print(f"| {label} | {hours:.1f} | {most:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
