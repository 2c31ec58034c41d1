"""A report re-run keeps the grids and flow figures already drawn from the same jobs and outcomes (their PNGs record
a stamp), so a machine without the jobs' artefacts does not regenerate them; anything else is drawn again."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import pytest
from PIL import Image

from meshadv.experiments import ResultStore
from meshadv.experiments.report import write_report
from meshadv.experiments.report_figures import CELL_CACHE_PX, CORRELATIONS_KEY, STAMP_KEY
from meshadv.util.png import png_text
from sweep_fixtures import probe_jobs, run_probe_sweep


@pytest.fixture()
def complete_db(tmp_path: Path) -> Path:
    """Synthetic attacks (mesh_probe_job) of boat, chair and sofa towards each other, every artefact on disk."""
    return run_probe_sweep(tmp_path / "r.db", probe_jobs(["boat", "chair", "sofa"]), tmp_path / "run")


def _figures(rep: object) -> dict:
    return {p.name: p.read_bytes() for p in rep.figures}


def test_figures_are_stamped_and_kept_without_the_artefacts(complete_db: Path, tmp_path: Path) -> None:
    first = write_report(complete_db, tmp_path / "rep")
    names = sorted(p.name for p in first.figures)
    assert names == ["curvature_v.png", "flow_heatmap_v.png", "flow_quiver_v.png", "grid_v_shape.png"]
    assert all(png_text(p).get(STAMP_KEY) for p in first.figures)
    assert "pearson" in png_text(tmp_path / "rep" / "figures" / "curvature_v.png")[CORRELATIONS_KEY]
    drawn = _figures(first)
    shutil.rmtree(tmp_path / "run")  # another machine: the database alone
    again = write_report(complete_db, tmp_path / "rep")
    assert _figures(again) == drawn  # kept as they were, not drawn again (nothing to draw them from)
    assert again.correlations == first.correlations and again.regenerations == {}
    readme = (tmp_path / "rep" / "README.md").read_text()
    assert "grid_v_shape.png" in readme and "Pearson r" in readme


def test_a_changed_outcome_redraws_the_grid(complete_db: Path, tmp_path: Path) -> None:
    write_report(complete_db, tmp_path / "rep")
    grid = tmp_path / "rep" / "figures" / "grid_v_shape.png"
    stamp = png_text(grid)[STAMP_KEY]
    with ResultStore(complete_db, read_only=True) as store:
        row = next(r for r in store.rows() if (r.spec["source_class"], r.spec["target"]) == ("boat", "chair"))
    conn = sqlite3.connect(complete_db)  # the attack's record says it failed after all
    with conn:
        conn.execute("UPDATE jobs SET success = 0, record = json_set(record, '$.success', json('false')) "
                     "WHERE job_id = ?", (row.job_id,))
    conn.close()
    cells = sorted(p.name for p in (tmp_path / "rep" / "figures" / "cells").iterdir())
    assert len(cells) == 9  # 3 benign renders + 6 attacks, kept small beside the figures
    shutil.rmtree(tmp_path / "run")  # and the artefacts are gone: the grid is drawn from the kept cells
    again = write_report(complete_db, tmp_path / "rep")
    assert grid in again.figures and png_text(grid).get(STAMP_KEY) not in (None, stamp)  # complete, failure marked
    with Image.open(grid) as img, Image.open(tmp_path / "rep" / "figures" / "cells" / cells[0]) as cell:
        assert img.size[0] > 3 * cell.size[0] and max(cell.size) <= CELL_CACHE_PX


def test_redraw_draws_what_it_can_from_the_kept_cells(complete_db: Path, tmp_path: Path) -> None:
    write_report(complete_db, tmp_path / "rep")
    shutil.rmtree(tmp_path / "run")
    redrawn = write_report(complete_db, tmp_path / "rep", redraw=True)
    assert [p.name for p in redrawn.figures] == ["grid_v_shape.png"]  # the flow figures need the meshes
    shutil.rmtree(tmp_path / "rep" / "figures" / "cells")
    assert write_report(complete_db, tmp_path / "rep", redraw=True).figures == []  # nothing left to draw from


def test_a_grid_with_a_cell_missing_is_not_kept(complete_db: Path, tmp_path: Path) -> None:
    with ResultStore(complete_db, read_only=True) as store:
        row = next(r for r in store.rows() if (r.spec["source_class"], r.spec["target"]) == ("chair", "sofa"))
    (Path(row.out_dir) / "after_v0.png").unlink()
    rep = write_report(complete_db, tmp_path / "rep")
    grid = tmp_path / "rep" / "figures" / "grid_v_shape.png"
    assert grid in rep.figures and STAMP_KEY not in png_text(grid)  # drawn with "no result" in one cell
    assert STAMP_KEY in png_text(tmp_path / "rep" / "figures" / "flow_quiver_v.png")
