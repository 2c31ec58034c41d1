"""Process CPU time per call of the Rust render bench (`crates/raster/examples/bench.rs`), builds or instruction sets
side by side.

Each round runs every variant once, in turn: the CPU time (user + system, of the child process) of
`bench 1 MODE CASE` with `BENCH_REPS=n`, minus that of `BENCH_REPS=1` (start-up, mesh loading and the first call),
divided by `n - 1`. Rounds alternate the variants so that a noisy shared machine slows them alike; the report gives
each variant's median and range, and each variant's median per-round ratio to the first one.

    cargo build --release -p meshadv-raster --example bench && cp target/release/examples/bench /tmp/bench_new
    python benchmarks/raster_cpu_time.py bwd sphere --rounds 15 --reps 41 \\
        avx2=/tmp/bench_new:avx2 avx512=/tmp/bench_new old=/tmp/bench_old

A variant is `LABEL=BINARY` or `LABEL=BINARY:ISA` (`BENCH_ISA`: portable, avx2; none: the fastest the CPU has).
One thread (`RAYON_NUM_THREADS=1`); the `pascal` case reads `MESHADV_DATA` (default `../shared/data`).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
from pathlib import Path
from typing import Dict, List, Tuple

DEFAULT_DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def child_cpu_seconds(cmd: List[str], env: Dict[str, str]) -> float:
    """User + system CPU seconds of running `cmd` to completion."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def parse_variant(text: str) -> Tuple[str, str, str]:
    """`LABEL=BINARY[:ISA]` as (label, binary, isa or '')."""
    label, sep, spec = text.partition("=")
    if not sep or not label or not spec:
        raise argparse.ArgumentTypeError(f"variant {text!r}: expected LABEL=BINARY or LABEL=BINARY:ISA")
    binary, _, isa = spec.partition(":")
    if isa not in ("", "portable", "avx2"):
        raise argparse.ArgumentTypeError(f"variant {text!r}: ISA must be portable or avx2, got {isa!r}")
    return label, binary, isa


def per_call_ms(binary: str, isa: str, mode: str, case: str, reps: int) -> float:
    """Milliseconds of CPU per call of one variant, start-up subtracted."""
    env = dict(os.environ, RAYON_NUM_THREADS="1", OMP_NUM_THREADS="1")
    env.setdefault("MESHADV_DATA", str(DEFAULT_DATA))
    env.pop("BENCH_ISA", None)
    if isa:
        env["BENCH_ISA"] = isa
    cmd = [binary, "1", mode, case]
    one = child_cpu_seconds(cmd, dict(env, BENCH_REPS="1"))
    many = child_cpu_seconds(cmd, dict(env, BENCH_REPS=str(reps)))
    return 1e3 * (many - one) / (reps - 1)


def main() -> None:
    """Runs the rounds and prints the medians and ratios."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("mode", choices=["fwd", "bwd"], help="the pass to time")
    parser.add_argument("case", choices=["sphere", "pascal", "pascal-rgb"], help="bench.rs's case")
    parser.add_argument("variants", nargs="+", type=parse_variant, help="LABEL=BINARY[:ISA], the first is the base")
    parser.add_argument("--rounds", type=int, default=9, help="alternating rounds (default 9)")
    parser.add_argument("--reps", type=int, default=41, help="calls per timed run, >= 2 (default 41)")
    args = parser.parse_args()
    if args.rounds < 1:
        parser.error("--rounds must be at least 1")
    if args.reps < 2:
        parser.error("--reps must be at least 2")
    labels = [label for label, _, _ in args.variants]
    if len(set(labels)) != len(labels):
        parser.error(f"variant labels must differ: {labels}")
    times: Dict[str, List[float]] = {label: [] for label in labels}
    for _ in range(args.rounds):
        for label, binary, isa in args.variants:
            times[label].append(per_call_ms(binary, isa, args.mode, args.case, args.reps))
    for label, v in times.items():
        print(f"{label}: median {statistics.median(v):.2f} ms (range {min(v):.2f}-{max(v):.2f}), {len(v)} rounds")
    base = labels[0]
    for label in labels[1:]:
        ratios = [x / y for x, y in zip(times[label], times[base])]
        print(
            f"{label} / {base}: median per-round ratio {statistics.median(ratios):.3f} "
            f"(range {min(ratios):.3f}-{max(ratios):.3f})"
        )
    print(f"1-minute load average at the end: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
