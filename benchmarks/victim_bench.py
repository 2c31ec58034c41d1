"""Victim options benchmark: torch's own ways to make a frozen victim's forward + input gradient cheaper on the CPU.

One attack step needs the victim's logits and the gradient of a loss w.r.t. its input images (never w.r.t. its
weights). For each victim and batch size this times that forward + input gradient, on random ``--image-size`` images,
for these variants of the same network:

* ``eager``: the network as the weights describe it (``load_victim(name, optimize=False)``; eval mode, parameters
  with ``requires_grad=False``, checked here);
* ``fused``: batch norms folded into the convolutions, which pad by themselves (``EfficientNetLite.fuse_batchnorm``);
* ``eager_cl`` / ``fused_cl``: the same in channels-last memory format (``EfficientNetLite.use_channels_last``);
  ``fused_cl`` is what ``load_victim(name)`` (``optimize=True``, the default) builds;
* ``fused_jit``: ``torch.jit.freeze`` of a ``torch.jit.trace`` of the fused network (``optimize_for_inference`` is not
  measured: its output carries no gradient);
* ``eager_bf16`` / ``fused_cl_bf16``: ``eager`` / ``fused_cl`` with the forward under ``torch.autocast("cpu",
  dtype=torch.bfloat16)`` (oneDNN's bfloat16 kernels: AVX-512-BF16 / AMX where the CPU has them), logits returned as
  float32; not an exact rewrite (see the accuracy columns);
* ``compile_<mode>``: ``torch.compile`` (inductor, compiled in this process:
  ``TORCHINDUCTOR_COMPILE_THREADS=1``) of the default (``fused_cl``) network, per ``--compile-modes``.

Every variant's first call is timed separately (for ``torch.compile`` it includes the compilation: the break-even
step count is that extra time over the per-step saving against ``fused_cl``, the default). The steps of all variants
are interleaved (round robin, ``--repeats`` rounds) so that a busy machine slows them alike; the table gives medians
of process CPU time at ``--threads`` torch threads (1: CPU time = wall time) and, for thread counts above 1, the wall
time too.

Accuracy: logits and input gradient relative to a float64 evaluation of the eager network (max |diff| / max |ref|
for the logits, ||diff|| / ||ref|| for the gradient), beside the same for the eager float32 network.

Usage:
    OMP_NUM_THREADS=1 TORCHINDUCTOR_COMPILE_THREADS=1 python benchmarks/victim_bench.py \\
        --victims efficientnet_lite0 efficientnet_lite2 --batches 6 1 --repeats 7 --out /tmp/victim_bench.json
    python benchmarks/victim_bench.py --victims efficientnet_lite0 --batches 6 --variants eager fused \\
        --threads 1 2 --repeats 7

Prints a Markdown table (paste it into benchmarks/RESULTS.md with the command line) and writes a JSON record.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

VARIANTS = ("eager", "fused", "eager_cl", "fused_cl", "fused_jit", "eager_bf16", "fused_cl_bf16")
COMPILE_MODES = ("default", "reduce-overhead", "max-autotune-no-cudagraphs")


class Bfloat16Autocast:
    """A victim whose forward runs under CPU autocast to bfloat16, returning float32 logits."""

    def __init__(self, victim: Any) -> None:
        self.victim = victim

    def __call__(self, images: Tensor) -> Tensor:
        with torch.autocast("cpu", dtype=torch.bfloat16):
            return self.victim(images).float()


def build_variant(variant: str, eager: Any, example: Tensor) -> Any:
    """A copy of the unoptimised victim ``eager`` with its network in ``variant``'s form (see the module docstring)."""
    if variant == "eager":
        return eager
    if variant.endswith("_bf16"):
        return Bfloat16Autocast(build_variant(variant[: -len("_bf16")], eager, example))
    victim = copy.deepcopy(eager)
    if variant.startswith(("fused", "compile_")):
        victim.net.fuse_batchnorm()
    if variant.endswith("_cl") or variant.startswith("compile_"):
        victim.net.use_channels_last()
    if variant == "fused_jit":
        with torch.no_grad():
            victim.net = torch.jit.freeze(torch.jit.trace(victim.net, victim.preprocess(example)))
    elif variant.startswith("compile_"):
        victim.net = torch.compile(victim.net, mode=variant[len("compile_"):])
    elif variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}")
    return victim


def forward_backward(victim: Any, images: Tensor) -> tuple[Tensor, Tensor]:
    """The victim's logits and the gradient of a two-logit margin w.r.t. the images (what an attack step needs)."""
    x = images.clone().requires_grad_(True)
    logits = victim(x)
    (logits[:, 1].sum() - logits[:, 0].sum()).backward()
    assert x.grad is not None
    return logits.detach(), x.grad


def _rel_max(got: Tensor, want: Tensor) -> float:
    return float((got.double() - want).abs().max() / want.abs().max())


def _rel_norm(got: Tensor, want: Tensor) -> float:
    return float((got.double() - want).norm() / want.norm())


def bench(name: str, batch: int, variants: list[str], args: argparse.Namespace) -> list[dict[str, Any]]:
    """Time and check every variant of victim ``name`` at ``batch`` images; one record per variant and thread count."""
    from meshadv.victims import load_victim

    eager = load_victim(name, optimize=False)
    assert not eager.training and not any(p.requires_grad for p in eager.parameters()), "victims are frozen"
    torch.manual_seed(0)
    images = torch.rand(batch, 3, args.image_size, args.image_size)
    reference = copy.deepcopy(eager).double()
    want_logits, want_grad = forward_backward(reference, images.double())
    del reference
    records = []
    for threads in args.threads:
        torch.set_num_threads(threads)
        built: dict[str, Any] = {}
        first: dict[str, tuple[float, float]] = {}
        errors: dict[str, tuple[float, float]] = {}
        for variant in variants:
            c0, w0 = time.process_time(), time.perf_counter()
            built[variant] = build_variant(variant, eager, images)
            logits, grad = forward_backward(built[variant], images)
            first[variant] = (time.process_time() - c0, time.perf_counter() - w0)
            errors[variant] = (_rel_max(logits, want_logits), _rel_norm(grad, want_grad))
            print(f"{name} batch {batch} threads {threads} {variant}: first call {first[variant][0]:.1f} s CPU",
                  file=sys.stderr, flush=True)
        cpu: dict[str, list[float]] = {v: [] for v in variants}
        wall: dict[str, list[float]] = {v: [] for v in variants}
        for _ in range(args.repeats):
            for variant in variants:
                c0, w0 = time.process_time(), time.perf_counter()
                forward_backward(built[variant], images)
                cpu[variant].append(time.process_time() - c0)
                wall[variant].append(time.perf_counter() - w0)
        base = statistics.median(cpu["fused_cl"]) if "fused_cl" in cpu else None
        for variant in variants:
            step = statistics.median(cpu[variant])
            extra = first[variant][0] - step
            saving = None if base is None else base - step
            records.append({
                "victim": name, "batch": batch, "image_size": args.image_size, "threads": threads,
                "variant": variant, "cpu_s": step, "wall_s": statistics.median(wall[variant]),
                "cpu_all_s": cpu[variant], "first_call_cpu_s": first[variant][0],
                "first_call_wall_s": first[variant][1],
                "break_even_steps_vs_default": (extra / saving) if variant.startswith("compile_") and saving
                and saving > 0 else None,
                "logits_rel_err": errors[variant][0], "grad_rel_err": errors[variant][1],
            })
        del built
    return records


def print_table(records: list[dict[str, Any]]) -> None:
    """Markdown table of the records (ratios against ``eager`` of the same victim, batch and threads)."""
    print("| victim | batch | threads | variant | fwd + input grad, CPU (wall) | vs eager | first call (CPU) | "
          "logits err | input-grad err |")
    print("|---|---:|---:|---|---:|---:|---:|---:|---:|")
    eager = {(r["victim"], r["batch"], r["threads"]): r["cpu_s"] for r in records if r["variant"] == "eager"}
    for r in records:
        key = (r["victim"], r["batch"], r["threads"])
        ratio = f"{eager[key] / r['cpu_s']:.2f}x" if key in eager else "-"
        wall = f" ({1e3 * r['wall_s']:.0f})" if r["threads"] > 1 else ""
        first = f"{r['first_call_cpu_s']:.1f} s"
        if r["break_even_steps_vs_default"] is not None:
            first += f" (break-even {r['break_even_steps_vs_default']:.0f} steps)"
        print(f"| {r['victim']} | {r['batch']} | {r['threads']} | {r['variant']} | {1e3 * r['cpu_s']:.0f}{wall} ms "
              f"| {ratio} | {first} | {r['logits_rel_err']:.1e} | {r['grad_rel_err']:.1e} |")


def main(argv: list[str]) -> int:
    """Run the benchmark (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--victims", nargs="+", default=["efficientnet_lite0", "efficientnet_lite2"])
    parser.add_argument("--batches", type=int, nargs="+", default=[6, 1])
    parser.add_argument("--image-size", type=int, default=224, help="side of the random input images")
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    parser.add_argument("--compile-modes", nargs="*", default=list(COMPILE_MODES), choices=COMPILE_MODES,
                        help="torch.compile modes to add as variants (none: no compilation)")
    parser.add_argument("--compile-batches", type=int, nargs="*", default=None,
                        help="batch sizes to compile at (default: all of --batches)")
    parser.add_argument("--compile-victims", nargs="*", default=None,
                        help="victims to compile (default: all of --victims)")
    parser.add_argument("--threads", type=int, nargs="+", default=[1], help="torch thread counts")
    parser.add_argument("--repeats", type=int, default=7, help="timed rounds (after each variant's first call)")
    parser.add_argument("--out", type=Path, default=None, help="JSON output file")
    args = parser.parse_args(argv)
    if "fused_cl" not in args.variants:
        args.variants = [*args.variants, "fused_cl"]
    os.environ.setdefault("TORCHINDUCTOR_COMPILE_THREADS", "1")

    command = "python benchmarks/victim_bench.py " + " ".join(argv)
    loads = [os.getloadavg()[0]]
    records: list[dict[str, Any]] = []
    for name in args.victims:
        for batch in args.batches:
            compiled = [f"compile_{m}" for m in args.compile_modes
                        if (args.compile_batches is None or batch in args.compile_batches)
                        and (args.compile_victims is None or name in args.compile_victims)]
            records += bench(name, batch, [*args.variants, *compiled], args)
            loads.append(os.getloadavg()[0])
            if args.out is not None:  # what is done so far, in case a later case does not finish
                args.out.write_text(json.dumps({"command": command, "torch": torch.__version__, "load": loads,
                                                "records": records}, indent=2))
    print(f"command: {command}")
    print(f"machine: {platform.processor() or platform.machine()}, torch {torch.__version__}; "
          f"1-minute load average {min(loads):.1f}-{max(loads):.1f}")
    print_table(records)
    if args.out is not None:
        args.out.write_text(json.dumps({"command": command, "torch": torch.__version__, "load": loads,
                                        "records": records}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
