"""Can a hard shape target be reached at all within the step budget, at any distortion? (issue 14, eighth session)

The ddn misses (``<instance> -> bicycle``) could be out of reach in 300 steps for any attack, or only for attacks
that keep the distortion small. This runs the least constrained shape attack there is: Adam on the raw vertex flow
(``smoothing=0``; or on the flow smoothed by ``SMOOTHING``), no perceptual term (``lambda_perceptual=0``), no early
stop, one target alone, at a given learning rate, and prints the first step that held, the best margin of any step,
the largest vertex displacement of the returned mesh (percent of the bounding-box diagonal) and the CPU seconds. The
instance and view are the convergence benchmark's.

Usage (1 thread, as the benchmark):
    OMP_NUM_THREADS=1 RAYON_NUM_THREADS=1 python benchmarks/convergence/h1/reach_unconstrained.py diningtable/1 \
        bicycle 0.001,0.003,0.01 300 [SMOOTHING]
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any, List

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import convergence_bench as cb  # noqa: E402
from meshadv.attacks import TargetedMisclassification, make_attack  # noqa: E402
from meshadv.victims import load_victim  # noqa: E402


def main(argv: List[str]) -> None:
    """``INSTANCE TARGET LRS STEPS [SMOOTHING]``: print one JSON line per learning rate."""
    if len(argv) not in (4, 5):
        raise SystemExit(__doc__)
    inst, target, lrs, steps = argv[0], argv[1], [float(s) for s in argv[2].split(",")], int(argv[3])
    smoothing = int(argv[4]) if len(argv) == 5 else 0
    mesh, views = cb.instance_scene(cb.instance_record(inst))
    victim = load_victim("efficientnet_lite0")
    diagonal = float((mesh.vertices.max(0).values - mesh.vertices.min(0).values).norm())
    for lr in lrs:
        best = [-float("inf")]

        def track(info: Any) -> None:
            best[0] = max(best[0], info.margin[0])

        attack = make_attack("shape", steps=steps, lr=lr, lambda_perceptual=0.0, smoothing=smoothing)
        cpu = time.process_time()
        result = attack(mesh, views, victim, [TargetedMisclassification(target)], setup=cb.render_setup(),
                        callback=track)
        moved = (result.adversarial[0].vertices - mesh.vertices).norm(dim=-1).max()
        print(json.dumps({"instance": inst, "target": target, "lr": lr, "steps": steps, "smoothing": smoothing,
                          "steps_to_success": result.steps_to_success[0],
                          "best_margin": round(best[0], 3),
                          "max_displacement_pct": round(100 * float(moved) / diagonal, 2),
                          "cpu_s": round(time.process_time() - cpu, 1)}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
