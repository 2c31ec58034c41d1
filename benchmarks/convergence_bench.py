"""Convergence benchmark: success rate and distance at success against optimiser steps, per method.

Benchmark set: the first ``--instances`` (default 2) configurations of each of the 7 classes of the packaged
PASCAL3D+ rendering set (the instances of ``configs/paper_small.toml``), meshes resampled to about 4000 faces,
224 px, 2x antialiasing, EfficientNet-Lite0, every other class as a target (6 targets, attacked together as one
batch: the targets are independent per-target problems, so batching changes nothing but the wall time).

Methods (``--methods``):

* ``paper``: the paper's protocol, Adam + a ``lambda`` binary search, 5 rounds x 1000 steps, no early stopping
  (:class:`~meshadv.attacks.ShapeAttack` / :class:`~meshadv.attacks.TextureAttack` defaults otherwise);
* ``small``: the settings of ``configs/paper_small.toml`` (Adam, 100 steps, early stop after 3 steps held, one
  ``lambda``), read from that file;
* ``ddn``: the distortion-budget method (``method="ddn"``, :mod:`meshadv.attacks.budget`), 300 steps for shape and
  100 for texture.

Curves come from the attack's per-step history (the parameters *before* each update, as the engine records them):
``success(k)`` = the target held at some step ``<= k``; ``distance(k)`` = the least distortion of a step ``<= k``
where it held. Shape distances are given in both conventions, the Eq. 4 sum and the per-pair mean (sum / 2E,
comparable with the paper); texture the face-colour RMSE. The final result (re-rendered from scratch) is stored too.

Each run (method, perturbation, instance) is one row of an SQLite file (``--db``), committed when the run ends; a
rerun skips finished rows, so the benchmark resumes after an interruption. ``--shard i/n`` splits the pending runs
between processes sharing the file. ``--report`` prints the summary table (Markdown) and writes one PNG per method.

While a run goes, its curves so far are stored every ``--checkpoint`` steps and at the end of every round in a
second table (``partial``), so a run stopped early (the paper's 5 x 1000 steps cost hours here) is still reported,
up to the steps it reached and labelled as partial; it is replaced by the run's row when the run finishes. A rerun
starts an unfinished run from its beginning (the attack keeps no resumable optimiser state); its partial row is
only overwritten once the new run has gone further.

Usage:
    python benchmarks/convergence_bench.py --methods ddn small --perturbations texture shape
    python benchmarks/convergence_bench.py --report --plots benchmarks/convergence
    python benchmarks/convergence_bench.py --methods ddn --perturbations shape --only bottle/1 sofa/0 \
        --method-options '{"edge_gradient": 1.0}' --db /tmp/convergence_edge_gradient1.sqlite
    python benchmarks/convergence_bench.py --report --only bottle/1 sofa/0   # the default rows of those instances
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sqlite3
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple

import torch

from meshadv.experiments.tables import PAPER_WORST, tail_stats

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_DB = ROOT / "benchmarks" / "convergence" / "runs.sqlite"
CLASSES = ("aeroplane", "bicycle", "boat", "bottle", "chair", "diningtable", "sofa")
METHODS = ("paper", "small", "ddn")
#: Step budgets the benchmark reports at: shape <= 300, texture <= 100 steps per target.
STEP_TARGETS = {"shape": 300, "texture": 100}
#: Steps of the ddn runs (the step budgets above).
DDN_STEPS = STEP_TARGETS


def _small_settings() -> Dict[str, Dict[str, Any]]:
    try:
        import tomllib
    except ImportError:  # Python < 3.11
        import tomli as tomllib  # type: ignore[no-redef]
    with open(ROOT / "configs" / "paper_small.toml", "rb") as f:
        raw = tomllib.load(f)
    return {p: dict(raw["attack"][p]) for p in ("shape", "texture")}


def method_settings(method: str, perturbation: str) -> Dict[str, Any]:
    """The attack keyword arguments of ``method`` for ``perturbation`` (224 px and 2x antialias added by the caller).

    Raises:
        ValueError: unknown method or perturbation.
    """
    if perturbation not in STEP_TARGETS:
        raise ValueError(f"perturbation must be shape or texture, got {perturbation!r}")
    if method == "paper":
        return {"steps": 1000, "binary_search_steps": 5}
    if method == "small":
        return _small_settings()[perturbation]
    if method == "ddn":
        return {"method": "ddn", "steps": DDN_STEPS[perturbation]}
    raise ValueError(f"method must be one of {METHODS}, got {method!r}")


def make_attack(method: str, perturbation: str, method_options: Optional[Dict[str, Any]] = None,
                attack_options: Optional[Dict[str, Any]] = None) -> Any:
    """The attack object of ``method`` (the render settings of a config are left to :func:`render_setup`).

    ``method_options`` (``ddn`` only) is passed as the attack's ``method_options``; ``attack_options`` (e.g.
    ``{"loss": "cw"}``) override the method's attack keyword arguments.

    Raises:
        ValueError: ``method_options`` for a method other than ``ddn``.
    """
    from meshadv.attacks import make_attack as make_family_attack

    kwargs = {k: v for k, v in method_settings(method, perturbation).items() if k not in ("antialias", "image_size")}
    if method_options:
        if method != "ddn":
            raise ValueError(f"method_options apply to method 'ddn' only, got method {method!r}")
        kwargs["method_options"] = dict(method_options)
    kwargs.update(attack_options or {})
    return make_family_attack(perturbation, **kwargs)


def render_setup() -> Any:
    """224 px, 2x antialiasing, white background (the rendering set's settings)."""
    from meshadv.render import RenderSetup

    return RenderSetup(image_size=224, antialias=2)


def instances(per_class: int, classes: Sequence[str],
              only: Optional[Sequence[Tuple[str, int]]] = None) -> List[Tuple[str, int, Dict[str, Any]]]:
    """``(class, configuration index, rendering record)`` of the benchmark set: every class's first configuration, then
    every class's second, ... (so a partial run covers every class). ``only``: keep just these ``(class, index)``."""
    from meshadv.datasets.rendering_set import load_rendering_set, packaged_rendering_set_path

    doc = load_rendering_set(packaged_rendering_set_path())
    by_class = {cls: [r for r in doc["renderings"] if r["class"] == cls][:per_class] for cls in classes}
    out = [(cls, i, by_class[cls][i]) for i in range(per_class) for cls in classes if i < len(by_class[cls])]
    if only is not None:
        out = [job for job in out if (job[0], job[1]) in set(only)]
    return out


def _curves(history: Sequence[Dict[str, Any]], num_targets: int) -> List[Dict[str, Any]]:
    """Per target: the first step that held, every step where the least distance at success fell, and the best
    (largest) margin of any step (``best_margin``; > 0 once it held, how close a miss came otherwise).

    Steps are 1-based counts of optimiser steps (over all rounds of a ``lambda`` search).
    """
    out: List[Dict[str, Any]] = [{"first": None, "improvements": [], "best_margin": None} for _ in range(num_targets)]
    best = [math.inf] * num_targets
    for k, row in enumerate(history, start=1):
        for t in range(num_targets):
            margin, dist = row["margin"][t], row["distance"][t]
            if margin is not None and (out[t]["best_margin"] is None or margin > out[t]["best_margin"]):
                out[t]["best_margin"] = float(margin)
            if margin is None or dist is None or not margin > 0:
                continue
            if out[t]["first"] is None:
                out[t]["first"] = k
            if dist < best[t]:
                best[t] = dist
                out[t]["improvements"].append([k, float(dist)])
    return out


class _Progress:
    """Step callback of one run: keeps the margins and distances of every step, prints a line every ``every`` steps
    and hands a partial row to ``save`` every ``every`` steps and at the end of every round."""

    def __init__(self, key: str, base: Dict[str, Any], every: int, save: Any) -> None:
        self.key, self.base, self.every, self.save = key, base, every, save
        self.history: List[Dict[str, Any]] = []
        self.wall0, self.cpu0 = time.perf_counter(), time.process_time()

    def partial_row(self, rounds: int, steps: int) -> Dict[str, Any]:
        """The row of the steps done so far (no final re-render: ``final_success`` is ``None``)."""
        done = len(self.history)
        return {**self.base, "steps": done, "history_len": done, "wall_time": time.perf_counter() - self.wall0,
                "cpu_time": time.process_time() - self.cpu0, "curves": _curves(self.history, len(self.base["targets"])),
                "final_success": None, "final_distances": None,
                "partial": {"steps_done": done, "steps_planned": rounds * steps, "rounds": rounds,
                            "steps_per_round": steps}}

    def __call__(self, info: Any) -> None:
        self.history.append({"margin": list(info.margin), "distance": list(info.distance)})
        round_end = info.step + 1 == info.steps
        if info.total_step % self.every == 0 or round_end:
            held = sum(b is not None for b in info.best_distance)
            print(f"{self.key}: round {info.round + 1}/{info.rounds} step {info.step + 1}/{info.steps}, "
                  f"{held}/{len(info.best_distance)} targets held so far, {time.process_time() - self.cpu0:.0f} s CPU",
                  flush=True)
            self.save(self.key, self.partial_row(info.rounds, info.steps))


def instance_scene(record: Dict[str, Any], target_faces: int = 4000) -> Tuple[Any, Any]:
    """``(mesh, views)`` of a benchmark instance's rendering record: its PASCAL3D+ mesh resampled to ``target_faces``
    (as the sweeps do) and its one view."""
    from meshadv.experiments.jobs import load_job_mesh
    from meshadv.render import ViewSet

    mesh = load_job_mesh({"source": "pascal3d", "path": record["mesh"], "target_faces": target_faces,
                          "max_faces": 100000})
    return mesh, ViewSet.from_records([record["view"]])


def instance_record(name: str) -> Dict[str, Any]:
    """The rendering record of benchmark instance ``name`` (``"class/index"``, e.g. ``"bottle/1"``).

    Raises:
        ValueError: ``name`` is not an instance of the benchmark set.
    """
    cls, _, index = name.partition("/")
    found = [r for c, i, r in instances(2, CLASSES) if c == cls and index.isdigit() and i == int(index)]
    if not found:
        raise ValueError(f"instance must be one of the benchmark set's 'class/index' names, got {name!r}")
    return found[0]


def run_one(method: str, perturbation: str, cls: str, index: int, record: Dict[str, Any], victim: Any,
            target_faces: int, progress: Optional[Tuple[int, Any]] = None,
            method_options: Optional[Dict[str, Any]] = None,
            attack_options: Optional[Dict[str, Any]] = None) -> Dict[str, Any]:
    """Attack one instance towards its 6 targets with ``method``; the JSON-able row.

    ``method_options`` and ``attack_options``: see :func:`make_attack` (the row's ``config`` records them).

    ``progress`` = ``(every, save)``: ``save(key, partial_row)`` is called every ``every`` steps and at the end of
    every round (see :class:`_Progress`). A run stopped by Ctrl-C (SIGINT) returns the row of the steps done, with
    ``row["partial"]`` set and the final re-render of its best result so far.
    """
    from meshadv.attacks import TargetedMisclassification
    from meshadv.mesh import vertex_edges

    mesh, views = instance_scene(record, target_faces)
    targets = [c for c in CLASSES if c != cls]
    attack = make_attack(method, perturbation, method_options, attack_options)
    base = {
        "method": method, "perturbation": perturbation, "class": cls, "index": index, "mesh": record["mesh"],
        "candidate": record.get("candidate"), "targets": targets, "num_vertices": int(mesh.vertices.shape[0]),
        "num_faces": int(mesh.faces.shape[0]), "num_edges": int(vertex_edges(mesh.faces).shape[0]),
        "config": attack.config(), "threads": torch.get_num_threads(), "setup": render_setup().config(),
    }
    callback = None if progress is None else _Progress(_key(method, perturbation, cls, index), base, *progress)
    start, cpu_start = time.perf_counter(), time.process_time()
    result = attack(mesh, views, victim, [TargetedMisclassification(t) for t in targets], setup=render_setup(),
                    callback=callback)
    row = {
        **base, "steps": int(result.steps), "history_len": len(result.loss_history),
        "wall_time": time.perf_counter() - start, "cpu_time": time.process_time() - cpu_start,
        "curves": _curves(result.loss_history, len(targets)),
        "final_success": [bool(s) for s in result.succeeded.tolist()],
        "final_distances": [dict(d) for d in result.distances],
    }
    if result.interrupted:
        row["partial"] = {"steps_done": len(result.loss_history),
                          "steps_planned": attack.steps * attack.binary_search_steps,
                          "rounds": attack.binary_search_steps, "steps_per_round": attack.steps}
    return row


def _connect(db: Path) -> sqlite3.Connection:
    db.parent.mkdir(parents=True, exist_ok=True)
    con = sqlite3.connect(str(db), timeout=60.0)
    con.execute("CREATE TABLE IF NOT EXISTS runs (key TEXT PRIMARY KEY, row TEXT NOT NULL, finished TEXT NOT NULL)")
    con.execute("CREATE TABLE IF NOT EXISTS partial (key TEXT PRIMARY KEY, row TEXT NOT NULL, updated TEXT NOT NULL)")
    con.commit()
    return con


def _key(method: str, perturbation: str, cls: str, index: int) -> str:
    return f"{method}/{perturbation}/{cls}/{index}"


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def load_rows(db: Path) -> List[Dict[str, Any]]:
    """Every finished row of the benchmark file, then the partial rows of runs that have none (``row["partial"]``
    says how far they got)."""
    if not db.exists():
        return []
    con = _connect(db)
    try:
        rows = [json.loads(r) for (r,) in con.execute("SELECT row FROM runs ORDER BY key")]
        rows += [json.loads(r) for (r,) in con.execute(
            "SELECT row FROM partial WHERE key NOT IN (SELECT key FROM runs) ORDER BY key")]
        return rows
    finally:
        con.close()


def _save_partial(con: sqlite3.Connection, key: str, row: Dict[str, Any]) -> None:
    """Store ``row`` as the partial row of ``key`` unless a stored one went further."""
    old = con.execute("SELECT row FROM partial WHERE key = ?", (key,)).fetchone()
    if old is not None and json.loads(old[0])["partial"]["steps_done"] > row["partial"]["steps_done"]:
        return
    with con:
        con.execute("INSERT OR REPLACE INTO partial VALUES (?, ?, ?)", (key, json.dumps(row), _now()))


def run(args: argparse.Namespace) -> None:
    """Run the pending runs of this shard, one committed row each."""
    from meshadv.victims import load_victim

    if (args.method_options or args.attack_options) and args.db.resolve() == DEFAULT_DB.resolve():
        raise SystemExit("--method-options / --attack-options need their own --db (the default file holds the "
                         "benchmark's default rows, and rows are keyed by method, perturbation and instance only)")
    con = _connect(args.db)
    done = {k for (k,) in con.execute("SELECT key FROM runs")}
    plan = [(m, p, c, i, r) for m in args.methods for p in args.perturbations
            for c, i, r in instances(args.instances, args.classes, args.only)]
    pending = [job for job in plan if _key(*job[:4]) not in done]
    shard, shards = args.shard
    pending = pending[shard::shards]
    print(f"{len(plan)} runs planned, {len(plan) - len(pending)} finished or in other shards, {len(pending)} to run",
          flush=True)
    victim = load_victim("efficientnet_lite0")
    for method, perturbation, cls, index, record in pending:
        key = _key(method, perturbation, cls, index)
        if con.execute("SELECT 1 FROM runs WHERE key = ?", (key,)).fetchone():
            continue
        row = run_one(method, perturbation, cls, index, record, victim, args.target_faces,
                      progress=(args.checkpoint, lambda k, r: _save_partial(con, k, r)),
                      method_options=args.method_options, attack_options=args.attack_options)
        if row.get("partial"):
            _save_partial(con, key, row)
            print(f"{key}: stopped at step {row['history_len']}; partial row stored, no further runs", flush=True)
            break
        with con:
            con.execute("INSERT OR REPLACE INTO runs VALUES (?, ?, ?)", (key, json.dumps(row), _now()))
            con.execute("DELETE FROM partial WHERE key = ?", (key,))
        ok = sum(row["final_success"])
        print(f"{key}: {ok}/{len(row['targets'])} final successes, {row['steps']} steps, {row['wall_time']:.0f} s",
              flush=True)
    con.close()


#: What ``--import-sweep`` takes from a sweep, per method: the jobs' ``protocol`` (``None``: the main setting) and
#: the victim, so that a sweep of several victims and protocols gives each method the jobs it ran.
IMPORTED_JOBS = {"small": (None, "efficientnet_lite0"), "paper": ("paper", "efficientnet_lite0")}


def import_sweep(sweep_db: Path, db: Path, method: str = "small") -> int:
    """Store a sweep's finished single-view jobs of ``method`` as its rows: ``small`` the main setting of a
    ``configs/paper_small.toml`` sweep, ``paper`` the paper's protocol of ``configs/paper_medium.toml``
    (``[attack.protocols.paper]``, on the benchmark's instances: its first 2 configurations per class).

    Those sweeps attack the same instances, one target per job; their records hold each target's first successful
    step (counted over all rounds of a lambda search) and the distances of the kept (least distorted) success, which
    give the success curve exactly and the distance curve from the first success on. Instances whose benign render
    the sweep skipped, or with unfinished jobs, are left out, and so is an instance this database already holds a
    row of the method for that the benchmark measured itself (its curves are complete). Returns the number of rows
    written.
    """
    protocol, victim = IMPORTED_JOBS[method]
    con = sqlite3.connect(f"file:{sweep_db}?mode=ro", uri=True, timeout=60.0)
    jobs = [(json.loads(spec), json.loads(rec)) for spec, rec in
            con.execute("SELECT spec, record FROM jobs WHERE state = 'done' AND record IS NOT NULL")]
    con.close()
    groups: Dict[Tuple[str, str, int], Dict[str, Any]] = {}
    for spec, rec in jobs:
        if spec.get("kind") != "single" or spec.get("protocol") != protocol or spec.get("victim") != victim:
            continue
        key = (spec["perturbation"], spec["source_class"], int(spec["config_index"]))
        groups.setdefault(key, {"spec": spec, "targets": {}})["targets"][spec["target"]] = rec
    out = _connect(db)
    measured = {key for key, row in out.execute("SELECT key, row FROM runs")
                if not str(json.loads(row).get("source") or "").startswith("imported")}
    written = 0
    for (perturbation, cls, index), group in sorted(groups.items()):
        targets = [c for c in CLASSES if c != cls]
        recs = group["targets"]
        key = _key(method, perturbation, cls, index)
        if set(recs) != set(targets) or any(r.get("skipped") for r in recs.values()) or key in measured:
            continue
        curves, final, dists = [], [], []
        for t in targets:
            r = recs[t]
            d = dict(r.get("distances") or {})
            first = r.get("steps_to_success")
            dist = d.get("laplacian_sum" if perturbation == "shape" else "color_rmse")
            curves.append({"first": first, "improvements": [[first, dist]] if first is not None and r["success"]
                           else []})
            final.append(bool(r["success"]))
            dists.append(d)
        first_rec = recs[targets[0]]
        attack = {k: v for k, v in group["spec"]["attack"].items() if k != "antialias"}
        row = {
            "method": method, "perturbation": perturbation, "class": cls, "index": index,
            "mesh": group["spec"]["mesh"]["path"], "candidate": None, "targets": targets,
            "num_vertices": first_rec["num_vertices"], "num_faces": first_rec["num_faces"],
            "num_edges": int(dists[0]["num_edges"]), "steps": sum(int(recs[t]["steps"]) for t in targets),
            "history_len": int(attack["steps"]) * int(attack.get("binary_search_steps", 1)),
            "wall_time": sum(float(recs[t]["time"]) for t in targets),
            "config": attack, "curves": curves, "final_success": final, "final_distances": dists,
            "threads": None, "source": f"imported from the sweep {sweep_db} (one job per target)",
        }
        with out:
            out.execute("INSERT OR REPLACE INTO runs VALUES (?, ?, ?)", (key, json.dumps(row), _now()))
        written += 1
    out.close()
    return written


def step_cost(steps: int, repeats: int = 3) -> Dict[Tuple[str, str], List[float]]:
    """Process CPU seconds per optimiser step of ``method="adam"`` (the paper's and paper_small's rule) and
    ``method="ddn"``, one target (aeroplane/0 towards boat), measured side by side ``repeats`` times, alternating.

    Only the steps count (between the first and the last step callback), not the setup or the final re-render, so
    the cost per target of a method is its steps times this.
    """
    from meshadv.attacks import TargetedMisclassification
    from meshadv.victims import load_victim
    from meshadv.attacks import make_attack as make_family_attack

    _, _, record = instances(1, ["aeroplane"])[0]
    mesh, views = instance_scene(record)
    victim = load_victim("efficientnet_lite0")
    out: Dict[Tuple[str, str], List[float]] = {}
    for _ in range(repeats):
        for perturbation in ("shape", "texture"):
            for method in ("adam", "ddn"):
                stamps: List[float] = []
                make_family_attack(perturbation, steps=steps, method=method)(
                    mesh, views, victim, TargetedMisclassification("boat"), setup=render_setup(),
                    callback=lambda _info: stamps.append(time.process_time()))
                out.setdefault((perturbation, method), []).append((stamps[-1] - stamps[0]) / (len(stamps) - 1))
    return out


# ---------------------------------------------------------------------------------------------------- report
def _distance_key(perturbation: str) -> str:
    return "laplacian_pair_mean" if perturbation == "shape" else "color_rmse"


def target_curves(row: Dict[str, Any], max_steps: int) -> Tuple[List[List[bool]], List[List[float]]]:
    """Per target, success (held at some step <= k) and least distance at success for k = 1..max_steps.

    Shape distances are converted to the per-pair mean (sum / 2E); ``nan`` before the first success.
    """
    scale = 1.0 / (2.0 * row["num_edges"]) if row["perturbation"] == "shape" else 1.0
    succ, dist = [], []
    for c in row["curves"]:
        s, d = [False] * max_steps, [math.nan] * max_steps
        imps = c["improvements"]
        j, cur = 0, math.nan
        for k in range(1, max_steps + 1):
            while j < len(imps) and imps[j][0] <= k:
                cur = imps[j][1] * scale
                j += 1
            s[k - 1] = c["first"] is not None and c["first"] <= k
            d[k - 1] = cur
        succ.append(s)
        dist.append(d)
    return succ, dist


def summarize(rows: Sequence[Dict[str, Any]], method: str, perturbation: str,
              budget: Optional[int] = None) -> Optional[Dict[str, Any]]:
    """The benchmark's measures for one method and perturbation within ``budget`` steps per target.

    A partial row (a run stopped early, ``row["partial"]``) counts only for budgets it reached.

    Returns:
        ``None`` without rows, else a dict with ``instances``, ``targets``, ``success`` (mean over targets),
        ``worst`` (fraction of instances whose every target held), ``median_distance`` (over targets that held, at
        their least distance), ``sum_median`` (the Eq. 4 sum, shape only), ``final_success`` (``None`` when no row
        has a final re-render), ``steps``, ``wall_time`` and ``partial`` (the partial rows' ``(steps done, steps
        planned)``); the distortion tail: ``tail`` (:class:`meshadv.experiments.tables.TailStats` of the same
        distances: median, 90th percentile, largest, and the share above :data:`PAPER_WORST`, the paper's largest
        worst-case distance) and ``displacement`` (``TailStats`` of the largest vertex displacement in % of the
        bounding-box diagonal, over the final results that succeeded, for rows the budget covers whole and that
        store it; ``n == 0`` otherwise, e.g. texture).
    """
    sel = [r for r in rows if r["method"] == method and r["perturbation"] == perturbation]
    budget = budget or max((r["history_len"] for r in sel), default=0)
    sel = [r for r in sel if not r.get("partial") or r["history_len"] >= budget]
    if not sel:
        return None
    held, worst, dists, sums, final, disp = [], [], [], [], [], []
    for r in sel:
        succ, dist = target_curves(r, budget)
        row_held = [s[-1] for s in succ]
        held.extend(row_held)
        worst.append(all(row_held))
        for ok, d in zip(row_held, dist):
            if ok:
                dists.append(d[-1])
                if r["perturbation"] == "shape":
                    sums.append(d[-1] * 2.0 * r["num_edges"])
        final.extend(r["final_success"] or [])
        disp.extend(_final_displacements(r, budget))
    return {
        "instances": len(sel), "targets": len(held), "success": sum(held) / len(held),
        "worst": sum(worst) / len(worst), "median_distance": statistics.median(dists) if dists else math.nan,
        "sum_median": statistics.median(sums) if sums else math.nan,
        "final_success": sum(final) / len(final) if final else None, "steps": budget,
        "wall_time": sum(r["wall_time"] for r in sel),
        "partial": [(r["partial"]["steps_done"], r["partial"]["steps_planned"]) for r in sel if r.get("partial")],
        "tail": tail_stats(dists, PAPER_WORST[perturbation]), "displacement": tail_stats(disp),
    }


def _final_displacements(row: Dict[str, Any], budget: int) -> List[float]:
    """The largest vertex displacement (% of the bounding-box diagonal) of each target whose final result succeeded,
    for a finished shape row that ``budget`` covers whole (the final result is the run's last word, not the one at
    ``budget`` steps) and that stores it; empty otherwise."""
    if row["perturbation"] != "shape" or row.get("partial") or budget < row["history_len"]:
        return []
    out = []
    for ok, d in zip(row.get("final_success") or [], row.get("final_distances") or []):
        if ok and d and d.get("max_displacement") is not None:
            out.append(100.0 * float(d["max_displacement"]))
    return out


def tail_above(rows: Sequence[Dict[str, Any]], method: str, perturbation: str) -> List[str]:
    """``"class/index -> target 1.2e-03"`` for every target of the finished rows of ``method`` whose least distance at
    success (at the row's last step) is above :data:`PAPER_WORST`, largest first."""
    out = []
    for r in rows:
        if r["method"] != method or r["perturbation"] != perturbation or r.get("partial"):
            continue
        succ, dist = target_curves(r, r["history_len"])
        for target, s, d in zip(r["targets"], succ, dist):
            if s and s[-1] and d[-1] > PAPER_WORST[perturbation]:
                out.append((d[-1], f"{r['class']}/{r['index']} -> {target} {d[-1]:.2g}"))
    return [text for _, text in sorted(out, reverse=True)]


def _method_label(method: str, s: Dict[str, Any]) -> str:
    """``method``, with the steps reached when the summary includes partial rows."""
    if not s["partial"]:
        return method
    reached = ", ".join(f"{done} of {planned}" for done, planned in s["partial"])
    return f"{method} (PARTIAL: {len(s['partial'])} of {s['instances']} runs stopped early, steps {reached})"


def _summary_row(method: str, perturbation: str, steps: Any, s: Dict[str, Any]) -> str:
    """One Markdown row of the summary table for a :func:`summarize` result ``s`` at ``steps``."""
    name = "Laplacian pair mean" if perturbation == "shape" else "colour RMSE"
    sums = f"{s['sum_median']:.3g}" if perturbation == "shape" else "-"
    final = "-" if s["final_success"] is None else f"{100 * s['final_success']:.1f}%"
    tail, disp = s["tail"], s["displacement"]
    above = "-" if tail.n == 0 else f"{100 * tail.above:.1f}% ({tail.above_n}/{tail.n})"
    moved = "-" if disp.n == 0 else f"{disp.median:.2g}% / {disp.p90:.2g}% ({disp.n})"
    return (f"| {_method_label(method, s)} | {perturbation} | {s['instances']} | {s['targets']} | {steps} | "
            f"{100 * s['success']:.1f}% | {100 * s['worst']:.0f}% | {name} {s['median_distance']:.3g}"
            f" | {sums} | {final} | {s['wall_time']:.0f} s | {_num(tail.p90)} | {_num(tail.max)} | {above} | "
            f"{moved} |")


def _num(value: float) -> str:
    return "-" if math.isnan(value) else f"{value:.3g}"


#: The summary table's header (Markdown, two lines).
SUMMARY_HEADER = [
    "| method | perturbation | instances | targets | steps per target | success | worst case (all 6 held) "
    "| median distance at success | median Eq. 4 sum | final re-render success | wall time (loaded) "
    "| p90 distance at success | max distance at success | successes above the paper's worst case "
    "| largest vertex displacement, median / p90 (% of bbox diagonal; final successes) |",
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

#: What the tail columns mean (printed under the table).
TAIL_NOTE = (f"Distances: for shape the per-pair-mean Laplacian (`laplacian_pair_mean`, Eq. 4's sum / 2E), the "
             f"convention comparable to the paper's Laplacian numbers (the Eq. 4 sum has its own column); for "
             f"texture the paper's colour RMSE. "
             f"Tail columns: the 90th percentile (linear interpolation) and the largest of the same distances as the "
             f"median (per-pair-mean Laplacian for shape, colour RMSE for texture), and the share of successes above "
             f"the paper's largest worst-case distance (shape {PAPER_WORST['shape']:.2g}, texture "
             f"{PAPER_WORST['texture']:.2g}; the paper's worst case is a mean over its instances, and the paper "
             f"reports no percentiles). Which column compares with the paper: none exactly, the paper's Table 1 gives "
             f"means (average case) and means of per-instance maxima (worst case); the share above its worst case "
             f"is the direct check that no success is more distorted than the paper's worst case on average was, "
             f"and p90 / max show how far the tail goes. "
             f"Displacement: the largest vertex displacement of each successful final result, in % of the mesh's "
             f"bounding-box diagonal (finished shape runs at their full step budget).")


def report(rows: Sequence[Dict[str, Any]], plots: Optional[Path]) -> str:
    """The Markdown summary table (and one PNG per method into ``plots``)."""
    lines = list(SUMMARY_HEADER)
    for method in METHODS:
        for perturbation in ("shape", "texture"):
            horizons = [r["history_len"] for r in rows if r["method"] == method and r["perturbation"] == perturbation]
            budgets = sorted({b for b in (50, 100, 300, 1000, 2000, 3000, 4000) if horizons and b < max(horizons)}
                             | ({max(horizons)} if horizons else set()))
            for budget in budgets:
                s = summarize(rows, method, perturbation, budget)
                if s is None:
                    continue
                lines.append(_summary_row(method, perturbation, budget, s))
    misses = []
    for method in METHODS:
        for perturbation in ("shape", "texture"):
            sel = [r for r in rows if r["method"] == method and r["perturbation"] == perturbation
                   and not r.get("partial")]
            missed = [f"{r['class']}/{r['index']} -> {t}"
                      + (f" (best margin {c['best_margin']:.2f})" if c.get("best_margin") is not None else "")
                      for r in sel for t, c in zip(r["targets"], r["curves"]) if c["first"] is None]
            if sel:
                misses.append(f"- {method} {perturbation}: {len(missed)} target(s) never held"
                              + (f": {', '.join(missed)}" if missed else ""))
    lines += ["", "Targets never held (finished runs):", "", *misses]
    above = []
    for method in METHODS:
        for perturbation in ("shape", "texture"):
            found = tail_above(rows, method, perturbation)
            if found:
                above.append(f"- {method} {perturbation}: {len(found)}: {', '.join(found)}")
    lines += ["", TAIL_NOTE, "", "Successes above the paper's worst case (finished runs, least distance at success at "
              "the last step):", "", *(above or ["- none"])]
    lines += ["", "Same instances only (those every method listed ran):", "", *SUMMARY_HEADER]
    for perturbation in ("shape", "texture"):
        runs: Dict[str, set] = {}
        for r in rows:
            if r["perturbation"] == perturbation:
                runs.setdefault(r["method"], set()).add((r["class"], r["index"]))
        if len(runs) < 2:
            continue
        common = set.intersection(*runs.values())
        for method in METHODS:
            sel = [r for r in rows if r["method"] == method and r["perturbation"] == perturbation
                   and (r["class"], r["index"]) in common]
            s = summarize(sel, method, perturbation, None) if sel else None
            if s is None:
                continue
            lines.append(_summary_row(method, perturbation, s["steps"], s))
    if plots is not None:
        for method in METHODS:
            if any(r["method"] == method for r in rows):
                plot_method(rows, method, plots / f"convergence_{method}.png")
        plot_compare(rows, plots / "convergence_compare.png")
    return "\n".join(lines)


def _mean_curves(sel: Sequence[Dict[str, Any]]) -> Tuple[List[float], List[float], List[Dict[str, Any]]]:
    """Success rate (%) and median least distance at success per step over the targets of ``sel``, and the partial
    records of ``sel``; with partial rows the curves end at the fewest steps a partial run reached."""
    partial = [r["partial"] for r in sel if r.get("partial")]
    horizon = max(r["history_len"] for r in sel)
    if partial:
        horizon = min(horizon, min(q["steps_done"] for q in partial))
    succ_all: List[List[bool]] = []
    dist_all: List[List[float]] = []
    for r in sel:
        s, d = target_curves(r, horizon)
        succ_all.extend(s)
        dist_all.extend(d)
    rate = [100.0 * sum(s[k] for s in succ_all) / len(succ_all) for k in range(horizon)]
    med = []
    for k in range(horizon):
        vals = [d[k] for d in dist_all if not math.isnan(d[k])]
        med.append(statistics.median(vals) if vals else math.nan)
    return rate, med, partial


def _partial_note(partial: Sequence[Dict[str, Any]]) -> str:
    if not partial:
        return ""
    return (f"PARTIAL: {len(partial)} run(s) stopped at step {min(q['steps_done'] for q in partial)} of "
            f"{partial[0]['steps_planned']}")


def _plot_column(ax_s: Any, ax_d: Any, perturbation: str,
                 series: Sequence[Tuple[str, Sequence[Dict[str, Any]]]]) -> None:
    """Success and distance curves of each ``(label, rows)`` of ``series`` on one column of axes."""
    for label, sel in series:
        if not sel:
            continue
        rate, med, partial = _mean_curves(sel)
        steps = list(range(1, len(rate) + 1))
        ax_s.plot(steps, rate, label=label)
        ax_d.plot(steps, med, label=label)
        per_round = int(sel[0]["config"].get("steps", len(rate)))
        for end in range(per_round, len(rate), per_round):
            for ax in (ax_s, ax_d):
                ax.axvline(end, color="grey", linestyle=":", linewidth=1)
    ax_s.set_ylabel("targets reached (%)")
    ax_s.set_ylim(0, 101)
    ax_d.set_yscale("log")
    ax_d.set_ylabel("median least distance at success\n" + (
        "(Laplacian per-pair mean)" if perturbation == "shape" else "(colour RMSE)"))
    ax_d.axhline(1.8e-4 if perturbation == "shape" else 1.1e-2, color="grey", linestyle="--", linewidth=1,
                 label="paper average")
    for ax in (ax_s, ax_d):
        ax.set_xlabel("optimiser steps per target")
        ax.set_xscale("log")
        ax.axvline(STEP_TARGETS[perturbation], color="red", linestyle=":", linewidth=1)
        ax.legend(fontsize=7)


def plot_method(rows: Sequence[Dict[str, Any]], method: str, path: Path) -> None:
    """Success rate and median distance at success against steps, shape and texture, one PNG.

    With partial rows (runs stopped early) the curves end at the fewest steps a partial run reached, and the title
    says so; dotted grey lines mark the ends of a ``lambda`` search's rounds.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(10, 7), constrained_layout=True)
    for col, perturbation in enumerate(("shape", "texture")):
        sel = [r for r in rows if r["method"] == method and r["perturbation"] == perturbation]
        note = _partial_note([r["partial"] for r in sel if r.get("partial")])
        axes[0, col].set_title(f"{method}, {perturbation} ({len(sel)} instances)" + (f"\n{note}" if note else ""))
        if sel:
            _plot_column(axes[0, col], axes[1, col], perturbation, [(method, sel)])
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_compare(rows: Sequence[Dict[str, Any]], path: Path) -> None:
    """Every method's curves on the same axes, per perturbation on the instances every method with rows for it
    ran (partial runs labelled), one PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5), constrained_layout=True)
    for col, perturbation in enumerate(("shape", "texture")):
        runs: Dict[str, set] = {}
        for r in rows:
            if r["perturbation"] == perturbation:
                runs.setdefault(r["method"], set()).add((r["class"], r["index"]))
        common = set.intersection(*runs.values()) if runs else set()
        series = []
        for method in METHODS:
            sel = [r for r in rows if r["method"] == method and r["perturbation"] == perturbation
                   and (r["class"], r["index"]) in common]
            note = _partial_note([r["partial"] for r in sel if r.get("partial")])
            series.append((f"{method}" + (f" ({note})" if note else ""), sel))
        axes[0, col].set_title(f"{perturbation}: {len(common)} instance(s) every method ran")
        _plot_column(axes[0, col], axes[1, col], perturbation, series)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _shard(text: str) -> Tuple[int, int]:
    i, n = (int(x) for x in text.split("/"))
    if not 0 <= i < n:
        raise argparse.ArgumentTypeError(f"--shard must be i/n with 0 <= i < n, got {text}")
    return i, n


def _json_object(text: str) -> Dict[str, Any]:
    try:
        value = json.loads(text)
    except json.JSONDecodeError as err:
        raise argparse.ArgumentTypeError(f"not valid JSON ({err}): {text}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"must be a JSON object, got {text}")
    return value


def _instance(text: str) -> Tuple[str, int]:
    cls, _, index = text.partition("/")
    if cls not in CLASSES or not index.isdigit():
        raise argparse.ArgumentTypeError(f"must be CLASS/INDEX with CLASS one of {CLASSES}, got {text}")
    return cls, int(index)


def main(argv: Optional[Sequence[str]] = None) -> None:
    """Command line (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=["ddn", "small"])
    parser.add_argument("--perturbations", nargs="+", choices=("shape", "texture"), default=["texture", "shape"])
    parser.add_argument("--classes", nargs="+", choices=CLASSES, default=list(CLASSES))
    parser.add_argument("--instances", type=int, default=2, help="rendering-set configurations per class")
    parser.add_argument("--only", nargs="+", type=_instance, default=None, metavar="CLASS/INDEX",
                        help="run only these instances of the benchmark set (e.g. bottle/1 sofa/0)")
    parser.add_argument("--method-options", type=_json_object, default=None, metavar="JSON",
                        help="ddn's method_options, e.g. '{\"smoothness\": 1.0}' (use a separate --db per setting: "
                             "rows are keyed by method, perturbation and instance only)")
    parser.add_argument("--attack-options", type=_json_object, default=None, metavar="JSON",
                        help="extra attack keyword arguments, e.g. '{\"loss\": \"cw\"}' (a separate --db too)")
    parser.add_argument("--target-faces", type=int, default=4000)
    parser.add_argument("--db", type=Path, default=DEFAULT_DB)
    parser.add_argument("--shard", type=_shard, default=(0, 1))
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--checkpoint", type=_positive, default=100,
                        help="store a running run's curves every this many steps (and at every round's end)")
    parser.add_argument("--report", action="store_true", help="print the summary and write the plots; run nothing")
    parser.add_argument("--plots", type=Path, default=None)
    parser.add_argument("--import-sweep", type=Path, default=None, metavar="RESULTS_DB",
                        help="store a sweep's finished jobs as rows of --import-method; run nothing")
    parser.add_argument("--import-method", choices=sorted(IMPORTED_JOBS), default="small",
                        help="small: a paper_small sweep's main setting; paper: paper_medium's paper protocol")
    parser.add_argument("--step-cost", type=_positive, default=None, metavar="STEPS",
                        help="print the CPU seconds per step of adam and ddn (1 target, STEPS steps, 3 repeats); "
                             "run nothing else")
    args = parser.parse_args(argv)
    if args.step_cost is not None:
        torch.set_num_threads(args.threads)
        for (perturbation, method), values in step_cost(args.step_cost).items():
            print(f"{perturbation} {method}: median {statistics.median(values):.4f} CPU s per step "
                  f"(runs: {', '.join(f'{v:.4f}' for v in values)})")
        return
    if args.import_sweep is not None:
        print(f"{import_sweep(args.import_sweep, args.db, args.import_method)} rows imported")
        return
    if args.report:
        rows = load_rows(args.db)
        if args.only is not None:
            rows = [r for r in rows if (r["class"], r["index"]) in set(args.only)]
        print(report(rows, args.plots))
        return
    torch.set_num_threads(args.threads)
    os.environ.setdefault("RAYON_NUM_THREADS", str(args.threads))
    run(args)


if __name__ == "__main__":
    sys.exit(main())
