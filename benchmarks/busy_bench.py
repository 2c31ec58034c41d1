"""`meshadv demo` wall time on a quiet and on a busy machine, before and after the thread policy (issue 18).

Each run starts a fresh `meshadv demo --quiet` process while ``--busy`` other processes spin on the CPU
(``python3 -c "while True: pass"``, as a laptop's other programs would). Two modes:

- ``after``: the command as shipped (``meshadv demo``: OpenMP wait policy PASSIVE set before torch loads, both
  pools sized by ``--threads``, default the CPUs available);
- ``before``: torch imported first with the user's environment untouched (torch's default spinning OpenMP
  threads, torch's and rayon's default pool sizes), then the same command: the behaviour before
  :mod:`meshadv.threads` existed.

Runs are interleaved (mode x busy level, repeated ``--repeats`` times) so slow drifts of the machine's own load hit
every cell alike; the 1-minute load average before each run is recorded. Results are printed as a Markdown table
and written to ``--json`` (atomically) when given.

Example:
    python3 benchmarks/busy_bench.py --busy 0 2 --modes before after --repeats 1 --json /tmp/busy.json
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Dict, List, Sequence

_BEFORE = "import sys, torch; from meshadv.cli import app; app(args=sys.argv[1:], prog_name='meshadv')"
_AFTER = "from meshadv.cli import main; main()"
_STEPS = re.compile(r"(\d+) steps in ([0-9.]+) s")


def run_demo(mode: str, busy: int, demo_args: Sequence[str]) -> Dict[str, object]:
    """One `meshadv demo` in a fresh process with ``busy`` spinning processes beside it; its wall time and steps."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OMP_", "KMP_", "MKL_", "RAYON_", "MESHADV_T"))}
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
    try:
        time.sleep(0.5)
        load = os.getloadavg()[0]
        with tempfile.TemporaryDirectory() as tmp:
            code = _BEFORE if mode == "before" else _AFTER
            start = time.perf_counter()
            proc = subprocess.run([sys.executable, "-c", code, "demo", "--quiet", "-o", tmp, *demo_args], env=env,
                                  capture_output=True, text=True)
            seconds = time.perf_counter() - start
    finally:
        for p in spinners:
            p.kill()
            p.wait()
    if proc.returncode != 0:
        raise RuntimeError(f"demo failed ({mode}, busy {busy}):\n{proc.stdout}\n{proc.stderr}")
    match = _STEPS.search(proc.stdout)
    return {"mode": mode, "busy": busy, "seconds": seconds, "load_before": load,
            "steps": int(match.group(1)) if match else None,
            "attack_seconds": float(match.group(2)) if match else None}


def main(argv: List[str] | None = None) -> None:
    """Run the grid and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--busy", type=int, nargs="+", default=[0, 2], help="competing busy processes")
    parser.add_argument("--modes", nargs="+", default=["before", "after"], choices=["before", "after"])
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--json", type=Path, default=None, help="write the runs here (atomically)")
    parser.add_argument("demo_args", nargs="*", help="extra `meshadv demo` arguments (after --)")
    args = parser.parse_args(argv)
    runs = []
    for _ in range(args.repeats):
        for mode in args.modes:
            for busy in args.busy:
                run = run_demo(mode, busy, args.demo_args)
                print(json.dumps(run), flush=True)
                runs.append(run)
                if args.json is not None:
                    tmp = args.json.with_name(f".{args.json.name}.tmp")
                    tmp.write_text(json.dumps({"argv": sys.argv, "cpus": os.cpu_count(), "runs": runs}, indent=1))
                    tmp.replace(args.json)
    print("\n| mode | busy processes | demo wall s (median) | attack steps | s per step | load avg before |")
    print("| --- | --- | --- | --- | --- | --- |")
    for mode in args.modes:
        for busy in args.busy:
            cell = [r for r in runs if r["mode"] == mode and r["busy"] == busy]
            wall = statistics.median(r["seconds"] for r in cell)
            steps = [r["steps"] for r in cell if r["steps"]]
            per = [r["attack_seconds"] / r["steps"] for r in cell if r["steps"]]
            loads = "/".join(f"{r['load_before']:.1f}" for r in cell)
            print(f"| {mode} | {busy} | {wall:.1f} | {'/'.join(map(str, steps))} | "
                  f"{statistics.median(per):.2f} | {loads} |"
                  if per else f"| {mode} | {busy} | {wall:.1f} | - | - | - |")


if __name__ == "__main__":
    main()
