"""The `-> bicycle` shape attacks of a sweep's configurations 0-1, one row per instance: the main ddn attack, its
retry and the paper's protocol side by side (benchmarks/RESULTS.md, "The bicycle misses: the paper's protocol
beside ddn").

    python benchmarks/bicycle_misses.py docs/results/paper_medium/results.db
"""

from __future__ import annotations

import argparse
import json
import sqlite3
from typing import Any, Dict, Optional, Tuple

QUERY = """select spec, record from jobs where state = 'done' and json_extract(spec, '$.perturbation') = 'shape'
  and json_extract(spec, '$.target') = ? and json_extract(spec, '$.victim') = ?
  and json_extract(spec, '$.kind') = 'single' and json_extract(spec, '$.config_index') < ?"""


def cell(record: Optional[Dict[str, Any]]) -> str:
    """One attack's outcome: reached (and the step of the first success), pair-mean Laplacian, largest vertex move
    as a share of the bounding-box diagonal, the victim's top-1 and the job's CPU seconds."""
    if record is None:
        return "-"
    d = record["distances"]
    reached = f"**yes** @{record['steps_to_success']}" if record["success"] else "no"
    return (f"{reached}, {d['laplacian_pair_mean']:.2g}, {100 * d['max_displacement']:.0f}%, "
            f"{record['adversarial_top1'][0]}, {record['cpu_time']:.0f} s")


def main() -> None:
    """Print the markdown table of the instances the paper's protocol has run."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("db", help="a sweep's results database")
    parser.add_argument("--target", default="bicycle")
    parser.add_argument("--victim", default="efficientnet_lite0")
    parser.add_argument("--configurations", type=int, default=2, help="configurations 0 .. N-1")
    args = parser.parse_args()
    rows = sqlite3.connect(args.db).execute(QUERY, (args.target, args.victim, args.configurations)).fetchall()
    by_instance: Dict[Tuple[str, int, str], Dict[str, Dict[str, Any]]] = {}
    for spec_text, record_text in rows:
        spec = json.loads(spec_text)
        key = (spec["source_class"], spec["config_index"], spec["mesh"]["path"])
        by_instance.setdefault(key, {})[spec.get("protocol", "main")] = json.loads(record_text)
    print("| instance (mesh) | ddn 300 steps (main) | ddn 1000 steps (retry) | paper's protocol (Adam, 5 x 1000) |")
    print("|---|---|---|---|")
    for (cls, config, path), runs in sorted(by_instance.items()):
        if "paper" in runs:
            print(f"| {cls}/{config} ({path.split('/')[-1]}) | {cell(runs.get('main'))} | {cell(runs.get('retry'))} "
                  f"| {cell(runs.get('paper'))} |")


if __name__ == "__main__":
    main()
