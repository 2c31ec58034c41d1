"""Attack benchmark: optimiser steps per second and time to first success, one target vs batched targets.

Real meshes (shared PASCAL3D+ models) and a real victim (EfficientNet-Lite0). For each mesh and perturbation:

* throughput: ``--steps`` Adam steps (no early stopping) with 1 target, then with ``--targets`` targets batched;
  reports steps/s and target-steps/s (targets x steps per second);
* time to success: the ``--targets`` classes the pristine renders rank 2nd, 3rd, ... attacked one at a time
  (sum of wall times) and all together as a batch (one wall time), with early stopping; reports the time until
  every target held, and how many did within ``--max-steps``.

Usage:
    python benchmarks/attack_bench.py --meshes chair/01 sofa/01 --views 5 --image-size 160 --targets 4 \\
        --out benchmarks/attack_bench.json

Prints a Markdown table (paste it into benchmarks/RESULTS.md with the command line) and writes a JSON record.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path
from typing import Any, Dict, List

import torch


def _ranked_classes(mesh: Any, views: Any, victim: Any, image_size: int, count: int) -> List[int]:
    """Classes ranked 2nd..count+1 by the mean softmax of the pristine renders."""
    from meshadv.attacks.base import render_views

    with torch.no_grad():
        images, _ = render_views(
            mesh.vertices.unsqueeze(0),
            mesh.faces,
            mesh.face_colors,
            views,
            image_size=image_size,
            background=(1.0, 1.0, 1.0),
        )
        probs = torch.softmax(victim(images), dim=1).mean(dim=0)
    return [int(i) for i in probs.topk(count + 1).indices.tolist()[1:]]


def _make_attack(perturb: str, **kwargs: Any) -> Any:
    from meshadv.attacks import ShapeAttack, TextureAttack

    if perturb == "shape":
        return ShapeAttack(lr=5e-3, lambda_perceptual=0.01, loss="cw", **kwargs)
    return TextureAttack(lr=0.1, lambda_perceptual=1e-4, loss="cw", **kwargs)


def bench_case(mesh_name: str, perturb: str, args: argparse.Namespace, victim: Any) -> Dict[str, Any]:
    """Benchmark one mesh and perturbation; returns a JSON-able record."""
    from meshadv.attacks import TargetedMisclassification
    from meshadv.data import require_shared_data
    from meshadv.mesh import load_mesh, normalize_mesh
    from meshadv.render import ViewSet

    mesh = normalize_mesh(load_mesh(require_shared_data(f"pascal3d/{mesh_name}.ply")), z_up=True)[0]
    views = ViewSet.orbit(
        torch.linspace(165.0, 195.0, args.views) if args.views > 1 else torch.tensor([180.0]),
        elevation=15.0,
        distance=4.5,
    )
    targets = _ranked_classes(mesh, views, victim, args.image_size, args.targets)
    crits = [TargetedMisclassification(t) for t in targets]
    record: Dict[str, Any] = {
        "mesh": mesh_name,
        "perturb": perturb,
        "faces": mesh.num_faces,
        "views": args.views,
        "image_size": args.image_size,
        "targets": targets,
    }

    # throughput
    for label, crit in (("single", crits[:1]), ("batched", crits)):
        attack = _make_attack(perturb, steps=args.steps, image_size=args.image_size)
        if label == "single" and args.warmup:
            attack(mesh, views, victim, crit)
        t0 = time.perf_counter()
        result = attack(mesh, views, victim, crit)
        dt = time.perf_counter() - t0
        record[f"{label}_steps_per_s"] = result.steps / dt
        record[f"{label}_target_steps_per_s"] = result.steps * len(crit) / dt

    # time to success
    seq_time, seq_ok, seq_first = 0.0, 0, []
    for crit in crits:
        attack = _make_attack(perturb, steps=args.max_steps, early_stop=1, image_size=args.image_size)
        t0 = time.perf_counter()
        result = attack(mesh, views, victim, crit)
        seq_time += time.perf_counter() - t0
        seq_ok += int(result.succeeded[0])
        seq_first.append(result.time_to_success[0])
    attack = _make_attack(perturb, steps=args.max_steps, early_stop=1, image_size=args.image_size)
    t0 = time.perf_counter()
    result = attack(mesh, views, victim, crits)
    record.update(
        sequential_time_s=seq_time,
        sequential_successes=seq_ok,
        sequential_first_success_s=seq_first,
        batched_time_s=time.perf_counter() - t0,
        batched_successes=int(result.succeeded.sum()),
        batched_first_success_s=list(result.time_to_success),
    )
    return record


def main(argv: List[str]) -> int:
    """Run the benchmark (see the module docstring for the options)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", nargs="+", default=["chair/01", "sofa/01"], help="PASCAL3D+ class/model")
    parser.add_argument("--perturb", nargs="+", default=["shape", "texture"], choices=["shape", "texture"])
    parser.add_argument("--victim", default="efficientnet_lite0")
    parser.add_argument("--views", type=int, default=5)
    parser.add_argument("--image-size", type=int, default=160)
    parser.add_argument("--targets", type=int, default=4)
    parser.add_argument("--steps", type=int, default=10, help="steps of the throughput runs")
    parser.add_argument("--max-steps", type=int, default=200, help="step limit of the time-to-success runs")
    parser.add_argument("--warmup", action="store_true", help="one untimed run first")
    parser.add_argument("--out", type=Path, default=None, help="JSON output file")
    args = parser.parse_args(argv)

    from meshadv.victims import load_victim

    torch.manual_seed(0)
    victim = load_victim(args.victim)
    records = [bench_case(m, p, args, victim) for m in args.meshes for p in args.perturb]
    command = "python benchmarks/attack_bench.py " + " ".join(argv)
    print(f"command: {command}")
    print(f"machine: {platform.processor() or platform.machine()}, torch threads {torch.get_num_threads()}")
    print(
        "| mesh | faces | perturb | views x px | steps/s 1 target | steps/s {T} targets | target-steps/s "
        "1 vs {T} | time to all successes: sequential | batched |".replace("{T}", str(args.targets))
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for r in records:
        print(
            f"| {r['mesh']} | {r['faces']} | {r['perturb']} | {r['views']} x {r['image_size']} | "
            f"{r['single_steps_per_s']:.2f} | {r['batched_steps_per_s']:.2f} | "
            f"{r['single_target_steps_per_s']:.2f} vs {r['batched_target_steps_per_s']:.2f} | "
            f"{r['sequential_time_s']:.1f} s ({r['sequential_successes']}/{args.targets}) | "
            f"{r['batched_time_s']:.1f} s ({r['batched_successes']}/{args.targets}) |"
        )
    if args.out is not None:
        args.out.write_text(
            json.dumps({"command": command, "torch_threads": torch.get_num_threads(), "records": records}, indent=2)
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
