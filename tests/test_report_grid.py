"""The report's classes x classes grid: titles fit inside the figure, empty cells say why, failures are labelled."""

from __future__ import annotations

from pathlib import Path
from typing import List

import pytest
from matplotlib.figure import Figure

from meshadv.experiments import ResultStore
from meshadv.experiments.figures import grid_figure, render_grid
from meshadv.experiments.report import write_report
from meshadv.experiments.report_figures import grid_cells
from sweep_fixtures import probe_jobs, run_probe_sweep


@pytest.fixture()
def small_db(tmp_path: Path) -> Path:
    """A database of synthetic attacks (mesh_probe_job): no diningtable source (its diagonal has no benign render),
    the boat -> chair attack failed, and the chair -> boat render was deleted."""
    jobs = [{**j, "success": (j["source_class"], j["target"]) != ("boat", "chair")}
            for j in probe_jobs(["boat", "chair", "diningtable"]) if j["source_class"] != "diningtable"]
    db = run_probe_sweep(tmp_path / "r.db", jobs, tmp_path / "run")
    with ResultStore(db, read_only=True) as store:
        for row in store.rows():
            if (row.spec["source_class"], row.spec["target"]) == ("chair", "boat"):
                (Path(row.out_dir) / "after_v0.png").unlink()
    return db


def _texts(fig: Figure) -> List:
    """Every visible, non-empty text artist of the figure (suptitle, titles, axis labels, cell notes)."""
    return [t for t in fig.findobj(lambda a: hasattr(a, "get_text") and hasattr(a, "get_window_extent"))
            if t.get_visible() and t.get_text().strip()]


def test_grid_marks_missing_and_failed_cells_and_keeps_titles_inside(small_db: Path) -> None:
    with ResultStore(small_db, read_only=True) as store:
        rows = store.rows()
    cells, classes, failed = grid_cells(rows)
    assert classes == ["boat", "chair", "diningtable"]
    assert failed == {("boat", "chair")}
    long_title = "shape attacks on efficientnet_lite0 (rows: benign class, columns: target; diagonal: benign; " \
                 "red: attack failed)"
    fig = grid_figure(cells, classes, title=long_title, failed=failed)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    box = fig.bbox
    texts = _texts(fig)
    for text in texts:  # no title, label or note is clipped by the figure's edge
        ext = text.get_window_extent(renderer)
        assert box.x0 - 0.5 <= ext.x0 and ext.x1 <= box.x1 + 0.5, text.get_text()
        assert box.y0 - 0.5 <= ext.y0 and ext.y1 <= box.y1 + 0.5, text.get_text()
    words = " ".join(t.get_text() for t in texts).split()
    assert " ".join(long_title.split()) in " ".join(words)  # wrapped, not cut
    axes = {(i, j): fig.axes[i * 3 + j] for i in range(3) for j in range(3)}

    def notes(i: int, j: int) -> List[str]:
        return [t.get_text() for t in axes[(i, j)].texts]

    assert notes(2, 2) == ["source = target\n(no benign render)"]  # no benign render of diningtable
    assert notes(1, 0) == ["no result"]  # chair -> boat: render missing
    assert notes(2, 0) == ["no result"]  # diningtable was never attacked
    assert notes(0, 1) == [] and axes[(0, 1)].get_xlabel() == "failed" and axes[(0, 1)].images
    assert axes[(0, 0)].get_xlabel() == "benign" and axes[(0, 0)].images
    assert axes[(0, 2)].get_xlabel() == "" and axes[(0, 2)].images  # a successful attack: its render, no label
    # an empty cell has no coloured frame: only a drawn image on the diagonal gets the green one
    for (i, j), ax in axes.items():
        coloured = any(s.get_visible() and len(set(s.get_edgecolor()[:3])) > 1 for s in ax.spines.values())
        assert coloured == (i == j and bool(ax.images)), (i, j)
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_report_writes_the_grid_and_render_grid_checks_classes(small_db: Path, tmp_path: Path) -> None:
    rep = write_report(small_db, tmp_path / "rep")
    assert (tmp_path / "rep" / "figures" / "grid_v_shape.png") in rep.figures
    with pytest.raises(ValueError, match="classes"):
        render_grid({}, [], tmp_path / "x.png")
