"""Attack benchmark: optimiser steps per second and time to first success, one target vs batched targets.

Real meshes (shared PASCAL3D+ models) and a real victim (EfficientNet-Lite0). For each mesh and perturbation:

* throughput: ``--steps`` Adam steps (no early stopping) with 1 target, then with ``--targets`` targets batched;
  reports steps/s and target-steps/s (targets x steps per second);
* time to success: the ``--targets`` classes the pristine renders rank 2nd, 3rd, ... attacked one at a time
  (sum of wall times) and all together as a batch (one wall time), with early stopping; reports the time until
  every target held, and how many did within ``--max-steps``.

With ``--split`` only one attack step's parts are timed, per mesh and perturbation, with ``--targets`` targets
batched (``targets x views`` images, ``--antialias`` supersampling; wall time, or process CPU time with
``--cpu-time``): the render's forward, the victim's forward + input gradient, the render's backward (median of
``--steps`` steps after one warm-up); it reports the renderer's share of the step and target-steps/s beside the
victim-alone ceiling (the victim's forward + input gradient on random images of the same batch and memory layout as
the renders: what a step would cost with a free renderer). Run it once per build (old and new extension) to compare
them side by side.
``--device cuda`` runs the victim on a GPU while meshes and rendering stay on the CPU (the attacks' GPU-victim path:
each batch of renders and its cotangent cross once per step); times are wall times, with the GPU synchronised before
each clock reading. ``benchmarks/gpu_victim_kit.py`` runs it on a lent GPU machine in one call.
``--victim-optimize both`` times the victim as its weights describe it (``load_victim(..., optimize=False)``) and
optimised (the default) in the same run, their steps interleaved, one table row each.

With ``--convergence`` only the shape attack's time to success is measured, for every combination of
``--smoothing`` (rounds of neighbour averaging of the flow, 0 = the paper's per-vertex flow) and ``--shape-lr``: each
target is attacked alone for up to ``--max-steps`` steps, stopping at the first step where it holds on every view
(early stopping is the first success, so a run also tells how many steps a smaller budget would have needed);
reports successes within each of ``--budgets`` steps, the steps to success and the Laplacian / displacement of the
applied flow at success.

With ``--split --whole-steps`` a whole step (render, victim, objective, render backward; the attack's own step
code, Adam's objective, no update) is timed instead, wall time, for each variant in one run with the variants
interleaved in bursts of ``--burst`` consecutive steps (the first of a burst not recorded): ``serial tN`` (torch and
the renderer on N threads, for each N of ``--torch-threads``) and ``old serial tN`` (the step with the render as
the PyTorch composition of camera, shading and rasterizer and the antialias pooling by ``F.avg_pool2d``). The
victim-alone ceilings are timed the same way, at each of ``--torch-threads``. The renderer share is the part of
the step's wall time not hidden behind the victim: ``1 - victim alone (same threads) / step``. ``--attack-steps N``
adds whole attacks (``ShapeAttack`` / ``TextureAttack`` of N steps, no early stop) per variant, alternating, and
reports their target-steps/s.

``--pool-bench`` times only the antialias pooling, forward and backward, the renderer's box filter against
torch's ``F.avg_pool2d`` (batch ``--targets x --views``, ``--image-size`` times ``--antialias`` pixels, RGBA, one
torch thread, wall time, median of ``--steps`` interleaved repetitions).

Usage:
    python benchmarks/attack_bench.py --meshes chair/01 sofa/01 --views 5 --image-size 160 --targets 4 \\
        --out benchmarks/attack_bench.json
    python benchmarks/attack_bench.py --convergence --meshes chair/01 sofa/01 --views 2 --image-size 128 \\
        --targets 3 --max-steps 200 --budgets 60 200 --smoothing 0 8 --shape-lr 5e-3 2e-2
    python benchmarks/attack_bench.py --split --meshes aeroplane/03 --views 1 --image-size 224 --antialias 2 \\
        --targets 6 --steps 10
    python benchmarks/attack_bench.py --split --whole-steps --torch-threads 1 2 --meshes aeroplane/03 --views 1 \\
        --image-size 224 --antialias 2 --targets 6 --steps 10 --attack-steps 10

Prints a Markdown table (paste it into benchmarks/RESULTS.md with the command line) and writes a JSON record.
"""

from __future__ import annotations

import argparse
import json
import os

# idle OpenMP threads sleep instead of spinning (as the meshadv command sets them); read when torch loads
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
os.environ.setdefault("KMP_BLOCKTIME", "0")
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple

import torch

from meshadv.render import RenderSetup, render_views


def _ranked_classes(mesh: Any, views: Any, victim: Any, image_size: int, count: int) -> List[int]:
    """Classes ranked 2nd..count+1 by the mean softmax of the pristine renders."""
    with torch.no_grad():
        images, _ = render_views(mesh.vertices.unsqueeze(0), mesh.faces, mesh.face_colors, views,
                                 RenderSetup(image_size=image_size))
        probs = torch.softmax(victim(images), dim=1).mean(dim=0)
    return [int(i) for i in probs.topk(count + 1).indices.tolist()[1:]]


def _make_attack(perturb: str, *, smoothing: Optional[int] = None, shape_lr: Optional[float] = None,
                 **kwargs: Any) -> Any:
    from meshadv.attacks import ShapeAttack, TextureAttack

    if perturb == "shape":
        extra: Dict[str, Any] = {} if smoothing is None else {"smoothing": smoothing}
        lr = 5e-3 if shape_lr is None else shape_lr
        return ShapeAttack(lr=lr, lambda_perceptual=0.01, loss="cw", **extra, **kwargs)
    return TextureAttack(lr=0.1, lambda_perceptual=1e-4, loss="cw", **kwargs)


def _scene(mesh_name: str, args: argparse.Namespace) -> Tuple[Any, Any]:
    """The normalised shared mesh ``pascal3d/<mesh_name>.ply`` and ``args.views`` victim views around its front."""
    from meshadv.data import require_shared_data
    from meshadv.mesh import load_mesh, normalize_mesh
    from meshadv.render import ViewSet

    mesh = normalize_mesh(load_mesh(require_shared_data(f"pascal3d/{mesh_name}.ply")), z_up=True)[0]
    views = ViewSet.orbit(
        torch.linspace(165.0, 195.0, args.views) if args.views > 1 else torch.tensor([180.0]),
        elevation=15.0,
        distance=4.5,
    )
    return mesh, views


def _setup(mesh_name: str, args: argparse.Namespace, victim: Any) -> Tuple[Any, Any, List[int]]:
    """The normalised shared mesh, the victim views and the runner-up target classes."""
    mesh, views = _scene(mesh_name, args)
    return mesh, views, _ranked_classes(mesh, views, victim, args.image_size, args.targets)


def convergence_case(mesh_name: str, smoothing: int, lr: float, args: argparse.Namespace,
                     victim: Any) -> Dict[str, Any]:
    """Shape attack time to success of each runner-up target alone, for one smoothing and learning rate."""
    from meshadv.attacks import TargetedMisclassification

    mesh, views, targets = _setup(mesh_name, args, victim)
    runs = []
    t_case = time.perf_counter()
    for target in targets:
        attack = _make_attack("shape", smoothing=smoothing, shape_lr=lr, steps=args.max_steps, early_stop=1)
        t0 = time.perf_counter()
        result = attack(mesh, views, victim, TargetedMisclassification(target),
                        setup=RenderSetup(image_size=args.image_size))
        runs.append({
            "target": target,
            "succeeded": bool(result.succeeded[0]),
            "steps_to_success": result.steps_to_success[0] if bool(result.succeeded[0]) else None,
            "steps": result.steps,
            "time_s": time.perf_counter() - t0,
            "distances": dict(result.distances[0]),
        })
    return {"mesh": mesh_name, "faces": mesh.num_faces, "smoothing": smoothing, "lr": lr, "views": args.views,
            "image_size": args.image_size, "max_steps": args.max_steps, "targets": targets, "runs": runs,
            "time_s": time.perf_counter() - t_case}


def _median(values: List[float]) -> Optional[float]:
    return float(statistics.median(values)) if values else None


def _fmt(value: Optional[float], spec: str) -> str:
    return "-" if value is None else format(value, spec)


def print_convergence(records: List[Dict[str, Any]], budgets: List[int]) -> None:
    """Markdown table of the convergence records."""
    heads = " | ".join(f"success <= {b} steps" for b in budgets)
    print(f"| mesh | smoothing | lr | {heads} | steps to success | Laplacian (median) | max / mean displacement "
          "(median, x bbox diagonal) | time |")
    print("|---|---|---|" + "---|" * len(budgets) + "---|---|---|---|")
    for r in records:
        runs = r["runs"]
        ok = [run for run in runs if run["succeeded"]]
        counts = " | ".join(
            f"{sum(1 for run in ok if run['steps_to_success'] <= b)}/{len(runs)}" for b in budgets
        )
        steps = ", ".join("-" if run["steps_to_success"] is None else str(run["steps_to_success"]) for run in runs)
        lap = _median([run["distances"]["laplacian_sum"] for run in ok])
        dmax = _median([run["distances"]["max_displacement"] for run in ok])
        dmean = _median([run["distances"]["mean_displacement"] for run in ok])
        print(f"| {r['mesh']} | {r['smoothing']} | {r['lr']:g} | {counts} | {steps} | {_fmt(lap, '.3g')} | "
              f"{_fmt(dmax, '.3f')} / {_fmt(dmean, '.4f')} | {r['time_s']:.0f} s |")


def victim_images_per_s(victim: Any, batch: int, image_size: int, repeats: int = 5,
                        clock: Callable[[], float] = time.perf_counter, like: Optional[torch.Tensor] = None) -> float:
    """Images per second of the victim's forward + backward (w.r.t. the input) on a batch of random renders.

    The ratio between ``batch = T x V`` and ``batch = V`` is the ceiling of what batching T targets can gain when the
    victim dominates a step (the renderer and the optimiser are a few percent of it). ``like``: a rendered batch whose
    memory layout the random images copy (the renderer hands out channels-innermost views of its RGBA buffer, on which
    torch runs the convolutions channels-last; contiguous NCHW images would time another code path).
    """
    if like is None:
        images = torch.rand(batch, 3, image_size, image_size)
    else:
        images = torch.empty_strided(like.shape, like.stride()).uniform_()
    times = []
    for i in range(repeats + 1):
        x = images.clone().requires_grad_(True)
        t0 = clock()
        out = victim(x)
        logits = out if isinstance(out, torch.Tensor) else out[0]
        logits.float().sum().backward()
        _synchronize(victim)
        if i > 0:  # the first call warms up
            times.append(clock() - t0)
    return batch / statistics.median(times)


def _synchronize(victim: Any) -> None:
    """Waits for the victim's GPU work (if it runs on one), so that a wall-clock reading after it includes it."""
    device = getattr(victim, "device", torch.device("cpu"))
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _diverged(rows: torch.Tensor) -> torch.Tensor:
    """``rows`` (one per target) moved apart by a small random flow (1e-3 per coordinate, seeded): a shape attack's
    targets have meshes of their own after its first step, and the rasterizer draws a batch element whose vertices
    repeat an earlier one's only once, so identical rows would time a step no shape attack takes."""
    g = torch.Generator().manual_seed(0)
    return rows + 1e-3 * torch.randn(rows.shape, generator=g, dtype=rows.dtype)


def step_split(mesh_name: str, perturb: str, args: argparse.Namespace,
               victims: Dict[str, Any]) -> List[Dict[str, Any]]:
    """Times the parts of one attack step (render forward, victim forward + input gradient, render backward) with
    ``args.targets`` targets batched, for each of ``victims`` (label -> victim; their steps interleaved); returns one
    JSON-able record (median seconds per part) per victim."""

    mesh, views = _scene(mesh_name, args)
    setup = RenderSetup(image_size=args.image_size, antialias=args.antialias)
    t = args.targets
    verts = mesh.vertices.unsqueeze(0).repeat(t, 1, 1)
    if perturb == "shape":
        verts = _diverged(verts)
    colors = mesh.face_colors.unsqueeze(0).repeat(t, 1, 1)
    param = verts if perturb == "shape" else colors
    param.requires_grad_(True)
    parts = {label: {"render_fwd": [], "victim": [], "render_bwd": []} for label in victims}
    images = None
    clock = time.process_time if args.cpu_time else time.perf_counter
    for step in range(args.steps + 1):
        for label, victim in victims.items():
            t0 = clock()
            images, _ = setup.render(verts, mesh.faces, colors, views,
                                     visibility_gradient=args.visibility_gradient)
            t1 = clock()
            x = images.detach().requires_grad_(True)
            out = victim(x)
            logits = out if isinstance(out, torch.Tensor) else out[0]
            (logits[:, 1].sum() - logits[:, 0].sum()).backward()
            _synchronize(victim)
            t2 = clock()
            images.backward(x.grad)
            t3 = clock()
            param.grad = None
            if step > 0:  # the first step warms up
                for key, dt in zip(parts[label], (t1 - t0, t2 - t1, t3 - t2)):
                    parts[label][key].append(dt)
    records = []
    for label, victim in victims.items():
        med = {key: float(statistics.median(v)) for key, v in parts[label].items()}
        step_s = sum(med.values())
        ceiling = victim_images_per_s(victim, t * args.views, args.image_size, clock=clock, like=images) / args.views
        records.append({"mesh": mesh_name, "faces": mesh.num_faces, "perturb": perturb, "victim": label,
                        "device": _device_name(victim.device),
                        "views": args.views, "image_size": args.image_size, "antialias": args.antialias,
                        "targets": t, "cpu_time": args.cpu_time, **{f"{k}_s": v for k, v in med.items()},
                        "step_s": step_s, "render_share": (med["render_fwd"] + med["render_bwd"]) / step_s,
                        "target_steps_per_s": t / step_s, "victim_ceiling_target_steps_per_s": ceiling})
    return records


def _old_downsample(t: torch.Tensor, k: int, num_threads: int = 0) -> torch.Tensor:
    """The antialias pooling done by torch instead of the box filter: ``F.avg_pool2d`` on the channels-last view."""
    import torch.nn.functional as F

    t = t.permute(0, 3, 1, 2)
    return t if k == 1 else F.avg_pool2d(t, kernel_size=k, stride=k)


class _Variant:
    """One way of running a step: at ``threads`` torch threads; ``old_pool``: the render as the PyTorch composition
    (camera, shading, rasterize) with the antialias pooling by ``F.avg_pool2d``, not the native flat op."""

    def __init__(self, label: str, threads: int, old_pool: bool = False) -> None:
        self.label, self.threads, self.old_pool = label, threads, old_pool

    def __enter__(self) -> "_Variant":
        from meshadv.render import renderer

        torch.set_num_threads(self.threads)
        self._saved = renderer._downsample, renderer.supports_flat_render
        if self.old_pool:
            renderer._downsample = _old_downsample
            renderer.supports_flat_render = lambda *args: False
        return self

    def __exit__(self, *exc: Any) -> None:
        from meshadv.render import renderer

        renderer._downsample, renderer.supports_flat_render = self._saved


def _variants(args: argparse.Namespace) -> List[_Variant]:
    out = []
    for n in args.torch_threads:
        out.append(_Variant(f"old serial t{n}", n, old_pool=True))
        out.append(_Variant(f"serial t{n}", n))
    return out


def pipeline_split(mesh_name: str, perturb: str, args: argparse.Namespace, victim: Any) -> Dict[str, Any]:
    """Wall time of whole attack steps (the attack's own step code) per variant, steps interleaved, beside the
    victim-alone ceilings; optionally whole attacks' target-steps/s. Returns a JSON-able record."""
    from meshadv.attacks import TargetedMisclassification
    from meshadv.attacks.loop import AttackCall, attack_step
    from meshadv.attacks.update import make_update_rule
    from meshadv.mesh.adjacency import vertex_edges

    mesh, views = _scene(mesh_name, args)
    setup = RenderSetup(image_size=args.image_size, antialias=args.antialias)
    t, num_v = args.targets, args.views
    attack = _make_attack(perturb, steps=1)
    call = AttackCall(mesh, views.detach(), victim, setup, vertex_edges(mesh.faces).long())
    crits = [TargetedMisclassification(c).bind(victim) for c in range(1, t + 1)]
    rule = make_update_rule("adam", attack=attack, num_targets=t)
    params = attack.initial_params(mesh, t).detach().clone()
    if perturb == "shape":
        params = _diverged(params)
    params.requires_grad_(True)
    rule.start_round(params)
    idx = torch.arange(t)
    variants = _variants(args)
    steps: Dict[str, List[float]] = {v.label: [] for v in variants}
    cpu: Dict[str, List[float]] = {v.label: [] for v in variants}
    ceil: Dict[str, List[float]] = {}
    like = setup.render(mesh.vertices.unsqueeze(0).repeat(t, 1, 1), mesh.faces, mesh.face_colors, views)[0]

    def victim_alone(rows: int) -> None:
        x = torch.empty_strided((rows, *like.shape[1:]), like.stride()).uniform_().requires_grad_(True)
        out = victim(x)
        (out[:, 1].sum() - out[:, 0].sum()).backward()
        _synchronize(victim)

    for step in range(args.steps + 1):
        for v in variants:
            with v:
                for burst in range(args.burst):  # consecutive steps; the first after a switch is not recorded
                    t0, c0 = time.perf_counter(), time.process_time()
                    attack_step(attack, params[idx], idx, crits, call, call.views, rule)
                    t1, c1 = time.perf_counter(), time.process_time()
                    params.grad = None
                    if step > 0 and (burst > 0 or args.burst == 1):
                        steps[v.label].append(t1 - t0)
                        cpu[v.label].append(c1 - c0)
                key = f"victim alone {v.label.replace('serial ', '')}"
                for burst in range(0 if v.old_pool else args.burst):
                    t2 = time.perf_counter()
                    victim_alone(t * num_v)
                    if step > 0 and (burst > 0 or args.burst == 1):
                        ceil.setdefault(key, []).append(time.perf_counter() - t2)
    med = {k: float(statistics.median(x)) for k, x in steps.items()}
    med_cpu = {k: float(statistics.median(x)) for k, x in cpu.items()}
    med_ceil = {k: float(statistics.median(x)) for k, x in ceil.items()}
    record: Dict[str, Any] = {"mesh": mesh_name, "faces": mesh.num_faces, "perturb": perturb, "views": num_v,
                              "device": _device_name(victim.device),
                              "image_size": args.image_size, "antialias": args.antialias, "targets": t,
                              "step_s": med, "step_cpu_s": med_cpu, "victim_alone_s": med_ceil}
    if args.attack_steps:
        from meshadv.attacks import TargetedMisclassification as TM

        runs: Dict[str, List[float]] = {}
        for rep in range(args.attack_reps):
            for v in variants:
                with v:
                    attack_v = _make_attack(perturb, steps=args.attack_steps)
                    t0 = time.perf_counter()
                    result = attack_v(mesh, views, victim, [TM(c) for c in range(1, t + 1)], setup=setup)
                    runs.setdefault(v.label, []).append(result.steps * t / (time.perf_counter() - t0))
        record["attack_target_steps_per_s"] = runs
    return record


def pool_bench(args: argparse.Namespace) -> Dict[str, Any]:
    """Median forward / backward wall time of the antialias pooling, box filter vs ``F.avg_pool2d``."""
    from meshadv.render.renderer import _downsample

    torch.set_num_threads(1)
    k, b, size = args.antialias, args.targets * args.views, args.image_size
    image = torch.rand(b, size * k, size * k, 4)
    grad = torch.rand(b, 4, size, size)
    times: Dict[str, Tuple[List[float], List[float]]] = {"avg_pool2d": ([], []), "box filter": ([], [])}
    for i in range(args.steps + 1):
        for name, fn in (("avg_pool2d", _old_downsample), ("box filter", _downsample)):
            x = image.clone().requires_grad_(True)
            t0 = time.perf_counter()
            y = fn(x, k)
            t1 = time.perf_counter()
            y.backward(grad)
            t2 = time.perf_counter()
            if i > 0:
                times[name][0].append(t1 - t0)
                times[name][1].append(t2 - t1)
    return {name: {"forward_s": statistics.median(f), "backward_s": statistics.median(bw)}
            for name, (f, bw) in times.items()}


def print_pipeline(records: List[Dict[str, Any]]) -> None:
    """Markdown table of the whole-step records."""
    print("| mesh | perturb | variant | step (wall) | CPU per step | target-steps/s | victim alone (same threads) | "
          "renderer share not hidden | best victim-alone ceiling | ratio to best ceiling | attack target-steps/s |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|---|")
    for r in records:
        t = r["targets"]
        best = min(r["victim_alone_s"].values())
        for label, step in r["step_s"].items():
            alone = r["victim_alone_s"].get(f"victim alone {label.replace('old serial ', '').replace('serial ', '')}")
            share = "-" if alone is None else f"{100 * (1 - alone / step):.0f}%"
            alone_txt = "-" if alone is None else f"{1e3 * alone:.0f} ms"
            runs = r.get("attack_target_steps_per_s", {}).get(label)
            runs_txt = "-" if not runs else " / ".join(f"{x:.2f}" for x in runs)
            print(f"| {r['mesh']} | {r['perturb']} | {label} | {1e3 * step:.0f} ms | "
                  f"{1e3 * r['step_cpu_s'][label]:.0f} ms | {t / step:.2f} | {alone_txt} | {share} | "
                  f"{t / best:.2f} ({min(r['victim_alone_s'], key=r['victim_alone_s'].get)}) | "
                  f"{best / step:.0%} | {runs_txt} |")


def print_split(records: List[Dict[str, Any]]) -> None:
    """Markdown table of the step-split records."""
    print("| mesh | faces | perturb | victim | targets x views x px (antialias) | render fwd | victim fwd+bwd | "
          "render bwd | renderer share | target-steps/s | victim-alone ceiling | ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in records:
        print(f"| {r['mesh']} | {r['faces']} | {r['perturb']} | {r.get('victim', '-')} | "
              f"{r['targets']} x {r['views']} x {r['image_size']} "
              f"({r['antialias']}x) | {1e3 * r['render_fwd_s']:.0f} ms | {1e3 * r['victim_s']:.0f} ms | "
              f"{1e3 * r['render_bwd_s']:.0f} ms | {100 * r['render_share']:.0f}% | {r['target_steps_per_s']:.2f} | "
              f"{r['victim_ceiling_target_steps_per_s']:.2f} | "
              f"{r['target_steps_per_s'] / r['victim_ceiling_target_steps_per_s']:.0%} |")


def bench_case(mesh_name: str, perturb: str, args: argparse.Namespace, victim: Any) -> Dict[str, Any]:
    """Benchmark one mesh and perturbation; returns a JSON-able record."""
    from meshadv.attacks import TargetedMisclassification

    mesh, views, targets = _setup(mesh_name, args, victim)
    shape_kw: Dict[str, Any] = {"smoothing": None if args.smoothing is None else args.smoothing[0],
                                "shape_lr": args.shape_lr[0]}
    crits = [TargetedMisclassification(t) for t in targets]
    record: Dict[str, Any] = {
        "mesh": mesh_name,
        "perturb": perturb,
        "faces": mesh.num_faces,
        "views": args.views,
        "image_size": args.image_size,
        "targets": targets,
    }

    # the victim alone: the ceiling of the batching gain
    record["victim_single_images_per_s"] = victim_images_per_s(victim, args.views, args.image_size)
    record["victim_batched_images_per_s"] = victim_images_per_s(victim, args.views * len(crits), args.image_size)

    # throughput
    for label, crit in (("single", crits[:1]), ("batched", crits)):
        attack = _make_attack(perturb, **shape_kw, steps=args.steps)
        if label == "single" and args.warmup:
            attack(mesh, views, victim, crit, setup=RenderSetup(image_size=args.image_size))
        t0 = time.perf_counter()
        result = attack(mesh, views, victim, crit, setup=RenderSetup(image_size=args.image_size))
        dt = time.perf_counter() - t0
        record[f"{label}_steps_per_s"] = result.steps / dt
        record[f"{label}_target_steps_per_s"] = result.steps * len(crit) / dt

    # time to success
    seq_time, seq_ok, seq_first = 0.0, 0, []
    for crit in crits:
        attack = _make_attack(perturb, **shape_kw, steps=args.max_steps, early_stop=1)
        t0 = time.perf_counter()
        result = attack(mesh, views, victim, crit, setup=RenderSetup(image_size=args.image_size))
        seq_time += time.perf_counter() - t0
        seq_ok += int(result.succeeded[0])
        seq_first.append(result.time_to_success[0])
    attack = _make_attack(perturb, **shape_kw, steps=args.max_steps, early_stop=1)
    t0 = time.perf_counter()
    result = attack(mesh, views, victim, crits, setup=RenderSetup(image_size=args.image_size))
    record.update(
        sequential_time_s=seq_time,
        sequential_successes=seq_ok,
        sequential_first_success_s=seq_first,
        batched_time_s=time.perf_counter() - t0,
        batched_successes=int(result.succeeded.sum()),
        batched_first_success_s=list(result.time_to_success),
    )
    return record


def _device_name(device: torch.device) -> str:
    """``cpu``, or a CUDA device with the GPU's name."""
    if device.type == "cuda":
        return f"{device} ({torch.cuda.get_device_name(device)})"
    return str(device)


def main(argv: List[str]) -> int:
    """Run the benchmark (see the module docstring for the options)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", nargs="+", default=["chair/01", "sofa/01"], help="PASCAL3D+ class/model")
    parser.add_argument("--perturb", nargs="+", default=["shape", "texture"], choices=["shape", "texture"])
    parser.add_argument("--victim", default="efficientnet_lite0")
    parser.add_argument("--device", default="cpu",
                        help="the victim's device (cuda: a GPU victim fed by the CPU renderer; wall times only)")
    parser.add_argument("--views", type=int, default=5)
    parser.add_argument("--image-size", type=int, default=160)
    parser.add_argument("--targets", type=int, default=4)
    parser.add_argument("--steps", type=int, default=10, help="steps of the throughput runs")
    parser.add_argument("--max-steps", type=int, default=200, help="step limit of the time-to-success runs")
    parser.add_argument("--warmup", action="store_true", help="one untimed run first")
    parser.add_argument("--out", type=Path, default=None, help="JSON output file")
    parser.add_argument("--convergence", action="store_true",
                        help="only the shape attack's time to success over --smoothing x --shape-lr")
    parser.add_argument("--smoothing", type=int, nargs="+", default=None,
                        help="shape flow smoothing rounds (default: ShapeAttack's default)")
    parser.add_argument("--shape-lr", type=float, nargs="+", default=[5e-3], help="shape attack learning rates")
    parser.add_argument("--split", action="store_true",
                        help="only time one step's parts (render fwd, victim, render bwd), --targets batched")
    parser.add_argument("--antialias", type=int, default=1, help="--split: supersampling factor of the render")
    parser.add_argument("--visibility-gradient", choices=("nmr", "local"), default="nmr",
                        help="--split: the render's visibility gradient (meshadv.render.render)")
    parser.add_argument("--cpu-time", action="store_true",
                        help="--split: process CPU time instead of wall time (steadier on a busy machine; run with "
                             "OMP_NUM_THREADS=1 RAYON_NUM_THREADS=1 so that it is also the 1-thread wall time)")
    parser.add_argument("--whole-steps", action="store_true",
                        help="--split: time whole steps at each of --torch-threads (see above)")
    parser.add_argument("--torch-threads", type=int, nargs="+", default=[1, 2],
                        help="--split --whole-steps: torch thread counts of the variants")
    parser.add_argument("--attack-steps", type=int, default=0,
                        help="--split --whole-steps: also run whole attacks of this many steps per variant")
    parser.add_argument("--burst", type=int, default=3,
                        help="--split --whole-steps: consecutive steps per variant and round (the first of each "
                             "burst is not recorded when > 1)")
    parser.add_argument("--pool-bench", action="store_true",
                        help="only time the antialias pooling (box filter vs F.avg_pool2d)")
    parser.add_argument("--attack-reps", type=int, default=2, help="--attack-steps: alternating repetitions")
    parser.add_argument("--victim-optimize", choices=["on", "off", "both"], default="on",
                        help="load_victim's optimize (both: --split times the two side by side)")
    parser.add_argument("--budgets", type=int, nargs="+", default=None,
                        help="--convergence: step budgets to count successes within (default: --max-steps)")
    args = parser.parse_args(argv)

    from meshadv.victims import load_victim

    torch.manual_seed(0)
    if args.victim_optimize == "both" and not args.split:
        parser.error("--victim-optimize both needs --split")
    try:
        device_type = torch.device(args.device).type
    except RuntimeError as exc:
        parser.error(f"--device {args.device!r} is not a torch device ({exc})")
    if args.cpu_time and device_type != "cpu":
        parser.error(f"--cpu-time counts this process's CPU time, not the GPU's: drop it with --device {args.device}")
    optimize = {"on": [True], "off": [False], "both": [False, True]}[args.victim_optimize]
    victims = {("optimized" if o else "plain"): load_victim(args.victim, optimize=o, device=args.device)
               for o in optimize}
    victim = next(iter(victims.values()))
    command = "python benchmarks/attack_bench.py " + " ".join(argv)
    machine = (f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch threads "
               f"{torch.get_num_threads()}, victim on {_device_name(victim.device)}")
    if args.pool_bench:
        record = pool_bench(args)
        print(f"command: {command}")
        print(f"batch {args.targets * args.views}, {args.image_size * args.antialias} -> {args.image_size} px, "
              f"1 torch thread, 1-minute load average {os.getloadavg()[0]:.1f}")
        for name, r in record.items():
            print(f"{name}: forward {1e3 * r['forward_s']:.1f} ms, backward {1e3 * r['backward_s']:.1f} ms")
        return 0
    if args.split and args.whole_steps:
        loads = [os.getloadavg()[0]]
        start = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
        records = [pipeline_split(m, p, args, victim) for m in args.meshes for p in args.perturb]
        loads.append(os.getloadavg()[0])
        print(f"command: {command}")
        print(f"{machine}; started {start}; 1-minute load average {min(loads):.1f}-{max(loads):.1f}")
        print_pipeline(records)
        if args.out is not None:
            args.out.write_text(json.dumps({"command": command, "load": loads, "start": start, "records": records},
                                           indent=2))
        return 0
    if args.split:
        loads = [os.getloadavg()[0]]
        records = [r for m in args.meshes for p in args.perturb for r in step_split(m, p, args, victims)]
        loads.append(os.getloadavg()[0])
        print(f"command: {command}")
        print(f"{machine}; 1-minute load average {min(loads):.1f}-{max(loads):.1f}")
        print_split(records)
        if args.out is not None:
            args.out.write_text(json.dumps({"command": command, "torch_threads": torch.get_num_threads(),
                                            "load": loads, "records": records}, indent=2))
        return 0
    if args.convergence:
        from meshadv.attacks.shape import DEFAULT_SMOOTHING

        smoothings = args.smoothing if args.smoothing is not None else [DEFAULT_SMOOTHING]
        budgets = sorted(b for b in (args.budgets or [args.max_steps]) if b <= args.max_steps)
        loads = [os.getloadavg()[0]]
        records = []
        for m in args.meshes:
            for k in smoothings:
                for lr in args.shape_lr:
                    records.append(convergence_case(m, k, lr, args, victim))
                    loads.append(os.getloadavg()[0])
                    steps = [run["steps_to_success"] for run in records[-1]["runs"]]
                    print(f"done {m} smoothing={k} lr={lr:g}: steps to success {steps} "
                          f"({records[-1]['time_s']:.0f} s, load {loads[-1]:.1f})", file=sys.stderr, flush=True)
        print(f"command: {command}")
        print(f"{machine}; 1-minute load average {min(loads):.1f}-{max(loads):.1f}")
        print_convergence(records, budgets)
        if args.out is not None:
            args.out.write_text(json.dumps({"command": command, "torch_threads": torch.get_num_threads(),
                                            "load": loads, "records": records}, indent=2))
        return 0
    records = [bench_case(m, p, args, victim) for m in args.meshes for p in args.perturb]
    print(f"command: {command}")
    print(machine)
    print(
        "| mesh | faces | perturb | views x px | steps/s 1 target | steps/s {T} targets | target-steps/s "
        "1 vs {T} | victim images/s 1 vs {T} (ceiling) | time to all successes: sequential | batched |"
        .replace("{T}", str(args.targets))
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in records:
        print(
            f"| {r['mesh']} | {r['faces']} | {r['perturb']} | {r['views']} x {r['image_size']} | "
            f"{r['single_steps_per_s']:.2f} | {r['batched_steps_per_s']:.2f} | "
            f"{r['single_target_steps_per_s']:.2f} vs {r['batched_target_steps_per_s']:.2f} | "
            f"{r['victim_single_images_per_s']:.1f} vs {r['victim_batched_images_per_s']:.1f} "
            f"({r['victim_batched_images_per_s'] / r['victim_single_images_per_s']:.2f}x) | "
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
