"""Does a variant of ``meshadv demo``'s attack hold on the demo's held-out views inside the default cap?

One run per invocation: the demo's subject (``default``: the shared PASCAL3D+ chair when the data are there, else
the built-in sofa; or ``builtin:sofa``), subdivided as the demo does, attacked with the demo's ddn + C&W attack under
the default perceptibility cap and the 0.8 held-out verdict, optionally as the robust attack (``--eot N``:
``robust_options("shape", "ddn", samples=N)``), on ``--views`` views over the subject's azimuths, towards the
pristine runner-up or ``--target``. Prints one JSON line: held-out rate and scores, the views' rate, the largest move
and the normals' 95th percentile, the attack's wall time. Threads: one (torch and the renderer).

Example:
    MESHADV_DATA=../shared/data python benchmarks/demo_held_out.py --mesh default --eot 4 --steps 100
"""

from __future__ import annotations

import argparse
import json
import os
import time
from typing import List, Optional

os.environ.setdefault("RAYON_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")


def main(argv: Optional[List[str]] = None) -> None:
    """Parse the arguments, run one attack and print its JSON line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", default="default", help="the demo's --mesh (default or builtin:sofa)")
    parser.add_argument("--eot", type=int, default=0, help="robust attack with this many views per step (0: off)")
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--views", type=int, default=2, help="attack views over the subject's azimuth range")
    parser.add_argument("--target", default=None, help="target class (default: the pristine runner-up)")
    args = parser.parse_args(argv)

    import torch

    from meshadv.attacks import ShapeAttack, TargetedMisclassification
    from meshadv.attacks.robust_settings import robust_options
    from meshadv.commands._common import DEFAULT_DISTANCE, DEFAULT_ELEVATION, load_mesh_input, make_views
    from meshadv.commands.demo import demo_subject, pick_target, subdivide
    from meshadv.perceptibility import held_out_views
    from meshadv.render import RenderSetup, render_views
    from meshadv.victims import load_victim

    torch.set_num_threads(1)
    subject = demo_subject(args.mesh)
    mesh = load_mesh_input(subject.mesh).mesh
    if subject.max_edge is not None:
        mesh = subdivide(mesh, subject.max_edge)
    model = load_victim("efficientnet_lite0")
    views = make_views(args.views, subject.azimuths, DEFAULT_ELEVATION, DEFAULT_DISTANCE)
    setup = RenderSetup(image_size=subject.image_size)
    with torch.no_grad():
        images, _ = render_views(mesh.vertices.unsqueeze(0), mesh.faces, mesh.face_colors, views, setup)
        _, runner_up = pick_target(model(images))
    goal = args.target or model.class_names[runner_up]
    robust = robust_options("shape", "ddn", samples=args.eot) if args.eot else {}
    attack = ShapeAttack(steps=args.steps, loss="cw", method="ddn", seed=0, perceptibility_cap="default",
                         held_out_fraction=0.8, **robust)
    start = time.perf_counter()
    result = attack(mesh, views, model, [TargetedMisclassification(goal)], eval_views=held_out_views(views),
                    setup=setup)
    print(json.dumps({
        "mesh": args.mesh, "eot": args.eot, "steps": args.steps, "views": args.views, "target": goal,
        "attack_s": round(time.perf_counter() - start, 1), "succeeded": bool(result.succeeded[0]),
        "views_rate": float(result.success_rate[0]), "held_out_rate": float(result.held_out_rate[0]),
        "held_out_scores": [round(float(x), 3) for x in result.eval_scores[0]],
        "max_displacement": result.distances[0]["max_displacement"],
        "normal_change_p95_deg": result.distances[0]["normal_change_p95_deg"],
    }))


if __name__ == "__main__":
    main()
