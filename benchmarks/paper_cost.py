"""Projected CPU time of a sweep from measured per-step costs (paper_medium, paper_full).

1. ``--measure``: run a stratified sample of a config's jobs (the first ``--per-group`` jobs of each victim x
   perturbation type x kind x update rule) one at a time in this process into ``<out>/results.db`` (resumable), with
   1 thread.
2. Project: per group (victim, type, kind, update rule: ``method``, ``adam`` when absent), the measured CPU seconds
   (the record's ``cpu_time``; wall time for older records) per optimisation step and image (a step renders and
   classifies ``views`` images) and the mean number of steps an attack ran, applied to every job of each config:
   ``seconds = per_step_image x views x rounds x steps``, where ``steps`` is, for a job with ``early_stop``,
   min(budget, measured mean steps) (expected) or the budget (upper bound), and the budget for a job without it
   (it runs every step: ``method = "ddn"``, and the paper's 5 x 1000 protocol). The multi-view jobs' unseen views
   (one forward pass each) are negligible. Groups without a measurement borrow the nearest one with the same update
   rule (same type and kind with another victim, else the same victim and type, else the same type) and say so.
   ``--db`` takes several databases (e.g. a sweep's own database for its ``ddn`` jobs and an Adam measurement for
   the paper's protocol). With ``[attack.retry]`` each main attack may run once more (its retry): expected at the
   group's measured failure rate of main attacks, at most once per main attack, labelled ``[retry]``; with several
   stages (``[[attack.retry]]``) each stage's retry is expected at the product of the measured failure rates of the
   stages before it (the main attacks' and each earlier stage's retries'; 1 where a stage has no finished retry yet),
   at its own update rule's cost, labelled ``[retry k]``.

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
from typing import Any, Dict, List, Optional, Sequence, Tuple

from meshadv.experiments import ResultStore, SerialBackend, run_sweep
from meshadv.experiments.config import expand_jobs, load_config
from meshadv.experiments.retries import protocol_label, retry_options, retry_spec, retry_stage

Group = Tuple[str, str, str, str]  # victim, perturbation, kind, update rule


def _group(spec: Dict[str, Any]) -> Group:
    return (spec["victim"], spec["perturbation"], spec.get("kind", "single"),
            str(spec.get("attack", {}).get("method", "adam")))


def _stops_early(spec: Dict[str, Any]) -> bool:
    """Whether the job's attack may end before its step budget (only with ``early_stop``)."""
    return spec.get("attack", {}).get("early_stop") is not None


def _budget(spec: Dict[str, Any]) -> Tuple[int, int]:
    attack = spec.get("attack", {})
    return int(attack.get("steps", 100)), int(attack.get("binary_search_steps", 1))


def _seconds(spec: Dict[str, Any], cost: Dict[str, float]) -> Tuple[float, float]:
    """Expected and largest CPU seconds of the job ``spec`` at its group's measured ``cost`` (module docstring)."""
    steps, rounds = _budget(spec)
    step_cost = cost["per_step_image"] * len(spec["views"]) * rounds
    most = step_cost * steps
    return (step_cost * min(steps, cost["steps"]) if _stops_early(spec) else most), most


def _label(spec: Dict[str, Any]) -> str:
    """The projection's group label of a job: its group, and ``[protocol]`` for an extra protocol's or a retry."""
    protocol = protocol_label(spec)
    return " ".join(_group(spec)) + (f" [{protocol}]" if protocol else "")


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


def measured(dbs: Sequence[Path]) -> Dict[Group, Dict[str, float]]:
    """Per group, over the done jobs of every database: seconds per step and image, mean steps per round, attacks
    measured."""
    rows = []
    for db in dbs:
        with ResultStore(db, read_only=True) as store:
            rows += [r for r in store.rows("done") if not r.record.get("skipped") and r.record.get("steps")]
    acc: Dict[Group, List[Tuple[float, float]]] = defaultdict(list)
    # successes of the main attacks (stage 0) and of each retry stage's, by the main attack's group: the expected
    # share of the next stage's retries
    outcomes: Dict[Tuple[str, str, str, int], List[bool]] = defaultdict(list)
    for r in rows:
        stage = retry_stage(r.spec)
        if stage or not r.spec.get("protocol"):  # keyed without the update rule: a retry stage may change it
            outcomes[(*_group(r.spec)[:3], stage)].append(bool(r.record.get("success")))
        steps, rounds = _budget(r.spec)
        views = len(r.spec["views"])
        seconds = r.record.get("cpu_time") or r.record["time"]  # CPU time when recorded: robust to a loaded machine
        per_step_image = seconds / (r.record["steps"] * views)
        acc[_group(r.spec)].append((per_step_image, r.record["steps"] / rounds))
    def failure_rate(key: Tuple[str, str, str, int]) -> float:
        return 1.0 - statistics.mean(outcomes[key]) if outcomes.get(key) else 1.0

    stages = sorted({k[3] for k in outcomes if k[3] > 0})
    return {g: {"per_step_image": statistics.median(v[0] for v in vals),
                "steps": statistics.mean(v[1] for v in vals), "n": len(vals),
                "failure_rate": failure_rate((*g[:3], 0)),
                "retry_failure_rates": {k: failure_rate((*g[:3], k)) for k in stages if (*g[:3], k) in outcomes}}
            for g, vals in acc.items()}


def _cost_of(g: Group, costs: Dict[Group, Dict[str, float]]) -> Optional[Dict[str, float]]:
    """The measured cost of group ``g``, else one borrowed with the same update rule: same type and kind (another
    victim), else same victim and type, else same type; ``None`` when there is none."""
    if g in costs:
        return costs[g]
    for same in (lambda k: k[1:] == g[1:], lambda k: k[:2] == g[:2] and k[3] == g[3],
                 lambda k: k[1] == g[1] and k[3] == g[3]):
        cost = next((c for k, c in sorted(costs.items()) if same(k)), None)
        if cost is not None:
            return cost
    return None


def _failure_rate(cost: Dict[str, Any], stage: int) -> float:
    """The measured failure rate of the main attacks (``stage`` 0) or of a retry stage's retries, from the main
    attack's group cost; 1 (every one fails) when not measured."""
    if stage == 0:
        return float(cost.get("failure_rate", 1.0))
    return float(cost.get("retry_failure_rates", {}).get(stage, 1.0))


def project(config: Path, costs: Dict[Group, Dict[str, float]]) -> Dict[str, Any]:
    """Expected and upper-bound CPU-hours of every job of ``config`` (see the module docstring); jobs of a group with
    nothing to borrow from are left out and counted under ``missing``."""
    total = upper = 0.0
    per_group: Dict[str, List[float]] = defaultdict(lambda: [0.0, 0.0])
    borrowed = set()
    missing: Dict[Group, int] = defaultdict(int)
    cfg = load_config(config)
    stages = cfg.attack["retry"]
    jobs = expand_jobs(cfg)

    def cost_of(spec: Dict[str, Any]) -> Optional[Dict[str, float]]:
        g = _group(spec)
        if g not in costs:
            borrowed.add(g)
        cost = _cost_of(g, costs)
        if cost is None:
            missing[g] += 1
        return cost

    for job in jobs:
        cost = cost_of(job)
        if cost is None:
            continue
        parts = [(job, *_seconds(job, cost))]
        share, parent = 1.0, job
        while (options := retry_options(stages, parent)) is not None:
            # the next stage's retry: at the measured failure rates of the stages before it, at most every time
            share *= _failure_rate(cost, retry_stage(parent))
            child = retry_spec(parent, "", options)
            child_cost = cost_of(child)
            if child_cost is None:
                break
            most = _seconds(child, child_cost)[1]
            parts.append((child, share * most, most))
            parent = child
        for spec, seconds, most in parts:
            total += seconds
            upper += most
            label = _label(spec)
            per_group[label][0] += seconds
            per_group[label][1] += most
    return {"config": str(config), "jobs": len(jobs), "cpu_hours": total / 3600.0, "upper_cpu_hours": upper / 3600.0,
            "groups": {k: (v[0] / 3600.0, v[1] / 3600.0) for k, v in sorted(per_group.items())},
            "borrowed": sorted(borrowed - set(missing)), "missing": dict(sorted(missing.items()))}


def main(argv: List[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--config", type=Path, nargs="+", required=True)
    parser.add_argument("--measure", action="store_true", help="run the sample jobs of the first config first")
    parser.add_argument("--per-group", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("out/cost"))
    parser.add_argument("--db", type=Path, nargs="+", default=None,
                        help="measured database(s) (default <out>/results.db)")
    args = parser.parse_args(argv)
    dbs = args.db or [args.out / "results.db"]
    if args.measure:
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        sample = sample_jobs(args.config[0], args.per_group)
        with ResultStore(dbs[0]) as store:
            run_sweep(store, sample, "meshadv.experiments.jobs:run_attack_job", out_root=args.out,
                      backend=SerialBackend(threads_per_job=1), max_attempts=1, progress=False)
    costs = measured(dbs)
    print("| victim | type | kind | update rule | attacks measured | CPU s per step and image | mean steps per round |")
    print("|---|---|---|---|---|---|---|")
    for (victim, ptype, kind, method), c in sorted(costs.items()):
        print(f"| {victim} | {ptype} | {kind} | {method} | {c['n']} | {c['per_step_image']:.3f} | {c['steps']:.0f} |")
    for config in args.config:
        p = project(config, costs)
        print(f"\n{p['config']}: {p['jobs']} jobs, {p['cpu_hours']:.1f} CPU-hours expected, "
              f"{p['upper_cpu_hours']:.1f} at most"
              + (f" (borrowed costs for {p['borrowed']})" if p["borrowed"] else ""))
        if p["missing"]:
            print("NOT COUNTED (no measurement with the same update rule): "
                  + ", ".join(f"{' '.join(g)}: {n} jobs" for g, n in p["missing"].items()))
        print("| group | expected CPU-hours | at most (full budget) |\n|---|---|---|")
        for label, (hours, most) in p["groups"].items():
            print(f"| {label} | {hours:.1f} | {most:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
