"""``meshadv report``: the tables (Markdown + CSV), the figures (PNG) and the run's settings from a results database.

Output folder layout::

    README.md                  summary: counts, Table 1, Table 2, figure list, correlations, definitions
    table1.md / table1.csv     best / average / worst case per victim and perturbation type
    table1_benign_correct.*    the same over instances whose benign render was classified correctly (written when
                               the sweep also attacked misclassified ones, benign_correct_only = false)
    table2.md / table2.csv     multi-view robustness (when the sweep had multi-view jobs)
    paper_comparison.md        Tables 1-3 beside the paper's numbers (meshadv.experiments.paper), shortfalls
    figures/grid_<victim>_<type>.png        classes x classes renders (diagonal benign, failed attacks labelled)
    figures/flow_heatmap_<victim>.png       flow magnitude, rendered and canonical views
    figures/flow_quiver_<victim>.png        flow directions around the most displaced vertex
    figures/curvature_<victim>.png          flow magnitude vs. mean curvature (+ correlation in README)
    proxies.csv                SSIM / PSNR of benign vs. adversarial render per attack (meshadv.study.proxies)
    settings.json              the sweep config, database meta (versions at sweep time) and versions now
"""

from __future__ import annotations

import json
import platform
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Sequence, Set, Tuple, Union

import numpy as np

from meshadv.experiments.compare import paper_comparison
from meshadv.experiments.store import JobRow, ResultStore
from meshadv.experiments.tables import (
    DISTANCE_NAMES,
    attack_rows,
    table1,
    table2,
    to_csv,
    to_markdown,
    victim_label,
)

__all__ = ["write_report", "ReportOutput", "environment_versions"]

CASE_DEFINITIONS = """\
Cases (Carlini & Wagner 2017, as used by MeshAdv): an instance is one benign render (mesh, rendering configuration,
seed) attacked towards every other class. Best case: the instance succeeds when any target succeeds; distance = the
smallest distance among its successful targets. Worst case: the instance succeeds only when every target succeeds;
distance = the largest distance among them. Average case: a random target, i.e. the mean over instances of the
fraction of successful targets; distance = the mean over all successful attacks. Mean distances are over successful
instances / attacks. Distances: shape, the Laplacian loss of the vertex flow (Eq. 4) in two conventions,
laplacian_pair_mean (divided by the 2E vertex-neighbour pairs: the scale of the paper's Table 1, the one to compare)
and laplacian_sum (the literal sum); texture, the face-colour RMSE over faces (the paper's measure). The paper
attacks only instances whose benign render the victim classifies correctly (sweep option benign_correct_only =
true); when a sweep attacked every instance, the table restricted to those is given too."""


def environment_versions() -> Dict[str, str]:
    """Versions of Python, the platform and the main packages (those importable)."""
    out = {"python": sys.version.split()[0], "platform": platform.platform()}
    for name in ("meshadv", "torch", "numpy", "matplotlib", "ray"):
        try:
            module = __import__(name)
            out[name] = str(getattr(module, "__version__", "?"))
        except Exception:  # noqa: BLE001 - a missing optional package is simply not listed
            continue
    return out


@dataclass
class ReportOutput:
    """What :func:`write_report` wrote.

    Attributes:
        out_dir: the report folder. tables: written table files. figures: written figure files.
        correlations: per victim, the flow-magnitude / mean-curvature correlations.
        counts: job counts per state.
    """

    out_dir: Path
    tables: List[Path] = field(default_factory=list)
    figures: List[Path] = field(default_factory=list)
    correlations: Dict[str, Dict[str, float]] = field(default_factory=dict)
    counts: Dict[str, int] = field(default_factory=dict)


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in text)


def _art(row: JobRow, key: str, index: int = 0) -> Optional[Path]:
    arts = (row.record or {}).get("artifacts", {})
    value = arts.get(key)
    if isinstance(value, list):
        value = value[index] if index < len(value) else None
    if not value or row.out_dir is None:
        return None
    path = Path(row.out_dir) / value
    return path if path.exists() else None


def _instance(row: JobRow) -> Tuple[Any, ...]:
    mesh = row.spec["mesh"]
    return (mesh.get("path") or mesh.get("name"), row.spec.get("config_index"), row.spec.get("seed"),
            row.spec.get("protocol"))


def _grid_cells(rows: List[JobRow]) -> Tuple[Dict[Tuple[str, str], Path], List[str], Set[Tuple[str, str]]]:
    """Pick, per source class, the instance with the most successful targets; return its renders, the classes and
    the ``(source, target)`` cells whose attack failed."""
    by_instance: Dict[Tuple[Any, ...], List[JobRow]] = defaultdict(list)
    for row in rows:
        by_instance[_instance(row)].append(row)
    best: Dict[str, List[JobRow]] = {}
    for inst_rows in by_instance.values():
        src = inst_rows[0].spec["source_class"]
        score = sum(bool(r.record.get("success")) for r in inst_rows)
        if src not in best or score > sum(bool(r.record.get("success")) for r in best[src]):
            best[src] = inst_rows
    from meshadv.experiments.config import PASCAL3D_CLASSES

    classes = sorted({r.spec["source_class"] for r in rows} | {r.spec["target"] for r in rows},
                     key=lambda c: (PASCAL3D_CLASSES.index(c) if c in PASCAL3D_CLASSES else 99, c))
    cells: Dict[Tuple[str, str], Path] = {}
    failed: Set[Tuple[str, str]] = set()
    for src, inst_rows in best.items():
        for r in inst_rows:
            benign = _art(r, "benign_images")
            if benign is not None:
                cells.setdefault((src, src), benign)
            adv = _art(r, "adversarial_images")
            if adv is not None:
                cells[(src, r.spec["target"])] = adv
                if not r.record.get("success"):
                    failed.add((src, r.spec["target"]))
    return cells, classes, failed


def _load_pair(row: JobRow) -> Optional[Tuple[np.ndarray, np.ndarray, np.ndarray]]:
    import trimesh

    benign, adv = _art(row, "benign_mesh"), _art(row, "adversarial_mesh")
    if benign is None or adv is None:
        return None
    a = trimesh.load(benign, process=False, force="mesh")
    b = trimesh.load(adv, process=False, force="mesh")
    if a.vertices.shape != b.vertices.shape:
        return None
    return np.asarray(a.vertices), np.asarray(b.vertices), np.asarray(a.faces)


def _curvature(vertices: np.ndarray, faces: np.ndarray) -> Optional[np.ndarray]:
    try:
        import torch

        from meshadv.mesh import Mesh, mean_curvature

        mesh = Mesh(torch.as_tensor(vertices, dtype=torch.float32), torch.as_tensor(faces, dtype=torch.int64),
                    torch.full((len(faces), 3), 0.7))
        return mean_curvature(mesh).detach().cpu().numpy().astype(np.float64)
    except Exception:  # noqa: BLE001 - fall back to the figures module's own estimate
        return None


def _flow_figures(rows: List[JobRow], fig_dir: Path, out: ReportOutput) -> None:
    from meshadv.experiments import figures

    by_victim: Dict[str, List[JobRow]] = defaultdict(list)
    for row in rows:
        if row.spec.get("perturbation") == "shape" and not row.record.get("skipped"):
            by_victim[row.spec["victim"]].append(row)
    for victim, vrows in sorted(by_victim.items()):
        # a successful shape attack (when there is one) on the densest mesh, then with the largest flow: the
        # clearest picture of the flow field
        vrows.sort(key=lambda r: (not r.record.get("success"), -(r.record.get("num_vertices") or 0),
                                  -(r.record.get("distances", {}).get("max_displacement") or 0.0)))
        for row in vrows:
            pair = _load_pair(row)
            if pair is None:
                continue
            v, va, f = pair
            view = row.spec["views"][0]
            label = f"{victim}: {row.spec['source_class']} → {row.spec['target']}" + (
                "" if row.record.get("success") else " (attack failed)")
            slug = _slug(victim)
            out.figures.append(figures.flow_heatmaps(v, va, f, fig_dir / f"flow_heatmap_{slug}.png",
                                                     view=view, title=label))
            out.figures.append(figures.flow_quiver(v, va, f, fig_dir / f"flow_quiver_{slug}.png",
                                                   title=f"{label}: flow directions"))
            path, corr = figures.curvature_scatter(v, va, f, fig_dir / f"curvature_{slug}.png",
                                                   curvature=_curvature(v, f))
            out.figures.append(path)
            out.correlations[victim] = {**corr, "job_id": row.job_id}
            break


#: A section a caller adds to the report: ``section(done_rows, out_dir) -> (markdown, files written)``; the
#: Markdown closes the README (``""``: no section). The report command composes them (the perceptual proxies of
#: :mod:`meshadv.study`), so this package imports neither ``meshadv.study`` nor ``meshadv.transfer``.
ReportSection = Callable[[List[JobRow], Path], Tuple[str, List[Path]]]


def write_report(db_path: Union[str, Path], out_dir: Union[str, Path], *, figures: bool = True,
                 transfer_rows: Sequence[Dict[str, Any]] = (), transfer_markdown: str = "",
                 sections: Sequence[ReportSection] = ()) -> ReportOutput:
    """Write the tables, figures and settings of a sweep's results database.

    The full report (with the Mitsuba transfer rows and the perceptual proxies) is composed by
    :func:`meshadv.commands.report.write_full_report`.

    Args:
        db_path: the results database (``results.db``).
        out_dir: the report folder (created).
        figures: also draw the figures.
        transfer_rows: Mitsuba transfer rows (``meshadv.transfer.results.load_transfer_rows``) for the paper
            comparison's Table 3.
        transfer_markdown: the transfer section (written to ``transfer.md`` and into the README), ``""`` for none.
        sections: extra sections, in order (see :data:`ReportSection`).

    Returns:
        A :class:`ReportOutput`.

    Raises:
        FileNotFoundError: ``db_path`` does not exist.
    """
    db = Path(db_path)
    if not db.is_file():
        raise FileNotFoundError(f"results database {db} does not exist")
    out = ReportOutput(out_dir=Path(out_dir))
    out.out_dir.mkdir(parents=True, exist_ok=True)
    with ResultStore(db, read_only=True) as store:
        rows = store.rows()
        meta = store.meta()
        out.counts = store.counts()
    done = [r for r in rows if r.state == "done" and r.record is not None]
    t1 = table1(attack_rows(done))
    t1_correct = table1(attack_rows(done, benign_correct_only=True))
    mixed = any(r.record.get("benign_correct") is False and not r.record.get("skipped") for r in done)
    t2 = table2(done)
    for name, table in (("table1", t1), ("table1_benign_correct", t1_correct), ("table2", t2)):
        if not table and name != "table1" or name == "table1_benign_correct" and not mixed:
            continue
        for ext, text in (("md", to_markdown(table)), ("csv", to_csv(table))):
            path = out.out_dir / f"{name}.{ext}"
            path.write_text(text, encoding="utf-8")
            out.tables.append(path)
    transfer = transfer_markdown
    comparison = paper_comparison(t1_correct if mixed else t1, t2, list(transfer_rows))
    path = out.out_dir / "paper_comparison.md"
    path.write_text(comparison, encoding="utf-8")
    out.tables.append(path)
    if transfer:
        path = out.out_dir / "transfer.md"
        path.write_text(transfer, encoding="utf-8")
        out.tables.append(path)
    if figures:
        fig_dir = out.out_dir / "figures"
        single = [r for r in done if r.spec.get("kind", "single") == "single" and not r.record.get("skipped")]
        groups: Dict[Tuple[str, str], List[JobRow]] = defaultdict(list)
        for r in single:
            groups[(victim_label(r.spec), r.spec["perturbation"])].append(r)
        from meshadv.experiments.figures import render_grid

        for (victim, perturbation), grows in sorted(groups.items()):
            cells, classes, failed = _grid_cells(grows)
            if cells:
                out.figures.append(render_grid(cells, classes, fig_dir / f"grid_{_slug(victim)}_{perturbation}.png",
                                               title=f"{perturbation} attacks on {victim} (rows: benign class, "
                                                     f"columns: target; diagonal: benign; red: attack failed)",
                                               failed=failed))
        _flow_figures(single, fig_dir, out)
    extra = []
    for section in sections:
        text, files = section(done, out.out_dir)
        out.tables.extend(files)
        if text:
            extra.append(text)
    settings = {"database": str(db.resolve()), "meta": meta, "report_versions": environment_versions(),
                "counts": out.counts, "correlations": out.correlations}
    (out.out_dir / "settings.json").write_text(json.dumps(settings, indent=2, sort_keys=True), encoding="utf-8")
    _write_readme(out, t1, t1_correct if mixed else None, t2, meta, _run_stats(done), transfer, comparison)
    for text in extra:  # the callers' sections close the README
        with open(out.out_dir / "README.md", "a", encoding="utf-8") as fh:
            fh.write("\n" + text)
    return out


def _run_stats(done: List[JobRow]) -> List[str]:
    """Lines on benign accuracy and attack cost per victim and type."""
    lines = []
    groups: Dict[Tuple[str, str], List[JobRow]] = defaultdict(list)
    for r in done:
        if r.spec.get("kind", "single") == "single":
            groups[(victim_label(r.spec), r.spec["perturbation"])].append(r)
    for (victim, perturbation), rows in sorted(groups.items()):
        instances = {_instance(r): bool(r.record.get("benign_correct")) for r in rows if "benign_correct" in r.record}
        attacked = [r for r in rows if not r.record.get("skipped")]
        steps = [r.record["steps"] for r in attacked if r.record.get("steps") is not None]
        secs = [r.record["time"] for r in attacked if r.record.get("time") is not None]
        line = f"- {victim}, {perturbation}: {len(attacked)} attacks"
        if instances:
            line += (f"; benign renders classified as their class: {sum(instances.values())}/{len(instances)} "
                     f"instances")
        if steps and secs:
            line += f"; mean {sum(steps) / len(steps):.0f} steps and {sum(secs) / len(secs):.1f} s per attack"
        lines.append(line)
    return lines


def _write_readme(out: ReportOutput, t1: List[Any], t1_correct: Optional[List[Any]], t2: List[Any],
                  meta: Dict[str, Any], stats: List[str], transfer: str = "", comparison: str = "") -> None:
    c = out.counts
    lines = [f"# Results: {meta.get('name', 'sweep')}", "",
             f"Jobs: {c.get('total', 0)} total, {c.get('done', 0)} done ({c.get('successes', 0)} successful), "
             f"{c.get('failed', 0)} failed, {c.get('pending', 0) + c.get('running', 0)} not finished.", ""]
    if meta.get("command"):
        lines += ["Command: `" + meta["command"] + "`", ""]
    lines += stats + [""] if stats else []
    lines += ["## Table 1: best / average / worst case", "", to_markdown(t1), CASE_DEFINITIONS, ""]
    if t1_correct is not None:
        lines += ["### Table 1, benign-correct instances only (the paper's protocol)", "",
                  "Only the instances whose benign render the victim classified as their class:", "",
                  to_markdown(t1_correct)]
    if t2:
        lines += ["## Table 2: multi-view robustness (success on unseen views)", "", to_markdown(t2)]
    if transfer:
        lines += [transfer, ""]
    if comparison:
        lines += [comparison, ""]
    if out.figures:
        lines += ["## Figures", ""]
        lines += [f"- [{p.name}](figures/{p.name})" for p in out.figures]
        lines.append("")
    for victim, corr in out.correlations.items():
        lines.append(f"Flow magnitude vs. mean curvature ({victim}, job {corr['job_id']}): Pearson r = "
                     f"{corr['pearson']:.3f}, Spearman ρ = {corr['spearman']:.3f} over {corr['vertices']} vertices.")
    lines += ["", f"Distances: {'; '.join(f'{k} → ' + ', '.join(v) for k, v in DISTANCE_NAMES.items())} "
              "(the first of each is the paper's measure). "
              "Settings and versions: settings.json.", ""]
    (out.out_dir / "README.md").write_text("\n".join(lines), encoding="utf-8")
