"""How small can the demo's perturbation be? (issue 18: "a perturbation one has to look for").

Runs the demo's attack (``meshadv.commands.demo``: its subjects, views, runner-up target and
:func:`~meshadv.commands.demo.build_demo_attack`) on the shared PASCAL3D+ chair and on the built-in sofa, with the
mesh as loaded or subdivided, Adam at several learning rates, and the distortion-budget method (``method="ddn"``),
and prints one JSON row per variant: success, steps run, first successful step, the largest vertex move as % of the
bounding-box diagonal, the Laplacian (pair mean) and the attack's process CPU seconds (1 thread).

Usage:
    OMP_NUM_THREADS=1 RAYON_NUM_THREADS=1 python3 benchmarks/demo_perturbation_bench.py [--json OUT.json] [--only I ...]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any, Dict, List, Optional

#: The variants: subject (chair / sofa), max_edge (0: the mesh as loaded, None: the subject's own subdivision),
#: method (adam: the demo's former attack at ``lr``; ddn: with ``options``, ``{}`` being the demo's own attack), the
#: most steps, and ``margin`` (the target must
#: lead by that many logits on every view: :class:`~meshadv.attacks.WithMargin`; absent: no margin).
VARIANTS: List[Dict[str, Any]] = [
    {"subject": "chair", "max_edge": 0, "method": "adam", "lr": 5e-3, "steps": 100},
    {"subject": "chair", "max_edge": 0, "method": "adam", "lr": 1e-3, "steps": 200},
    {"subject": "chair", "max_edge": 0, "method": "ddn", "steps": 200,
     "options": {"init_budget": 1e-2, "step_size": 1e-2, "final_step_size": 1e-3}},
    {"subject": "chair", "max_edge": 0.25, "method": "adam", "lr": 1e-3, "steps": 100},
    {"subject": "chair", "max_edge": 0.15, "method": "adam", "lr": 2e-3, "steps": 100},
    {"subject": "chair", "max_edge": 0.15, "method": "adam", "lr": 1e-3, "steps": 100},
    {"subject": "chair", "max_edge": 0.15, "method": "adam", "lr": 5e-4, "steps": 100},
    {"subject": "chair", "max_edge": 0.15, "method": "ddn", "steps": 100, "options": {}},
    {"subject": "chair", "max_edge": 0.1, "method": "adam", "lr": 1e-3, "steps": 100},
    {"subject": "sofa", "max_edge": None, "method": "adam", "lr": 1e-3, "steps": 100},
    {"subject": "chair", "max_edge": None, "method": "ddn", "steps": 100, "options": {}, "margin": 0.5},
    {"subject": "sofa", "max_edge": None, "method": "ddn", "steps": 100, "options": {}, "margin": 0.5},
    {"subject": "sofa", "max_edge": None, "method": "ddn", "steps": 100, "options": {}},
]


def run_variant(variant: Dict[str, Any], cache: Dict[str, Any]) -> Dict[str, Any]:
    """Attack one variant; return its row."""
    import torch

    from meshadv.attacks import ShapeAttack, TargetedMisclassification, WithMargin
    from meshadv.commands._common import DEFAULT_DISTANCE, DEFAULT_ELEVATION, load_mesh_input, make_views
    from meshadv.commands.demo import BUILTIN_SOFA, SHARED_CHAIR, build_demo_attack, pick_target, subdivide
    from meshadv.render import RenderSetup, render_views
    from meshadv.victims import load_victim

    subject = SHARED_CHAIR if variant["subject"] == "chair" else BUILTIN_SOFA
    if "victim" not in cache:
        cache["victim"] = load_victim("efficientnet_lite0")
    victim = cache["victim"]
    mesh = load_mesh_input(subject.mesh).mesh
    max_edge: Optional[float] = subject.max_edge if variant["max_edge"] is None else variant["max_edge"]
    if max_edge:
        mesh = subdivide(mesh, max_edge)
    views = make_views(2, subject.azimuths, DEFAULT_ELEVATION, DEFAULT_DISTANCE)
    setup = RenderSetup(image_size=subject.image_size)
    torch.manual_seed(0)
    with torch.no_grad():
        images, _ = render_views(mesh.vertices.unsqueeze(0), mesh.faces, mesh.face_colors, views, setup)
        top1, runner_up = pick_target(victim(images))
    if variant["method"] == "adam":  # the demo's attack until the twenty-second session
        attack = ShapeAttack(steps=variant["steps"], lr=variant["lr"], lambda_perceptual=0.01, loss="cw",
                             early_stop=2, early_stop_margin=0.5, seed=0)
    elif not variant["options"]:
        attack = build_demo_attack(variant["steps"], 0)
    else:
        attack = ShapeAttack(steps=variant["steps"], loss="cw", method="ddn", method_options=variant["options"],
                             seed=0)
    criterion: Any = TargetedMisclassification(runner_up)
    if variant.get("margin"):
        criterion = WithMargin(criterion, variant["margin"])
    cpu = time.process_time()
    result = attack(mesh, views, victim, [criterion], setup=setup)
    cpu = time.process_time() - cpu
    d = result.distances[0]
    names = list(victim.class_names)
    return {**variant, "faces": int(mesh.faces.shape[0]), "pristine_top1": names[top1], "target": names[runner_up],
            "success": bool(result.succeeded[0]), "steps_run": int(result.steps),
            "first_success_step": result.steps_to_success[0], "max_displacement_pct": 100 * d["max_displacement"],
            "laplacian_pair_mean": d.get("laplacian_pair_mean"), "attack_cpu_s": round(cpu, 2)}


def main() -> None:
    """Run every variant and print / store the rows."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=None, help="also write the rows to this JSON file")
    parser.add_argument("--only", type=int, nargs="+", default=None, metavar="I",
                        help="run only these variants (indices into VARIANTS)")
    args = parser.parse_args()
    from meshadv.threads import apply_threads

    apply_threads(1)
    cache: Dict[str, Any] = {}
    rows = []
    chosen = VARIANTS if args.only is None else [VARIANTS[i] for i in args.only]
    for variant in chosen:
        row = run_variant(dict(variant), cache)
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
