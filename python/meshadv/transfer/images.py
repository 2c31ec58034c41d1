"""Saved Mitsuba renders of the controlled transfer: 8-bit PNGs named after their case (:func:`save_images`), and
the folder's ``index.csv`` listing every file with its full job id and outcome (:func:`write_image_index`)."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any, Sequence, Union

from meshadv.transfer.cases import TransferCase
from meshadv.transfer.render import MitsubaImage
from meshadv.transfer.results import ControlledResult

__all__ = ["INDEX_COLUMNS", "save_images", "write_image_index"]


#: Columns of the renders' ``index.csv``.
INDEX_COLUMNS = ("file", "job_id", "victim", "true_class", "target", "perturbation", "view", "success_meshadv",
                 "success_mitsuba", "top1_meshadv", "top1_mitsuba")


def write_image_index(image_dir: Union[str, Path], cases: Sequence[TransferCase],
                      rows: Sequence[ControlledResult]) -> Path:
    """Add the renders of ``cases`` to ``<image_dir>/index.csv`` (file name -> job id, classes, view, outcome), keeping
    the entries of earlier runs; written atomically.

    Args:
        image_dir: the folder the renders were saved in.
        cases: the transferred cases (their ``name`` and ``case_id``).
        rows: their results (one per case and view).

    Returns:
        The index path.
    """
    from meshadv.util.atomic import write_text_atomic

    path = Path(image_dir) / "index.csv"
    entries = _read_index(path)
    stems = {case.case_id: case.name or case.case_id for case in cases}
    for row in rows:
        if row.case_id not in stems or row.error is not None:
            continue
        entry = _index_entry(stems[row.case_id], row)
        entries[entry["file"]] = entry
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=INDEX_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for file in sorted(entries):
        writer.writerow({k: entries[file].get(k, "") for k in INDEX_COLUMNS})
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, out.getvalue())
    return path


def _read_index(path: Path) -> dict[str, dict[str, Any]]:
    """The entries of an existing ``index.csv`` by file name (none when there is no such file)."""
    if not path.is_file():
        return {}
    with open(path, newline="", encoding="utf-8") as fh:
        return {row["file"]: row for row in csv.DictReader(fh)}


def _index_entry(stem: str, row: ControlledResult) -> dict[str, Any]:
    """The ``index.csv`` entry of the render of ``row``'s view, saved as ``<stem>_v<view>.png``."""
    file = f"{stem}_v{row.view}.png"
    return {"file": file, "job_id": row.case_id, "victim": row.victim, "true_class": row.true_class,
            "target": row.target, "perturbation": row.perturbation, "view": row.view,
            "success_meshadv": row.success_meshadv, "success_mitsuba": row.success_mitsuba,
            "top1_meshadv": row.top1_meshadv, "top1_mitsuba": row.top1_mitsuba}


def save_images(images: Sequence[MitsubaImage], out_dir: Union[str, Path], stem: str) -> list[Path]:
    """Save Mitsuba renders as 8-bit PNGs ``<stem>_v<i>.png`` in ``out_dir`` (created if missing; linear values, as
    meshadv's images) and return their paths."""
    from meshadv.util.png import save_png

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, im in enumerate(images):
        path = out_dir / f"{stem}_v{i}.png"
        save_png(im.image, path)
        paths.append(path)
    return paths
