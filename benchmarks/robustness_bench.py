"""Robustness benchmark: do adversarial meshes hold on unseen views and in Mitsuba, at what distortion?

Benchmark set: the shared PASCAL3D+ meshes (``../shared/data/pascal3d`` or ``$MESHADV_DATA``), the first
``--instances`` of each of ``--classes`` (all 7 and 4 instances for the full run), loaded and normalised as
``meshadv attack`` loads them (Z-up, ``[-1, 1]``), EfficientNet-Lite0, 224 px on white, and ``--targets`` target
classes per mesh (the other classes, in class order starting after the mesh's own: 6 for the full run), attacked
together as one batch (independent per-target problems). Both perturbations.

Methods (``--methods``):

* ``ddn``: ``meshadv attack``'s defaults: ``method="ddn"`` on the 5 views of ``--azimuths 150:210`` at elevation 15
  and distance 4.5, ``--steps`` steps, no early stopping;
* ``robust``: the same with the robust attack, ``meshadv attack --eot 4``
  (:func:`meshadv.attacks.robust_options`): 4 fresh views of the range per step, success checked and kept on fresh
  views, the low-pass of the perturbation;
* ``paper``: the paper's protocol, Adam with a 5-round ``lambda`` search of ``--paper-steps`` steps each on the same
  5 views (the attack classes' defaults otherwise).

Every adversarial mesh is judged on what it was not optimised on, the same for every method:

* ``heldout``: ``--heldout`` views drawn once (seed 12345) uniformly from azimuth 150..210, elevation 15 +- 5 and
  distance 4.5 +- 5%, NMR's head light; the benign mesh is rendered too. Targeted success = the target is top-1;
  untargeted success = top-1 is not the source class, counted only on views where the benign render *is* the source
  class (benign-controlled).
* ``aa``: the 5 attack views re-rendered with 4x4 supersampling (antialiased pixels): targeted success.
* ``mitsuba``: the first ``--mitsuba-views`` held-out views rendered by Mitsuba 3 (``meshadv.transfer``'s controlled
  transfer: same camera and lights, ``--spp`` samples per pixel, ``llvm_ad_rgb`` or the ``scalar_rgb`` fallback),
  the benign mesh too; untargeted transfer counted only where Mitsuba's benign render is the source class.

Distortion: the Laplacian pair mean (the paper's convention) and the largest vertex move over the bounding-box
diagonal for shape; the face-colour RMSE for texture.

Each run (method, perturbation, class, instance) is one row of the SQLite file ``--db``, written in one transaction
when the run is complete (an interrupted run leaves nothing and is redone); a rerun skips finished rows. A contact
sheet of the held-out renders (benign, then one row per target; meshadv and Mitsuba) is written per run into
``--renders`` so that results are judged by looking too. ``--report`` prints the tables (Markdown) and writes the
frontier plot, of ``--db``'s rows and those of any ``--with-db`` databases.

Usage:
    python benchmarks/robustness_bench.py --classes aeroplane bottle chair --instances 1 --targets 2
    python benchmarks/robustness_bench.py --report --plot benchmarks/robustness/frontier.png
    python benchmarks/robustness_bench.py --report --db benchmarks/robustness/runs_full.sqlite \
        --with-db benchmarks/robustness/runs_paper.sqlite --plot benchmarks/robustness/frontier_methods.png
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sqlite3
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple

import torch

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "benchmarks" / "robustness"
DEFAULT_DB = OUT / "runs.sqlite"
CLASSES = ("aeroplane", "bicycle", "boat", "bottle", "chair", "diningtable", "sofa")
METHODS = ("ddn", "robust", "paper")
PERTURBATIONS = ("shape", "texture")
VICTIM = "efficientnet_lite0"
AZIMUTHS = (150.0, 210.0)
ATTACK_VIEWS = 5
HELDOUT_SEED = 12345


def data_root() -> Path:
    """The shared data folder (``$MESHADV_DATA`` or ``../shared/data`` beside the repository)."""
    return Path(os.environ.get("MESHADV_DATA", ROOT.parent / "shared" / "data"))


def mesh_path(cls: str, index: int) -> Path:
    """The PLY of instance ``index`` (0-based) of ``cls``."""
    return data_root() / "pascal3d" / cls / f"{index + 1:02d}.ply"


def targets_for(cls: str, count: int) -> List[str]:
    """``count`` target classes of a mesh of ``cls``: the other classes in class order, starting after ``cls``."""
    i = CLASSES.index(cls)
    others = [CLASSES[(i + k) % len(CLASSES)] for k in range(1, len(CLASSES))]
    return others[:count]


def attack_views() -> Any:
    """The 5 attack views of ``meshadv attack``'s defaults."""
    from meshadv.commands._common import DEFAULT_DISTANCE, DEFAULT_ELEVATION, make_views

    return make_views(ATTACK_VIEWS, AZIMUTHS, DEFAULT_ELEVATION, DEFAULT_DISTANCE)


def heldout_views(count: int) -> Any:
    """``count`` held-out views (see the module docstring), the same for every run."""
    from meshadv.commands._common import DEFAULT_DISTANCE, DEFAULT_ELEVATION
    from meshadv.render import ViewSet

    gen = torch.Generator().manual_seed(HELDOUT_SEED)
    u = torch.rand(3, count, generator=gen, dtype=torch.float64)
    az = AZIMUTHS[0] + (AZIMUTHS[1] - AZIMUTHS[0]) * u[0]
    el = DEFAULT_ELEVATION + 10.0 * (u[1] - 0.5)
    dist = DEFAULT_DISTANCE * (1.0 + 0.1 * (u[2] - 0.5))
    return ViewSet.orbit(az.float(), elevation=el.float(), distance=dist.float())


def make_attack(method: str, perturbation: str, steps: int, paper_steps: int, cap: str = "none") -> Any:
    """The attack of ``method`` (see the module docstring), under ``meshadv.perceptibility.DEFAULT_CAP`` when
    ``cap`` is ``"default"``."""
    from meshadv.attacks import make_attack as build, robust_options
    from meshadv.perceptibility import DEFAULT_CAP

    capped = {"perceptibility_cap": DEFAULT_CAP} if cap == "default" else {}
    if method == "paper":
        return build(perturbation, steps=paper_steps, binary_search_steps=5, method="adam", **capped)
    robust = robust_options(perturbation, "ddn") if method == "robust" else {}
    return build(perturbation, steps=steps, method="ddn", early_stop=None, early_stop_margin=0.5, **robust, **capped)


def _fractions(success: torch.Tensor, mask: Optional[torch.Tensor] = None) -> List[Optional[float]]:
    """Per row of ``success (T, V)``: the fraction of True among the views of ``mask (V,)`` (``None``: none)."""
    if mask is None:
        mask = torch.ones(success.shape[1], dtype=torch.bool)
    n = int(mask.sum())
    return [None if n == 0 else float(row[mask].float().mean()) for row in success]


def mitsuba_transfer(benign: Any, adversarial: Sequence[Any], views: Any, cls: str, targets: Sequence[str],
                     perturbation: str, spp: int, image_dir: Path, stem: str) -> Dict[str, Any]:
    """Mitsuba renders of the benign and adversarial meshes from ``views`` and the victim's verdicts.

    Returns:
        ``benign_top1`` and ``benign_correct`` per view, and per target ``untargeted`` / ``targeted`` per view,
        ``untargeted_controlled`` (fraction over the benign-correct views) and ``targeted_fraction``.
    """
    from meshadv.transfer.controlled import TransferCase, controlled_transfer

    records = tuple(views.to_records())
    cases = [TransferCase(case_id=f"{stem}_benign", mesh=benign, views=records, victim=VICTIM, true_class=cls,
                          perturbation=perturbation, name=f"{stem}_benign")]
    cases += [TransferCase(case_id=f"{stem}_{t}", mesh=m, views=records, victim=VICTIM, true_class=cls, target=t,
                           perturbation=perturbation, name=f"{stem}_{t}") for m, t in zip(adversarial, targets)]
    rows = controlled_transfer(cases, spp=spp, variant="llvm_ad_rgb", image_dir=image_dir, on_error="raise")
    by_case: Dict[str, List[Any]] = {}
    for row in rows:
        by_case.setdefault(row.case_id, []).append(row)
    benign_rows = sorted(by_case[f"{stem}_benign"], key=lambda r: r.view)
    correct = [not bool(r.untargeted_mitsuba) for r in benign_rows]
    out: Dict[str, Any] = {"benign_top1": [r.top1_mitsuba for r in benign_rows], "benign_correct": correct,
                           "variant": benign_rows[0].variant, "targets": []}
    for t in targets:
        adv = sorted(by_case[f"{stem}_{t}"], key=lambda r: r.view)
        un = [bool(r.untargeted_mitsuba) for r in adv]
        tg = [bool(r.success_mitsuba) for r in adv]
        kept = [u for u, c in zip(un, correct) if c]
        out["targets"].append({"target": t, "top1": [r.top1_mitsuba for r in adv], "untargeted": un, "targeted": tg,
                               "untargeted_controlled": (sum(kept) / len(kept)) if kept else None,
                               "targeted_fraction": sum(tg) / len(tg)})
    return out


def _read_pngs(folder: Path, name: str, count: int) -> torch.Tensor:
    """The renders ``<name>_v<view>.png`` of ``folder`` as ``(count, 3, H, W)`` in ``[0, 1]``."""
    import numpy as np
    from PIL import Image

    return torch.stack([torch.from_numpy(np.asarray(Image.open(folder / f"{name}_v{v}.png").convert("RGB"))
                                         .copy()).permute(2, 0, 1).float() / 255.0 for v in range(count)])


def contact_sheet(rows: Sequence[torch.Tensor], path: Path, thumb: int = 112) -> None:
    """Rows of ``(V, 3, H, W)`` renders as one PNG of ``thumb``-pixel tiles."""
    from torch.nn.functional import interpolate

    from meshadv.util.png import save_png

    tiles = [interpolate(r.float().clamp(0, 1), size=(thumb, thumb), mode="area") for r in rows]
    width = max(t.shape[0] for t in tiles)
    lines = []
    for t in tiles:
        pad = torch.ones(width - t.shape[0], 3, thumb, thumb)
        lines.append(torch.cat(list(torch.cat([t, pad])), dim=2))
    save_png(torch.cat(lines, dim=1), path)


def run_one(method: str, perturbation: str, cls: str, index: int, victim: Any, args: argparse.Namespace) -> Dict:
    """One run: attack, then the held-out, antialiased and Mitsuba verdicts (see the module docstring)."""
    from meshadv.attacks import Misclassification, TargetedMisclassification, evaluate
    from meshadv.commands._common import load_mesh_input
    from meshadv.render import RenderSetup

    mesh = load_mesh_input(str(mesh_path(cls, index)), say=False).mesh
    targets = targets_for(cls, args.targets)
    setup = RenderSetup(image_size=224)
    views, held = attack_views(), heldout_views(args.heldout)
    attack = make_attack(method, perturbation, args.steps, args.paper_steps, args.cap)
    start = time.perf_counter()
    result = attack(mesh, views, victim, [TargetedMisclassification(t) for t in targets], setup=setup)
    wall = time.perf_counter() - start
    adv = list(result.adversarial)
    crit_t = [TargetedMisclassification(t) for t in targets]
    untargeted = Misclassification(cls)
    on_views = evaluate(adv, views, victim, crit_t, setup=setup)
    on_held = evaluate(adv, held, victim, crit_t, setup=setup)
    un_held = evaluate(adv, held, victim, [untargeted] * len(targets), setup=setup)
    benign_held = evaluate(mesh, held, victim, untargeted, setup=setup)
    benign_ok = ~benign_held.success[0]
    aa = evaluate(adv, views, victim, crit_t, setup=RenderSetup(image_size=224, antialias=4))
    stem = f"{method}_{perturbation}_{cls}_{index}"
    render_dir = Path(args.renders)
    mitsuba = None
    m = min(args.mitsuba_views, args.heldout)
    if m > 0:
        with tempfile.TemporaryDirectory(prefix="robustness_mitsuba_") as tmp:
            mitsuba = mitsuba_transfer(mesh, adv, held[:m], cls, targets, perturbation, args.spp, Path(tmp), stem)
            names = [f"{stem}_benign"] + [f"{stem}_{t}" for t in targets]
            contact_sheet([_read_pngs(Path(tmp), n, m) for n in names], render_dir / f"{stem}_mitsuba.png")
    contact_sheet([benign_held.images[0]] + [on_held.images[t] for t in range(len(targets))],
                  render_dir / f"{stem}_heldout.png")
    per_target = []
    for t, target in enumerate(targets):
        d = result.distances[t]
        per_target.append({
            "target": target,
            "succeeded": bool(result.succeeded[t]),
            "success_views": _fractions(on_views.success)[t],
            "success_heldout": _fractions(on_held.success)[t],
            "untargeted_heldout": _fractions(un_held.success, benign_ok)[t],
            "success_aa": _fractions(aa.success)[t],
            "laplacian_pair_mean": d.get("laplacian_pair_mean"),
            "max_displacement": d.get("max_displacement"),
            "color_rmse": d.get("color_rmse"),
            "steps_to_success": result.steps_to_success[t],
            "top1_heldout": on_held.top1[t].tolist() if on_held.top1 is not None else None,
            "mitsuba": None if mitsuba is None else mitsuba["targets"][t],
        })
    return {
        "method": method, "perturbation": perturbation, "class": cls, "instance": index,
        "mesh": str(mesh_path(cls, index).relative_to(data_root())), "faces": int(mesh.faces.shape[0]),
        "victim": VICTIM, "steps": result.steps, "wall_time": wall, "config": result.config,
        "benign_heldout_correct": [bool(x) for x in benign_ok.tolist()],
        "mitsuba_benign": None if mitsuba is None else {k: mitsuba[k] for k in ("benign_top1", "benign_correct",
                                                                                   "variant")},
        "targets": per_target,
        "settings": {"heldout": args.heldout, "mitsuba_views": m, "spp": args.spp, "steps": args.steps,
                     "paper_steps": args.paper_steps, "threads": torch.get_num_threads(), "cap": args.cap},
    }


def _connect(db: Path) -> sqlite3.Connection:
    db.parent.mkdir(parents=True, exist_ok=True)
    con = sqlite3.connect(str(db))
    con.execute("CREATE TABLE IF NOT EXISTS runs (key TEXT PRIMARY KEY, row TEXT NOT NULL, finished TEXT NOT NULL)")
    return con


def _key(method: str, perturbation: str, cls: str, index: int) -> str:
    return f"{method}/{perturbation}/{cls}/{index}"


def load_rows(db: Path) -> List[Dict[str, Any]]:
    """Every finished run of ``db`` (none when it does not exist)."""
    if not db.is_file():
        return []
    con = _connect(db)
    try:
        return [json.loads(r[0]) for r in con.execute("SELECT row FROM runs ORDER BY key")]
    finally:
        con.close()


def run(args: argparse.Namespace) -> None:
    """Every pending run of the selection, each stored when it is complete."""
    from meshadv.victims import load_victim

    torch.set_num_threads(args.threads)
    victim = load_victim(VICTIM)
    con = _connect(Path(args.db))
    con.execute("PRAGMA busy_timeout = 60000")
    done = {r[0] for r in con.execute("SELECT key FROM runs")}
    plan = [(m, p, c, i) for c in args.classes for i in range(args.instances) for p in args.perturbations
            for m in args.methods]
    shard, shards = args.shard
    for method, perturbation, cls, index in plan[shard::shards]:
        key = _key(method, perturbation, cls, index)
        if key in done:
            continue
        t0 = time.perf_counter()
        row = run_one(method, perturbation, cls, index, victim, args)
        with con:
            con.execute("INSERT OR REPLACE INTO runs VALUES (?, ?, ?)",
                        (key, json.dumps(row), time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())))
        print(f"{key}: {time.perf_counter() - t0:.0f} s; " + "; ".join(
            f"{t['target']} held-out {t['success_heldout']:.2f}" for t in row["targets"]), flush=True)
    con.close()


# ------------------------------------------------------------------ report
def _mean(values: Sequence[Optional[float]]) -> Optional[float]:
    vals = [v for v in values if v is not None and not (isinstance(v, float) and math.isnan(v))]
    return sum(vals) / len(vals) if vals else None


def _fmt(value: Optional[float], spec: str = ".2f") -> str:
    return "-" if value is None else format(value, spec)


def summarize(rows: Sequence[Dict[str, Any]], method: str, perturbation: str) -> Optional[Dict[str, Any]]:
    """Means over the (run, target) pairs of ``method`` and ``perturbation`` (``None`` without any)."""
    pairs = [(r, t) for r in rows if r["method"] == method and r["perturbation"] == perturbation
             for t in r["targets"]]
    if not pairs:
        return None
    mits = [t["mitsuba"] for _, t in pairs if t["mitsuba"]]
    return {
        "n": len(pairs), "runs": len({id(r) for r, _ in pairs}),
        "succeeded": sum(t["succeeded"] for _, t in pairs),
        "views": _mean([t["success_views"] for _, t in pairs]),
        "heldout": _mean([t["success_heldout"] for _, t in pairs]),
        "untargeted": _mean([t["untargeted_heldout"] for _, t in pairs]),
        "aa": _mean([t["success_aa"] for _, t in pairs]),
        "mitsuba_untargeted": _mean([m["untargeted_controlled"] for m in mits]),
        "mitsuba_targeted": _mean([m["targeted_fraction"] for m in mits]),
        "pair_mean": _mean([t["laplacian_pair_mean"] for _, t in pairs]),
        "max_move": _mean([t["max_displacement"] for _, t in pairs]),
        "rmse": _mean([t["color_rmse"] for _, t in pairs]),
        "wall": _mean([r["wall_time"] for r, _ in pairs]),
    }


def report(rows: Sequence[Dict[str, Any]], plot: Optional[Path]) -> str:
    """The Markdown summary of ``rows`` (and the frontier plot at ``plot``)."""
    lines = ["| perturbation | method | targets | succeeded | attack views | held-out targeted | held-out untargeted "
             "(benign-controlled) | 4x4 antialiased | Mitsuba untargeted (benign-controlled) | Mitsuba targeted | "
             "pair mean | max move / diag | colour RMSE | s per run |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for p in PERTURBATIONS:
        for m in METHODS:
            s = summarize(rows, m, p)
            if s is None:
                continue
            # Each perturbation leaves the other's distance at zero: show only its own.
            if p == "shape":
                s["rmse"] = None
            else:
                s["pair_mean"] = s["max_move"] = None
            lines.append(f"| {p} | {m} | {s['n']} | {s['succeeded']} | {_fmt(s['views'])} | {_fmt(s['heldout'])} | "
                         f"{_fmt(s['untargeted'])} | {_fmt(s['aa'])} | {_fmt(s['mitsuba_untargeted'])} | "
                         f"{_fmt(s['mitsuba_targeted'])} | {_fmt(s['pair_mean'], '.2e')} | "
                         f"{_fmt(s['max_move'], '.4f')} | {_fmt(s['rmse'], '.4f')} | {_fmt(s['wall'], '.0f')} |")
    if plot is not None and rows:
        plot_frontier(rows, plot)
    return "\n".join(lines)


def plot_frontier(rows: Sequence[Dict[str, Any]], path: Path) -> None:
    """Success on held-out views and in Mitsuba (untargeted, targeted) against distortion, one point per (run,
    target), one colour per method: shape against the pair mean and the largest move, texture against the RMSE."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    measures = [("heldout targeted", lambda t: t["success_heldout"]),
                ("held-out untargeted (benign-ctrl)", lambda t: t["untargeted_heldout"]),
                ("Mitsuba untargeted (benign-ctrl)", lambda t: t["mitsuba"] and t["mitsuba"]["untargeted_controlled"]),
                ("Mitsuba targeted", lambda t: t["mitsuba"] and t["mitsuba"]["targeted_fraction"])]
    axes_x = [("shape", "laplacian_pair_mean", "Laplacian pair mean"),
              ("shape", "max_displacement", "largest vertex move / bbox diagonal"),
              ("texture", "color_rmse", "face-colour RMSE")]
    colors = {"ddn": "tab:blue", "robust": "tab:red", "paper": "tab:green"}
    fig, axes = plt.subplots(len(axes_x), len(measures), figsize=(4 * len(measures), 3.2 * len(axes_x)),
                             squeeze=False)
    for i, (pert, key, xlabel) in enumerate(axes_x):
        for j, (name, get) in enumerate(measures):
            ax = axes[i][j]
            for m in METHODS:
                pts = [(t[key], get(t)) for r in rows if r["method"] == m and r["perturbation"] == pert
                       for t in r["targets"] if t.get(key) and get(t) is not None]
                if pts:
                    ax.scatter([x for x, _ in pts], [y for _, y in pts], s=18, alpha=0.75, color=colors[m], label=m)
            ax.xaxis.set_major_locator(MaxNLocator(4))
            ax.ticklabel_format(axis="x", style="sci", scilimits=(-2, 2))
            ax.set_ylim(-0.05, 1.05)
            ax.set_xlabel(xlabel, fontsize=8)
            ax.set_title(f"{pert}: {name}", fontsize=9)
            if i == 0 and j == 0:
                ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    os.replace(tmp, path)


def _shard(text: str) -> Tuple[int, int]:
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--shard must be i/n, got {text}") from None
    if not 0 <= i < n:
        raise argparse.ArgumentTypeError(f"--shard must be i/n with 0 <= i < n, got {text}")
    return i, n


def main(argv: Optional[Sequence[str]] = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--db", default=str(DEFAULT_DB))
    parser.add_argument("--renders", default=str(OUT / "renders"))
    parser.add_argument("--classes", nargs="+", default=list(CLASSES), choices=CLASSES)
    parser.add_argument("--instances", type=int, default=4)
    parser.add_argument("--targets", type=int, default=6)
    parser.add_argument("--methods", nargs="+", default=["ddn", "robust"], choices=METHODS)
    parser.add_argument("--perturbations", nargs="+", default=list(PERTURBATIONS), choices=PERTURBATIONS)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--paper-steps", type=int, default=1000)
    parser.add_argument("--cap", choices=("none", "default"), default="none",
                        help="attack under no perceptibility cap (the recorded runs) or meshadv's default cap")
    parser.add_argument("--heldout", type=int, default=8)
    parser.add_argument("--mitsuba-views", type=int, default=4)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--shard", type=_shard, default=(0, 1), help="i/n: of the selection's runs, take every n-th "
                                                                     "from the i-th (processes sharing the database)")
    parser.add_argument("--report", action="store_true", help="print the tables instead of running")
    parser.add_argument("--plot", default=str(OUT / "frontier.png"))
    parser.add_argument("--with-db", nargs="+", default=[], metavar="DB",
                        help="--report: add the rows of these databases (another selection or method) to --db's")
    args = parser.parse_args(argv)
    if args.report:
        rows = [row for db in [args.db, *args.with_db] for row in load_rows(Path(db))]
        print(report(rows, Path(args.plot) if args.plot else None))
        return
    run(args)


if __name__ == "__main__":
    sys.exit(main())
