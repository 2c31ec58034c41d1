"""The paper's protocol (Adam + lambda binary search, 5 x 1000 steps, the attack's defaults) on ONE target of a
benchmark instance, built as ``benchmarks/convergence_bench.py`` builds it: does the reference method reach
``instance -> target`` at all? Prints one JSON line every 250 steps (margin now, best margin so far, steps held,
first step held, process CPU s) and one with the final result.

Usage: ``OMP_NUM_THREADS=1 RAYON_NUM_THREADS=1 python benchmarks/convergence/h1/paper_single.py bottle/1 bicycle``
"""
import json
import sys
import time
from pathlib import Path
from typing import Any, Dict

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import convergence_bench as cb  # noqa: E402
from meshadv.attacks import TargetedMisclassification  # noqa: E402
from meshadv.victims import load_victim  # noqa: E402


def main(instance: str, target: str) -> None:
    """Run the paper's protocol on ``instance`` (``class/index``) against ``target`` and print its progress."""
    mesh, views = cb.instance_scene(cb.instance_record(instance))
    victim = load_victim("efficientnet_lite0")
    state: Dict[str, Any] = {"step": 0, "best": -1e9, "held": 0, "first": None}
    start = time.process_time()

    def progress(info: Any) -> None:
        state["step"] += 1
        margin = float(info.margin[0])
        state["best"] = max(state["best"], margin)
        if margin > 0:
            state["held"] += 1
            state["first"] = state["first"] or state["step"]
        if state["step"] % 250 == 0:
            print(json.dumps({"step": state["step"], "margin": round(margin, 3), "best": round(state["best"], 3),
                              "held_steps": state["held"], "first": state["first"],
                              "cpu": round(time.process_time() - start)}), flush=True)

    result = cb.make_attack("paper", "shape")(mesh, views, victim, [TargetedMisclassification(target)],
                                              setup=cb.render_setup(), callback=progress)
    print(json.dumps({"instance": instance, "target": target, "steps_to_success": result.steps_to_success[0],
                      "distances": result.distances[0], "cpu": round(time.process_time() - start)}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
