"""``meshadv attack``'s defaults against the same command with one option changed, side by side, on PASCAL3D+ meshes.

Per (mesh, target) case it runs ``meshadv attack MESH --target T`` (the defaults: 5 views, ddn, 300 steps, MeshLab
resampling, the default perceptibility cap, the held-out verdict) and the same with ``--eot N`` or
``--visibility-gradient local``, two runs at a time (one thread each), each stopped with Ctrl-C (SIGINT: the command
saves its best result so far) after ``--budget`` seconds; then ``meshadv transfer attack`` renders each result in
Mitsuba (benign-controlled). Resumable: a run folder with a ``result.json`` (and ``transfer.json``) is not run
again. Prints one markdown row per run and writes them to ``<out>/summary.json``.

Example:
    python benchmarks/attack_defaults_bench.py --out runs/attack_defaults --eot 4 --budget 570
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple

DATA = Path(os.environ.get("MESHADV_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))

#: (PASCAL3D+ mesh, target): four classes, each mesh its class's on all 5 default views (EfficientNet-Lite0), each
#: target a class of another object ranked among the benign centre view's top 6.
CASES: Tuple[Tuple[str, str], ...] = (
    ("aeroplane/02", "space shuttle"),
    ("bottle/04", "water jug"),
    ("sofa/03", "chest"),
    ("chair/02", "loudspeaker"),
    ("chair/05", "cellular telephone"),
)


def _env() -> Dict[str, str]:
    env = dict(os.environ)
    env.update(OMP_NUM_THREADS="1", RAYON_NUM_THREADS="1", MKL_NUM_THREADS="1")
    return env


def _run(cmd: Sequence[str], log: Path, budget: float) -> Tuple[int, float]:
    """Run ``cmd`` (its output into ``log``), sending SIGINT after ``budget`` seconds; ``(exit code, seconds)``."""
    start = time.perf_counter()
    with open(log, "w", encoding="utf-8") as fh:
        proc = subprocess.Popen(list(cmd), stdout=fh, stderr=subprocess.STDOUT, env=_env())
        try:
            code = proc.wait(timeout=budget)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGINT)
            try:
                code = proc.wait(timeout=120)
            except subprocess.TimeoutExpired:
                proc.kill()
                code = proc.wait()
    return code, time.perf_counter() - start


def run_case(mesh: str, target: str, variant: str, extra: Sequence[str], out: Path, budget: float,
             spp: int) -> Dict[str, Any]:
    """One run of ``meshadv attack`` (the defaults plus ``extra`` options) and its Mitsuba transfer (skipped when
    already done); its summary row."""
    folder = out / f"{mesh.replace('/', '_')}_{variant}"
    folder.mkdir(parents=True, exist_ok=True)
    meshadv = [sys.executable, "-m", "meshadv"]
    wall: Optional[float] = None
    if not (folder / "result.json").is_file():
        cmd = [*meshadv, "attack", str(DATA / "pascal3d" / f"{mesh}.ply"), "--target", target, "--quiet",
               "--threads", "1", "-o", str(folder), *extra]
        code, wall = _run(cmd, folder / "attack.log", budget)
        (folder / "wall.json").write_text(json.dumps({"exit_code": code, "wall_s": wall, "command": cmd}))
    if (folder / "result.json").is_file() and not (folder / "transfer.json").is_file():
        _run([*meshadv, "transfer", "attack", str(folder), "--spp", str(spp), "--threads", "1"],
             folder / "transfer.log", 600)
    return summary_row(mesh, target, variant, folder)


def summary_row(mesh: str, target: str, variant: str, folder: Path) -> Dict[str, Any]:
    """The numbers of one finished run folder."""
    row: Dict[str, Any] = {"mesh": mesh, "target": target, "variant": variant, "folder": str(folder)}
    wall = folder / "wall.json"
    if wall.is_file():
        row["wall_s"] = json.loads(wall.read_text())["wall_s"]
    if not (folder / "result.json").is_file():
        row["status"] = "no result"
        return row
    rec = json.loads((folder / "result.json").read_text())
    d = rec["distances"][0]
    row.update(
        succeeded=rec["succeeded"][0], inside_cap=rec["inside_cap"][0], interrupted=rec["interrupted"],
        steps=rec["steps"], attack_views=f"{sum(rec['success'][0])}/{len(rec['success'][0])}",
        held_out=(None if rec.get("eval_success") is None
                  else f"{sum(rec['eval_success'][0])}/{len(rec['eval_success'][0])}"),
        held_out_rate=None if rec.get("held_out_rate") is None else rec["held_out_rate"][0],
        attack_wall_s=rec["wall_time"], max_displacement=d.get("max_displacement"),
        normal_change_p95_deg=d.get("normal_change_p95_deg"), edge_strain_p95=d.get("edge_strain_p95"),
        laplacian_pair_mean=d.get("laplacian_pair_mean"),
        ssim_held_out_min=d.get("ssim_held_out_min"), num_faces=rec["num_faces"],
    )
    transfer = folder / "transfer.json"
    if transfer.is_file():
        rows = json.loads(transfer.read_text())["rows"]
        control = [r for r in rows if r.get("benign_correct_mitsuba")]
        row["mitsuba_targeted"] = f"{sum(bool(r.get('success_mitsuba')) for r in rows)}/{len(rows)}"
        row["mitsuba_untargeted"] = f"{sum(bool(r.get('untargeted_mitsuba')) for r in control)}/{len(control)}"
    return row


def markdown(rows: List[Dict[str, Any]]) -> str:
    """The rows as a markdown table."""
    def f(v: Any, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    head = ("| mesh -> target | variant | SUCCESS | attack views | held-out | Mitsuba targeted | Mitsuba untargeted "
            "(benign-ctrl) | max move | normals p95 | edge strain p95 | pair mean | SSIM held-out min | steps | "
            "attack s |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        lines.append(
            f"| {r['mesh']} -> {r['target']} | {r['variant']} | {'yes' if r.get('succeeded') else 'no'} | "
            f"{r.get('attack_views', '-')} | {r.get('held_out', '-')} | {r.get('mitsuba_targeted', '-')} | "
            f"{r.get('mitsuba_untargeted', '-')} | {f(r.get('max_displacement'), '.2%')} | "
            f"{f(r.get('normal_change_p95_deg'), '.1f')} | {f(r.get('edge_strain_p95'), '.3f')} | "
            f"{f(r.get('laplacian_pair_mean'), '.2e')} | "
            f"{f(r.get('ssim_held_out_min'), '.3f')} | {r.get('steps', '-')}"
            f"{' (stopped)' if r.get('interrupted') else ''} | {f(r.get('attack_wall_s'), '.0f')} |")
    return "\n".join(lines)


def main(argv: Optional[Sequence[str]] = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("runs/attack_defaults"))
    parser.add_argument("--eot", type=int, default=4, help="samples of the EOT variant")
    parser.add_argument("--budget", type=float, default=570.0, help="seconds before a run is stopped (SIGINT)")
    parser.add_argument("--spp", type=int, default=32, help="Mitsuba samples per pixel")
    parser.add_argument("--parallel", type=int, default=2, help="runs at a time")
    parser.add_argument("--cases", nargs="+", default=None, help="only these meshes of CASES (e.g. bottle/04)")
    parser.add_argument("--variants", nargs="+", default=["default", "eot"], choices=["default", "eot", "local"],
                        help="default: the defaults; eot: with --eot N; local: with --visibility-gradient local")
    parser.add_argument("--report", action="store_true", help="only summarise the finished folders")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    cases = [(m, t) for m, t in CASES if args.cases is None or m in args.cases]
    options = {"default": ("default", ()), "eot": (f"eot{args.eot}", ("--eot", str(args.eot))),
               "local": ("local", ("--visibility-gradient", "local"))}
    variants = [options[v] for v in args.variants]
    jobs = [(mesh, target, variant, extra) for mesh, target in cases for variant, extra in variants]
    if args.report:
        rows = [summary_row(m, t, v, args.out / f"{m.replace('/', '_')}_{v}") for m, t, v, _ in jobs]
    else:
        with ThreadPoolExecutor(max_workers=args.parallel) as pool:
            rows = list(pool.map(lambda j: run_case(*j, out=args.out, budget=args.budget, spp=args.spp), jobs))
    name = ("summary.json" if args.cases is None and args.variants == ["default", "eot"]
            else f"summary_{'_'.join(v for v, _ in variants)}_{len(rows)}.json")
    (args.out / name).write_text(json.dumps(rows, indent=2))
    print(markdown(rows))


if __name__ == "__main__":
    main()
