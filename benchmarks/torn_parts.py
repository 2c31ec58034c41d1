"""Torn thin parts: the largest edge strain of a sweep's kept shape results, beside the percentile measures.

For every attacked shape job of a sweep database whose artefacts (``benign.ply``, ``adversarial.ply``) are in the
output folder, prints one Markdown row: the mesh, the target, the multi-view cell, the kept result's largest vertex
move (% of the diagonal), the normals' area-weighted 95th percentile (degrees), the share of the area turned past
90 degrees (%), the edge strain's length-weighted 95th percentile and its largest value over the edges
(:func:`meshadv.perceptibility.geometry.edge_strains`), and the held-out SSIM mean of the record. The largest strain
is what a thin part torn open shows: the short edges across a wing's thickness stretched many times over, a sliver
of the edge length and of the area, so the percentiles do not see it. Then a summary per class.

Usage:
    python benchmarks/torn_parts.py out/paper_medium_robust/results.db            # artefacts beside the database
    python benchmarks/torn_parts.py DB --output DIR --json torn.json
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import statistics
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence

import torch
import trimesh

from meshadv.perceptibility.geometry import face_normal_turns, surface_measures


def _load(path: Path) -> "tuple[torch.Tensor, torch.Tensor]":
    mesh = trimesh.load(path, process=False, force="mesh")
    return torch.tensor(mesh.vertices, dtype=torch.float64), torch.tensor(mesh.faces, dtype=torch.long)


def measure(job_dir: Path) -> Optional[Dict[str, float]]:
    """The measures of one job folder's kept result, or ``None`` without both meshes."""
    if not (job_dir / "benign.ply").is_file() or not (job_dir / "adversarial.ply").is_file():
        return None
    benign, faces = _load(job_dir / "benign.ply")
    adversarial, faces_adv = _load(job_dir / "adversarial.ply")
    if adversarial.shape != benign.shape or not torch.equal(faces, faces_adv):
        raise ValueError(f"{job_dir}: benign.ply and adversarial.ply are not the same mesh's vertices")
    colors = torch.zeros(faces.shape[0], 3)
    measures = surface_measures(adversarial, colors, benign, colors, faces)
    angles, areas = face_normal_turns(adversarial, benign, faces)
    return {
        "max_move_pct": 100 * measures["max_displacement"],
        "normals_p95_deg": measures["normal_change_p95_deg"],
        "turned_90_pct": 100 * float(areas[angles[0] > 90.0].sum() / areas.sum()),
        "strain_p95": measures["edge_strain_p95"],
        "strain_max": measures["edge_strain_max"],
    }


def collect(db: Path, output: Path) -> List[Dict[str, Any]]:
    """One row per attacked shape job with artefacts, in the database's order."""
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    rows = []
    for spec_text, record_text, out_dir in conn.execute(
            "SELECT spec, record, out_dir FROM jobs WHERE state = 'done' ORDER BY rowid"):
        spec, record = json.loads(spec_text), json.loads(record_text or "{}")
        if record.get("skipped") or spec.get("perturbation") != "shape" or not out_dir:
            continue
        measures = measure(output / out_dir)
        if measures is None:
            continue
        cell = (f"{spec['num_views']} views, {spec['azimuth_range'][0]:g}-{spec['azimuth_range'][1]:g}"
                if spec.get("kind") == "multiview" else "single view")
        rows.append({"mesh": spec["mesh"]["path"], "class": spec["source_class"], "target": spec["target"],
                     "cell": cell, "success": bool(record.get("success")),
                     "ssim_held_out_mean": (record.get("distances") or {}).get("ssim_held_out_mean"), **measures})
    conn.close()
    return rows


def report(rows: Sequence[Dict[str, Any]]) -> str:
    """The rows and a per-class summary as Markdown."""
    lines = ["| mesh | target | cell | success | move max % | normals p95 | turned > 90 deg % | strain p95 | "
             "strain max | SSIM held-out mean |", "|---|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        ssim = "-" if r["ssim_held_out_mean"] is None else f"{r['ssim_held_out_mean']:.2f}"
        lines.append(f"| {r['mesh']} | {r['target']} | {r['cell']} | {'yes' if r['success'] else 'no'} | "
                     f"{r['max_move_pct']:.2f} | {r['normals_p95_deg']:.1f} | {r['turned_90_pct']:.3f} | "
                     f"{r['strain_p95']:.3f} | {r['strain_max']:.2f} | {ssim} |")
    lines += ["", "| class | kept results | strain max: median | min | max |", "|---|---:|---:|---:|---:|"]
    for cls in sorted({r["class"] for r in rows}):
        values = [r["strain_max"] for r in rows if r["class"] == cls]
        lines.append(f"| {cls} | {len(values)} | {statistics.median(values):.2f} | {min(values):.2f} | "
                     f"{max(values):.2f} |")
    return "\n".join(lines)


def main(argv: Optional[Sequence[str]] = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("db", help="results database of a sweep")
    parser.add_argument("--output", default=None, help="the sweep's output folder (default: the database's folder)")
    parser.add_argument("--json", default=None, help="also write the rows to this JSON file")
    args = parser.parse_args(argv)
    db = Path(args.db)
    rows = collect(db, Path(args.output) if args.output else db.parent)
    if not rows:
        raise SystemExit(f"{db}: no attacked shape job with benign.ply and adversarial.ply under its output folder")
    print(report(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
