"""Margin study: does asking ddn for a logit margin make its attacks transfer to Mitsuba (issue 16, Table 3)?

``method="ddn"`` shrinks the distortion budget while the target holds, so it ends on the victim's decision
boundary. This script reruns paper_medium's main-setting attacks (``configs/paper_medium.toml``: the packaged
rendering set, 4,000-face resampling, 224 px, antialias 2, ddn defaults, 300 shape / 100 texture steps, seed 0)
with a required logit margin ``m``: the target only counts as held when its logit beats every other logit by more
than ``m``. It uses the job's own ``required_margin`` attack option (:func:`meshadv.experiments.jobs.run_attack_job`
wraps the criterion in :class:`meshadv.attacks.WithMargin`; the loss stays the plain targeted cross-entropy), so a
row is exactly the job a config with ``required_margin = m`` would run. Each finished attack is then re-rendered by
Mitsuba under its own camera and lights (:func:`meshadv.transfer.controlled.controlled_transfer`, spp 64, depth 8:
``meshadv transfer controlled``'s defaults) and one JSON line is appended to the results file (resumable: rows
already there are skipped).

``m = 0`` rows can be taken from paper_medium's database (``--reference-db``: its records and its Table 3 Mitsuba
verdicts) instead of being rerun; ``--check`` reruns a few of them to show the rerun reproduces the database.

Examples::

    env OMP_NUM_THREADS=1 RAYON_NUM_THREADS=1 python benchmarks/margin_study.py run --margins 1 4
    python benchmarks/margin_study.py import-reference      # m = 0 rows from docs/results/paper_medium/results.db
    python benchmarks/margin_study.py summary --plot benchmarks/margin_study/margin_study.png
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Dict, Iterable, List, Optional, Sequence, Tuple

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CONFIG = ROOT / "configs" / "paper_medium.toml"
DEFAULT_OUT = ROOT / "benchmarks" / "margin_study" / "results.jsonl"
DEFAULT_REFERENCE = ROOT / "docs" / "results" / "paper_medium" / "results.db"
VICTIM = "efficientnet_lite0"


def study_jobs(config: Path, *, perturbations: Sequence[str], classes: Optional[Sequence[str]], config_index: int,
               part: str = "main") -> List[Dict[str, Any]]:
    """The sweep specs of the study: ``part`` (``"main"`` or ``"multiview"``) jobs of the Lite0 victim, of
    configuration ``config_index`` (main setting only), of the given perturbation types and classes, ordered
    target-major (every class's first target, then every class's second...), so a stopped run covers every class.

    Raises:
        ValueError: no job matches.
    """
    from meshadv.experiments.config import expand_jobs, job_part, load_config

    jobs = [j for j in expand_jobs(load_config(config)) if job_part(j) == part and j["victim"] == VICTIM
            and j["perturbation"] in perturbations and (classes is None or j["source_class"] in classes)
            and (part != "main" or int(j.get("config_index", 0)) == config_index)]
    if not jobs:
        raise ValueError("no job of the config matches --perturbations / --classes / --config-index")
    rank: Dict[Tuple[str, str], int] = {}
    for j in jobs:
        key = (j["perturbation"], j["source_class"])
        j["_rank"] = rank.get(key, 0)
        rank[key] = j["_rank"] + 1
    order = {p: i for i, p in enumerate(perturbations)}
    jobs.sort(key=lambda j: (order[j["perturbation"]], j.pop("_rank")))
    return jobs


def row_key(spec: Dict[str, Any], margin: float) -> str:
    """Identity of a study row: the job id of ``spec`` (``meshadv.experiments.spec.job_id``) and the margin."""
    from meshadv.experiments.spec import job_id

    return f"{job_id(spec)}@m{margin:g}"


def read_rows(path: Path) -> List[Dict[str, Any]]:
    """The rows of a results file (missing file: none); a truncated last line (killed mid-write) is ignored."""
    if not path.is_file():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return rows


def append_row(path: Path, row: Dict[str, Any]) -> None:
    """Append one JSON line to ``path`` (parents created) and flush it to disk."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as fh:
        fh.write(json.dumps(row, sort_keys=True) + "\n")
        fh.flush()


_VICTIMS: Dict[str, Any] = {}


def _load_victim(name: str) -> Any:
    """The victim as the sweep's jobs and ``meshadv transfer controlled`` load it (``load_victim``'s defaults),
    loaded once."""
    if name not in _VICTIMS:
        from meshadv.victims import load_victim

        _VICTIMS[name] = load_victim(name)
    return _VICTIMS[name]


def mitsuba_verdicts(spec: Dict[str, Any], job: str, out_dir: Path) -> Dict[str, Any]:
    """Mitsuba transfer of the attack whose artefacts are in ``out_dir`` (same camera and lights; views of a
    multi-view job are the attack views): per-view untargeted / targeted verdicts on both renderers and top-1
    labels, as ``meshadv transfer controlled`` records them."""
    from meshadv.transfer.controlled import _case_from_job
    from meshadv.transfer.controlled import controlled_transfer

    case = _case_from_job(SimpleNamespace(job_id=job, spec=spec, record={}), out_dir)
    if case is None:
        return {"mitsuba_error": "no adversarial mesh or views in the job folder"}
    rows = controlled_transfer([case], victim_loader=_load_victim)
    return {
        "mitsuba_error": next((r.error for r in rows if getattr(r, "error", None)), None),
        "untargeted_mitsuba": [bool(r.untargeted_mitsuba) for r in rows],
        "targeted_mitsuba": [bool(r.success_mitsuba) for r in rows],
        "untargeted_meshadv": [bool(r.untargeted_meshadv) for r in rows],
        "targeted_meshadv": [bool(r.success_meshadv) for r in rows],
        "top1_mitsuba": [r.top1_mitsuba for r in rows],
        "top1_meshadv": [r.top1_meshadv for r in rows],
    }


def benign_rows(specs: Sequence[Dict[str, Any]]) -> List[Dict[str, Any]]:
    """The control: each instance's *benign* mesh rendered by meshadv and by Mitsuba under the attack's views, and
    whether the victim already misclassifies it (``untargeted_*`` true = not the source class). An attack "transfers
    untargeted" for free where Mitsuba's benign render is already misclassified. One row per instance (mesh and
    views), ``margin`` null, ``kind`` ``"benign"``."""
    from meshadv.experiments.jobs import load_job_mesh
    from meshadv.transfer.controlled import TransferCase
    from meshadv.transfer.controlled import controlled_transfer

    seen, rows = set(), []
    for spec in specs:
        key = json.dumps([spec["mesh"], spec["views"]], sort_keys=True)
        if key in seen:
            continue
        seen.add(key)
        antialias = int(spec.get("attack", {}).get("antialias", 1))
        case = TransferCase(case_id=f"benign:{spec['mesh']['path']}", mesh=load_job_mesh(spec["mesh"]),
                            views=tuple(spec["views"]), victim=spec["victim"], true_class=spec["source_class"],
                            perturbation="benign", image_size=int(spec.get("image_size", 224)), antialias=antialias)
        res = controlled_transfer([case], victim_loader=_load_victim)
        rows.append({
            "key": f"benign:{spec['mesh']['path']}:{spec.get('kind', 'single')}:{len(spec['views'])}",
            "kind": "benign", "margin": None, "part": "multiview" if spec.get("kind") == "multiview" else "main",
            "source_class": spec["source_class"], "mesh": spec["mesh"]["path"],
            "config_index": spec.get("config_index"),
            "num_views": len(spec["views"]),
            "untargeted_meshadv": [bool(r.untargeted_meshadv) for r in res],
            "untargeted_mitsuba": [bool(r.untargeted_mitsuba) for r in res],
            "top1_meshadv": [r.top1_meshadv for r in res], "top1_mitsuba": [r.top1_mitsuba for r in res],
            "mitsuba_error": next((r.error for r in res if getattr(r, "error", None)), None),
        })
    return rows


def run_one(spec: Dict[str, Any], margin: float, work: Path, *, transfer: bool) -> Dict[str, Any]:
    """Run the attack job ``spec`` with ``required_margin = margin`` and (when it succeeds and ``transfer``) its
    Mitsuba transfer; returns the study row."""
    from meshadv.experiments.jobs import run_attack_job
    from meshadv.experiments.spec import job_id

    job_spec = json.loads(json.dumps(spec))
    if margin > 0:
        job_spec["attack"]["required_margin"] = float(margin)
    job = job_id(spec)
    out = work / f"{job}_m{margin:g}"
    out.mkdir(parents=True, exist_ok=True)
    record = run_attack_job(job_spec, out)
    row: Dict[str, Any] = {
        "key": row_key(spec, margin), "job_id": job, "margin": float(margin), "source": "run",
        "part": "multiview" if spec.get("kind") == "multiview" else "main",
        "perturbation": spec["perturbation"], "source_class": spec["source_class"], "target": spec["target"],
        "config_index": spec.get("config_index"), "num_views": len(spec["views"]),
        "eval_views": len(spec.get("eval_views") or []),
        **{k: record.get(k) for k in ("success", "skipped", "distance", "distances", "steps", "steps_to_success",
                                      "cpu_time", "adversarial_top1", "target_score", "eval_success_rate",
                                      "benign_top1", "attack_config")},
        "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    if transfer and record.get("success"):
        t0 = time.process_time()
        row.update(mitsuba_verdicts(spec, job, out))
        row["mitsuba_cpu_time"] = time.process_time() - t0
    return row


def reference_rows(db: Path, specs: Iterable[Dict[str, Any]]) -> List[Dict[str, Any]]:
    """``m = 0`` rows from a paper_medium database: the job records of ``specs`` and their Table 3 Mitsuba verdicts
    (the ``transfer`` table, experiment ``controlled``); jobs the database has not run are left out."""
    import sqlite3

    from meshadv.experiments import ResultStore
    from meshadv.experiments.spec import job_id

    with ResultStore(db, read_only=True) as store:
        done = {r.job_id: r for r in store.rows("done")}
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    rows = []
    for spec in specs:
        job = job_id(spec)
        if job not in done:
            continue
        record = done[job].record or {}
        row: Dict[str, Any] = {
            "key": row_key(spec, 0.0), "job_id": job, "margin": 0.0, "source": f"reference:{db.name}",
            "part": "main", "perturbation": spec["perturbation"], "source_class": spec["source_class"],
            "target": spec["target"], "config_index": spec.get("config_index"), "num_views": len(spec["views"]),
            "eval_views": 0,
            **{k: record.get(k) for k in ("success", "skipped", "distance", "distances", "steps", "steps_to_success",
                                          "cpu_time", "adversarial_top1", "target_score", "eval_success_rate",
                                          "benign_top1", "attack_config")},
        }
        views = sorted(con.execute("select view, record from transfer where experiment='controlled' and case_id=?",
                                   (job,)).fetchall())
        if views:
            recs = [json.loads(r) for _, r in views]
            row.update(untargeted_mitsuba=[bool(r["untargeted_mitsuba"]) for r in recs],
                       targeted_mitsuba=[bool(r["success_mitsuba"]) for r in recs],
                       untargeted_meshadv=[bool(r["untargeted_meshadv"]) for r in recs],
                       targeted_meshadv=[bool(r["success_meshadv"]) for r in recs],
                       top1_mitsuba=[r["top1_mitsuba"] for r in recs], top1_meshadv=[r["top1_meshadv"] for r in recs],
                       mitsuba_error=next((r.get("error") for r in recs if r.get("error")), None))
        rows.append(row)
    con.close()
    return rows


def attack_rows(rows: Sequence[Dict[str, Any]]) -> List[Dict[str, Any]]:
    """The attack rows of a results file (not the ``benign`` control rows)."""
    out = []
    for r in rows:
        if r.get("kind") == "benign" or r.get("margin") is None:
            continue
        out.append(r)
    return out


def benign_correct_meshes(rows: Sequence[Dict[str, Any]]) -> Optional[set]:
    """``(part, source_class)`` of the instances whose benign Mitsuba render is classified as the source class in
    every view (``benign`` rows), or None when the file has no ``benign`` rows."""
    benign = [r for r in rows if r.get("kind") == "benign"]
    if not benign:
        return None
    return {(r["part"], r["source_class"]) for r in benign if not any(r["untargeted_mitsuba"])}


def _fmt(x: Optional[float]) -> str:
    return "-" if x is None else f"{x:.2e}"


def _pct(a: int, b: int) -> str:
    return f"{a}/{b} ({100.0 * a / b:.0f}%)" if b else "-"


def summarize(rows: Sequence[Dict[str, Any]], *, paired_with: Optional[float] = 0.0) -> List[str]:
    """Markdown table lines per (part, perturbation, margin): attacks, success, distance (median / mean over
    successes), untargeted and targeted Mitsuba transfer over successes (a success counts as transferred when every
    view transfers; single-view jobs have one), unseen-view success (multi-view) and the median CPU seconds.

    ``paired_with``: a second table restricted to the (job, margin) pairs whose job also has a row at this margin,
    with the distance ratio to it (median over jobs both hold)."""
    groups: Dict[Tuple[str, str, float], List[Dict[str, Any]]] = {}
    for r in rows:
        if r.get("skipped"):
            continue
        groups.setdefault((r["part"], r["perturbation"], float(r["margin"])), []).append(r)
    by_job = {(r["job_id"], float(r["margin"])): r for r in rows if not r.get("skipped")}
    lines = ["| part | type | margin m | attacks | success | median distance | mean distance | untargeted Mitsuba "
             "transfer | targeted Mitsuba transfer | unseen-view success (mean) | distance / m=0 (median, paired) "
             "| median CPU s |", "|" + "---|" * 12]
    for (part, pert, m), rs in sorted(groups.items()):
        ok = [r for r in rs if r.get("success")]
        d = [float(r["distance"]) for r in ok if r.get("distance") is not None]
        tr = [r for r in ok if r.get("untargeted_mitsuba")]
        un = sum(all(r["untargeted_mitsuba"]) for r in tr)
        tg = sum(all(r["targeted_mitsuba"]) for r in tr)
        ev = [float(r["eval_success_rate"]) for r in rs if r.get("eval_success_rate") is not None]
        ratios = []
        if paired_with is not None:
            for r in ok:
                ref = by_job.get((r["job_id"], float(paired_with)))
                if ref and ref.get("success") and ref.get("distance") and r.get("distance") is not None:
                    ratios.append(float(r["distance"]) / float(ref["distance"]))
        cpu = [float(r["cpu_time"]) for r in rs if r.get("cpu_time") is not None]
        lines.append(
            f"| {part} | {pert} | {m:g} | {len(rs)} | {_pct(len(ok), len(rs))}"
            f" | {_fmt(statistics.median(d) if d else None)}"
            f" | {_fmt(statistics.fmean(d) if d else None)} | {_pct(un, len(tr))} | {_pct(tg, len(tr))}"
            f" | {f'{100 * statistics.fmean(ev):.0f}% ({len(ev)} attacks)' if ev else '-'}"
            f" | {f'{statistics.median(ratios):.2f}x ({len(ratios)})' if ratios else '-'}"
            f" | {f'{statistics.median(cpu):.0f}' if cpu else '-'} |")
    return lines


def transfer_pairs(rows: Sequence[Dict[str, Any]], base: float = 0.0) -> List[str]:
    """Per margin ``m != base`` (single-view shape/texture rows): over the jobs that succeed at both ``base`` and
    ``m`` and have Mitsuba verdicts, how many transfer (untargeted, every view) at both, at ``base`` only, at ``m``
    only, at neither: the discordant counts are what a margin changes."""
    by = {(r["part"], r["perturbation"], r["job_id"], float(r["margin"])): r for r in rows}
    out = []
    for part, pert, m in sorted({(r["part"], r["perturbation"], float(r["margin"])) for r in rows}):
        if m == base:
            continue
        counts = {"both": 0, "base only": 0, "m only": 0, "neither": 0}
        for (p2, t2, job, m2), r in by.items():
            ref = by.get((p2, t2, job, float(base)))
            if (p2, t2, m2) != (part, pert, m) or ref is None:
                continue
            if not (r.get("untargeted_mitsuba") and ref.get("untargeted_mitsuba")):
                continue
            a, b = all(ref["untargeted_mitsuba"]), all(r["untargeted_mitsuba"])
            counts["both" if a and b else "base only" if a else "m only" if b else "neither"] += 1
        out.append(f"{part} {pert} m={m:g} vs m={base:g} (jobs successful at both): "
                   + ", ".join(f"{k} {v}" for k, v in counts.items()))
    return out


def paired_rows(rows: Sequence[Dict[str, Any]], margins: Sequence[float]) -> List[Dict[str, Any]]:
    """The rows of the jobs that have a (non-skipped) row at every one of ``margins``: the paired sample."""
    have: Dict[str, set] = {}
    for r in rows:
        if not r.get("skipped"):
            have.setdefault(r["job_id"], set()).add(float(r["margin"]))
    keep = {j for j, ms in have.items() if all(float(m) in ms for m in margins)}
    return [r for r in rows if r["job_id"] in keep and float(r["margin"]) in {float(m) for m in margins}]


def plot(rows: Sequence[Dict[str, Any]], path: Path) -> None:
    """Untargeted Mitsuba transfer, success and median distance against the margin (main-setting shape rows of the
    paired sample), one PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shape = [r for r in rows if r["part"] == "main" and r["perturbation"] == "shape" and not r.get("skipped")]
    margins = sorted({float(r["margin"]) for r in shape})
    if not margins:
        raise ValueError("no main-setting shape rows to plot")
    paired = paired_rows(shape, margins)
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.6))
    succ, trans, med = [], [], []
    for m in margins:
        rs = [r for r in paired if float(r["margin"]) == m]
        ok = [r for r in rs if r.get("success")]
        tr = [r for r in ok if r.get("untargeted_mitsuba")]
        succ.append(100.0 * len(ok) / max(1, len(rs)))
        trans.append(100.0 * sum(all(r["untargeted_mitsuba"]) for r in tr) / max(1, len(tr)))
        med.append(statistics.median([float(r["distance"]) for r in ok]) if ok else float("nan"))
    n = len({r["job_id"] for r in paired})
    ax[0].plot(margins, trans, "o-", label="untargeted Mitsuba transfer (of successes)")
    ax[0].plot(margins, succ, "s--", label="attack success")
    ax[0].set_xlabel("required logit margin m")
    ax[0].set_ylabel("%")
    ax[0].set_ylim(0, 105)
    ax[0].legend(fontsize=7)
    ax[0].set_title(f"Lite0 shape, {n} paired targets", fontsize=9)
    ax[1].plot(margins, med, "o-")
    ax[1].set_yscale("log")
    ax[1].set_xlabel("required logit margin m")
    ax[1].set_ylabel("median laplacian_pair_mean (successes)")
    ax[1].axhline(1.8e-4, color="grey", ls=":", label="paper's mean (DenseNet)")
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def _margins(values: Sequence[float]) -> List[float]:
    out = []
    for v in values:
        if not v >= 0:
            raise argparse.ArgumentTypeError(f"--margins must be >= 0, got {v}")
        out.append(float(v))
    return out


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Command line: ``run``, ``import-reference``, ``summary`` (see ``--help``)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--config", type=Path, default=DEFAULT_CONFIG, help="sweep config (paper_medium)")
    common.add_argument("--out", type=Path, default=DEFAULT_OUT, help="results JSONL (appended, resumable)")
    common.add_argument("--perturbations", nargs="+", default=["shape"], choices=["shape", "texture"])
    common.add_argument("--classes", nargs="+", default=None, help="source classes (default: all of the config)")
    common.add_argument("--config-index", type=int, default=0, help="rendering configuration of the main setting")
    common.add_argument("--part", default="main", choices=["main", "multiview"],
                        help="main setting (single view) or Table 2's multi-view jobs")
    common.add_argument("--views", type=int, nargs="*", default=None,
                     help="multi-view: keep only jobs with these attack-view counts (e.g. 5)")
    common.add_argument("--ranges", nargs="*", default=None,
                     help="multi-view: keep only these azimuth ranges, as LO-HI (e.g. 45-60)")
    run = sub.add_parser("run", parents=[common], help="run the attacks (and their Mitsuba transfer)")
    run.add_argument("--margins", nargs="+", type=float, default=[1.0, 4.0],
                     help="required logit margins; per target, every margin in this order")
    run.add_argument("--limit", type=int, default=None, help="at most this many new attacks")
    run.add_argument("--work", type=Path, default=None, help="artefact folder (default: a temporary one)")
    run.add_argument("--no-transfer", action="store_true", help="skip the Mitsuba pass")
    run.add_argument("--threads", type=int, default=1, help="torch threads")
    run.add_argument("--deadline", default=None, help="start no attack after this UTC time, HH:MM")
    sub.add_parser("benign", parents=[common], help="control: Mitsuba verdicts of the benign meshes")
    sub.add_parser("import-reference", parents=[common], help="m = 0 rows from paper_medium's database").add_argument(
        "--db", type=Path, default=DEFAULT_REFERENCE, help="reference sweep database")
    summ = sub.add_parser("summary", parents=[common], help="markdown tables of the results file")
    summ.add_argument("--paired", nargs="*", type=float, default=None,
                      help="also a table over the jobs that have rows at every one of these margins")
    summ.add_argument("--plot", type=Path, default=None, help="write the PNG here")
    args = ap.parse_args(argv)

    if args.command == "summary":
        everything = read_rows(args.out)
        rows = attack_rows(everything)
        if not rows:
            raise SystemExit(f"--out {args.out} holds no attack rows")
        print("\n".join(summarize(rows)))
        print("\nuntargeted Mitsuba transfer, paired:")
        print("\n".join(transfer_pairs(rows)))
        correct = benign_correct_meshes(everything)
        if correct is not None:
            kept = [r for r in rows if (r["part"], r["source_class"]) in correct]
            print(f"\ninstances whose benign Mitsuba render is the source class in every view ({len(correct)}):")
            print("\n".join(summarize(kept)))
        if args.paired:
            print(f"\npaired over margins {args.paired}:")
            print("\n".join(summarize(paired_rows(rows, args.paired))))
        if args.plot is not None:
            plot(rows, args.plot)
        return 0

    specs = study_jobs(args.config, perturbations=args.perturbations, classes=args.classes,
                       config_index=args.config_index, part=args.part)
    done = {r["key"] for r in read_rows(args.out)}
    if args.views:
        specs = [s for s in specs if len(s["views"]) in set(args.views)]
    if args.ranges:
        wanted = {tuple(float(x) for x in r.split("-")) for r in args.ranges}
        specs = [s for s in specs if tuple(float(x) for x in s.get("azimuth_range", ())) in wanted]
    if args.command == "benign":
        new = [r for r in benign_rows(specs) if r["key"] not in done]
        for r in new:
            append_row(args.out, r)
            print(f"{r['source_class']} {r['mesh']}: meshadv {r['top1_meshadv']} mitsuba {r['top1_mitsuba']}")
        return 0
    if args.command == "import-reference":
        new = [r for r in reference_rows(args.db, specs) if r["key"] not in done]
        for r in new:
            append_row(args.out, r)
        print(f"imported {len(new)} m=0 rows from {args.db}")
        return 0

    import torch

    torch.set_num_threads(max(1, args.threads))
    margins = _margins(args.margins)
    work = args.work or Path(tempfile.mkdtemp(prefix="margin_study_"))
    count = 0
    for spec in specs:
        for m in margins:
            if row_key(spec, m) in done:
                continue
            if args.limit is not None and count >= args.limit:
                return 0
            if args.deadline and time.strftime("%H:%M", time.gmtime()) >= args.deadline:
                print(f"deadline {args.deadline} UTC reached", flush=True)
                return 0
            row = run_one(spec, m, work, transfer=not args.no_transfer)
            append_row(args.out, row)
            count += 1
            print(f"{row['finished_utc']} {row['perturbation']} {row['source_class']}->{row['target']} m={m:g} "
                  f"success={row['success']} distance={row.get('distance')} "
                  f"mitsuba_untargeted={row.get('untargeted_mitsuba')} targeted={row.get('targeted_mitsuba')} "
                  f"unseen={row.get('eval_success_rate')} cpu={row.get('cpu_time', 0):.0f}s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
