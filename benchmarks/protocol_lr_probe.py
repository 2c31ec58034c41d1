"""How much of the paper's protocol's distortion is its Adam learning rate? Re-run one protocol job of a sweep with
other learning rates.

The paper gives its optimiser (Adam, lambda by binary search, 5 rounds x 1000 steps) but not the learning rate.
``configs/paper_medium.toml`` runs the protocol with the attacks' default rates (shape 1e-3, texture 5e-2). Adam moves
every coordinate by about ``lr`` per step and the protocol does not stop early, so the rate sets a floor under the
result's distortion. This script takes one job of the sweep's protocol from its database, changes only
``attack.lr`` and runs it as the sweep would (:func:`meshadv.experiments.jobs.run_attack_job`), one JSON line per
rate:

    OMP_NUM_THREADS=1 RAYON_NUM_THREADS=1 python benchmarks/protocol_lr_probe.py docs/results/paper_medium/results.db \
        --source aeroplane --config 0 --perturbation texture --target boat --lr 0.005 0.01 \
        -o benchmarks/protocol_lr/texture_aeroplane0_boat.jsonl
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any, Dict, List

from meshadv.attacks.distances import PAPER_COMPARABLE
from meshadv.experiments import ResultStore
from meshadv.experiments.jobs import run_attack_job


def protocol_job(db: Path, protocol: str, source: str, config: int, perturbation: str,
                 target: str) -> Dict[str, Any]:
    """The spec and record of the protocol's job for that instance and target."""
    with ResultStore(db, read_only=True) as store:
        rows = [r for r in store.rows() if r.spec.get("protocol") == protocol and r.spec["source_class"] == source
                and r.spec.get("config_index") == config and r.spec["perturbation"] == perturbation
                and r.spec["target"] == target]
    if len(rows) != 1:
        raise SystemExit(f"expected one {protocol!r} job of {source}/{config} {perturbation} -> {target} in {db}, "
                         f"found {len(rows)}")
    return {"spec": rows[0].spec, "record": rows[0].record}


def summary(spec: Dict[str, Any], record: Dict[str, Any], **extra: Any) -> Dict[str, Any]:
    """One output line: the rate, the outcome and the distance in the paper's measure."""
    measure = PAPER_COMPARABLE[spec["perturbation"]]
    return {"lr": spec["attack"]["lr"], "success": record["success"], measure: record["distances"][measure],
            "largest_successful_lambda": record.get("lambda_perceptual"),
            "steps_to_success": record.get("steps_to_success"), **extra}


def main(argv: List[str] = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("db", type=Path, help="the sweep's results database")
    parser.add_argument("--protocol", default="paper")
    parser.add_argument("--source", required=True, help="source class")
    parser.add_argument("--config", type=int, required=True, help="rendering configuration index")
    parser.add_argument("--perturbation", choices=("shape", "texture"), required=True)
    parser.add_argument("--target", required=True)
    parser.add_argument("--lr", type=float, nargs="+", required=True, help="learning rates to run")
    parser.add_argument("-o", "--out", type=Path, help="append the JSON lines here too")
    args = parser.parse_args(argv)
    job = protocol_job(args.db, args.protocol, args.source, args.config, args.perturbation, args.target)
    lines = [summary(job["spec"], job["record"], run="stored", cpu_s=job["record"].get("cpu_time"))]
    for lr in args.lr:
        spec = json.loads(json.dumps(job["spec"]))
        spec["attack"]["lr"] = lr
        cpu = time.process_time()
        with tempfile.TemporaryDirectory() as out_dir:
            record = run_attack_job(spec, Path(out_dir))
        lines.append(summary(spec, record, run="probe", cpu_s=time.process_time() - cpu))
    for line in lines:
        text = json.dumps({"instance": f"{args.source}/{args.config}", "perturbation": args.perturbation,
                           "target": args.target, **line})
        print(text, flush=True)
        if args.out is not None:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            with open(args.out, "a", encoding="utf-8") as fh:
                fh.write(text + "\n")


if __name__ == "__main__":
    main()
