"""benchmarks/torn_parts.py: the measures it reads from a sweep's kept meshes and its table (no attack run)."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest
import torch
import trimesh

from benchmark_scripts import load_benchmark


def _slab() -> "tuple[torch.Tensor, torch.Tensor]":
    """A wing-like slab: two 11 x 5 sheets 1 x 0.25, 0.01 apart, joined by a wall along the edge y = 0.25."""
    x, y = torch.meshgrid(torch.linspace(0, 1, 11), torch.linspace(0, 0.25, 5), indexing="ij")
    top = torch.stack([x.flatten(), y.flatten(), torch.full((55,), 0.005)], dim=1).double()
    index = torch.arange(55).reshape(11, 5)
    a, b, c, d = (index[:-1, :-1].flatten(), index[1:, :-1].flatten(), index[1:, 1:].flatten(),
                  index[:-1, 1:].flatten())
    sheet = torch.cat([torch.stack([a, b, c], dim=1), torch.stack([a, c, d], dim=1)])
    edge = index[:, -1]
    wall = torch.cat([torch.stack([edge[:-1], edge[1:], edge[1:] + 55], dim=1),
                      torch.stack([edge[:-1], edge[1:] + 55, edge[:-1] + 55], dim=1)])
    vertices = torch.cat([top, top - torch.tensor([0.0, 0.0, 0.01], dtype=torch.float64)])
    return vertices, torch.cat([sheet, sheet.flip(1) + 55, wall])


def _sweep(tmp_path: Path, opened: float) -> Path:
    """A sweep database with one attacked shape job whose kept mesh opens the slab's wall by ``opened``."""
    vertices, faces = _slab()
    job = tmp_path / "jobs" / "ab" / "abc"
    job.mkdir(parents=True)
    trimesh.Trimesh(vertices.numpy(), faces.numpy(), process=False).export(job / "benign.ply")
    moved = vertices.clone()
    moved[:55, 2] += opened * (vertices[:55, 1] / 0.25)  # the top sheet lifted towards its closed edge
    trimesh.Trimesh(moved.numpy(), faces.numpy(), process=False).export(job / "adversarial.ply")
    db = tmp_path / "results.db"
    conn = sqlite3.connect(db)
    conn.execute("CREATE TABLE jobs (spec TEXT, state TEXT, record TEXT, out_dir TEXT)")
    spec = {"kind": "multiview", "perturbation": "shape", "mesh": {"path": "slab.ply"}, "source_class": "aeroplane",
            "target": "boat", "num_views": 5, "azimuth_range": [45.0, 60.0]}
    record = {"skipped": False, "success": False, "distances": {"ssim_held_out_mean": 0.7}}
    conn.execute("INSERT INTO jobs VALUES (?, 'done', ?, 'jobs/ab/abc')", (json.dumps(spec), json.dumps(record)))
    skipped = {**spec, "target": "bottle"}
    conn.execute("INSERT INTO jobs VALUES (?, 'done', ?, 'jobs/ab/none')",
                 (json.dumps(skipped), json.dumps({"skipped": True})))
    conn.commit()
    conn.close()
    return db


def test_torn_parts_reads_the_kept_meshes_and_measures_the_opened_wall(tmp_path: Path) -> None:
    bench = load_benchmark("torn_parts")
    db = _sweep(tmp_path, opened=0.03)
    rows = bench.collect(db, tmp_path)
    assert len(rows) == 1 and rows[0]["cell"] == "5 views, 45-60" and rows[0]["target"] == "boat"
    # the wall's edges: 0.01 long (above the floor, 0.25% of a diagonal of 1.03), grown by 0.03: strain 3
    assert rows[0]["strain_max"] == pytest.approx(3.0, rel=1e-3)
    assert rows[0]["strain_p95"] < 0.1 and rows[0]["max_move_pct"] == pytest.approx(100 * 0.03 / 1.0310, rel=1e-3)
    table = bench.report(rows)
    assert "| slab.ply | boat | 5 views, 45-60 | no |" in table and "| aeroplane | 1 | 3.00 | 3.00 | 3.00 |" in table


def test_torn_parts_refuses_a_database_without_kept_meshes(tmp_path: Path) -> None:
    bench = load_benchmark("torn_parts")
    db = _sweep(tmp_path, opened=0.03)
    with pytest.raises(SystemExit, match="no attacked shape job"):
        bench.main([str(db), "--output", str(tmp_path / "elsewhere")])
