"""``meshadv report``: the tables (Markdown + CSV), the figures (PNG) and the run's settings from a results database.

Output folder layout::

    README.md                  summary: counts, Table 1, Table 2, figure list, correlations, definitions
    table1.md / table1.csv     best / average / worst case per victim and perturbation type
    table1_benign_correct.*    the same over instances whose benign render was classified correctly (written when
                               the sweep also attacked misclassified ones, benign_correct_only = false)
    table2.md / table2.csv     multi-view robustness (when the sweep had multi-view jobs)
    table2_per_class.*         the same per class and target (the paper's Table 2 pools the classes of a cell)
    paper_comparison.md        Tables 1-3 beside the paper's numbers (meshadv.experiments.paper), shortfalls
    figures/grid_<victim>_<type>.png        classes x classes renders (diagonal benign, failed attacks labelled)
    figures/flow_heatmap_<victim>.png       flow magnitude, rendered and canonical views
    figures/flow_quiver_<victim>.png        flow directions around the most displaced vertex
    figures/curvature_<victim>.png          flow magnitude vs. mean curvature (+ correlation in README)
    regeneration.md / .csv     when figures used regenerated artefacts: stored vs regenerated record per job
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
    PAPER_WORST,
    attack_rows,
    table1,
    table2,
    to_csv,
    to_markdown,
    victim_label,
)

__all__ = ["write_report", "ReportOutput", "ArtifactSource", "environment_versions", "figure_caption",
           "settings_mix", "PAPER_FLOW_EXAMPLE"]

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
true); when a sweep attacked every instance, the table restricted to those is given too.
The columns that compare with the paper's Table 1 are the three cases' distance and success in the rows whose
"paper's measure" is yes. The last four columns are the distortion tail, which the paper does not report (it gives
means only): over every successful attack, the median, the 90th percentile (linear interpolation) and the largest
distance, and the share of successful attacks above the paper's largest worst-case distance (shape
laplacian_pair_mean {shape:.2g}, texture color_rmse {texture:.2g}; a mean over the paper's instances, so some of the
paper's own attacks lie above it too). A mean or median alone hides a tail of visibly broken meshes.""".format(
    shape=PAPER_WORST["shape"], texture=PAPER_WORST["texture"])


def _git_state(folder: Path) -> Dict[str, str]:
    """``{"git_commit": ..., "git_dirty": "yes"/"no"}`` of the checkout holding ``folder`` (``{}`` outside one): the
    package version alone does not say which code ran, and an editable install runs uncommitted edits too."""
    import subprocess

    try:
        commit = subprocess.run(["git", "-C", str(folder), "rev-parse", "HEAD"], capture_output=True, text=True,
                                timeout=10, check=True).stdout.strip()
        status = subprocess.run(["git", "-C", str(folder), "status", "--porcelain", "--untracked-files=no", "--",
                                 "."], capture_output=True, text=True, timeout=10, check=True).stdout
    except (OSError, subprocess.SubprocessError):
        return {}
    return {"git_commit": commit, "git_dirty": "yes" if status.strip() else "no"} if commit else {}


def environment_versions() -> Dict[str, str]:
    """Versions of Python, the platform and the main packages (those importable), and, when meshadv runs from a git
    checkout, its commit and whether the package's files had uncommitted changes (``git_dirty``)."""
    out = {"python": sys.version.split()[0], "platform": platform.platform()}
    for name in ("meshadv", "torch", "numpy", "matplotlib", "ray"):
        try:
            module = __import__(name)
            out[name] = str(getattr(module, "__version__", "?"))
        except Exception:  # noqa: BLE001 - a missing optional package is simply not listed
            continue
    try:
        import meshadv

        out.update(_git_state(Path(meshadv.__file__).resolve().parent))
    except Exception:  # noqa: BLE001 - versions are informative, never fatal
        pass
    return out


@dataclass
class ReportOutput:
    """What :func:`write_report` wrote.

    Attributes:
        out_dir: the report folder. tables: written table files. figures: written figure files.
        correlations: per victim, the flow-magnitude / mean-curvature correlations.
        counts: job counts per state.
        regenerations: per job whose artefacts the figures took from a regeneration, its check against the stored
            record (:class:`ArtifactSource`).
    """

    out_dir: Path
    tables: List[Path] = field(default_factory=list)
    figures: List[Path] = field(default_factory=list)
    correlations: Dict[str, Dict[str, float]] = field(default_factory=dict)
    counts: Dict[str, int] = field(default_factory=dict)
    regenerations: Dict[str, Dict[str, Any]] = field(default_factory=dict)


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in text)


def _artifact_names(record: Dict[str, Any]) -> List[str]:
    """The file names a record's ``artifacts`` lists (relative ones: what a complete job folder holds)."""
    names: List[str] = []
    for value in (record.get("artifacts") or {}).values():
        for name in value if isinstance(value, list) else [value]:
            if isinstance(name, str) and name and not Path(name).is_absolute():
                names.append(name)
    return names


def _complete(folder: Optional[Union[str, Path]], record: Dict[str, Any]) -> bool:
    """Whether ``folder`` holds every artefact ``record`` lists (a folder the job finished writing)."""
    if not folder or "://" in str(folder):
        return False
    names = _artifact_names(record)
    return bool(names) and all((Path(folder) / n).is_file() for n in names)


class ArtifactSource:
    """Where the report finds the artefacts (meshes, renders) of a finished job.

    The folder the database records for the job when it is complete on this machine (``use_stored``), else
    ``<root>/jobs/<id[:2]>/<id>`` when it is complete there (regenerated earlier), else, with ``root`` set, the job is
    regenerated there from its stored spec and seed (:func:`meshadv.experiments.regenerate.regenerate_job`) and its
    new record is compared with the stored one; each regeneration's check is kept in :attr:`checks` and written to
    ``regeneration.json`` in the job's folder (read back when a later report reuses the folder).

    Args:
        db_path: the results database. root: the folder for regenerated artefacts (``None``: never regenerate).
        use_stored: use the folders the database records. threads: intra-op threads of a regeneration.
        assume: the sweep's defaults for records that do not pin them (:func:`~meshadv.experiments.regenerate.
            pinned_spec`).
    """

    def __init__(self, db_path: Union[str, Path], root: Optional[Union[str, Path]] = None, *,
                 use_stored: bool = True, threads: int = 1, assume: Optional[Dict[str, Any]] = None) -> None:
        self.db_path = Path(db_path)
        self.root = None if root is None else Path(root)
        self.use_stored = bool(use_stored)
        self.threads = int(threads)
        self.assume = dict(assume or {})
        self.checks: Dict[str, Dict[str, Any]] = {}
        self._folders: Dict[str, Optional[Path]] = {}

    def folder(self, row: JobRow, *, regenerate: bool = True) -> Optional[Path]:
        """The job's complete artefact folder, regenerating it when allowed and needed; ``None`` when there is none."""
        if row.job_id in self._folders and (self._folders[row.job_id] is not None or not regenerate):
            return self._folders[row.job_id]
        record = row.record or {}
        found: Optional[Path] = None
        if self.use_stored and _complete(row.out_dir, record):
            found = Path(str(row.out_dir))
        elif self.root is not None:
            from meshadv.experiments.runner import job_out_dir

            target = job_out_dir(self.root, row.job_id)
            check_file = target / "regeneration.json"
            if _complete(target, record) and check_file.is_file():
                found = target
                self.checks[row.job_id] = json.loads(check_file.read_text(encoding="utf-8"))
            elif regenerate:
                found = self._regenerate(row, target)
        self._folders[row.job_id] = found
        return found

    def _regenerate(self, row: JobRow, target: Path) -> Path:
        import time

        from meshadv.experiments.regenerate import regenerate_job

        cpu = time.process_time()
        done = regenerate_job(self.db_path, row.job_id, target, threads=self.threads, assume=self.assume)
        check = {"job_id": row.job_id, "matches": done.matches, "differences": list(done.differences),
                 "notes": list(done.notes), "cpu_s": round(time.process_time() - cpu, 2),
                 "stored": {k: (done.stored or {}).get(k) for k in ("success", "steps", "distance")},
                 "regenerated": {k: done.record.get(k) for k in ("success", "steps", "distance")}}
        (target / "regeneration.json").write_text(json.dumps(check, indent=2, sort_keys=True), encoding="utf-8")
        self.checks[row.job_id] = check
        return target


def _art(row: JobRow, key: str, index: int = 0, source: Optional[ArtifactSource] = None) -> Optional[Path]:
    arts = (row.record or {}).get("artifacts", {})
    value = arts.get(key)
    if isinstance(value, list):
        value = value[index] if index < len(value) else None
    if not value:
        return None
    if source is not None:
        folder = source.folder(row)
    else:
        folder = None if row.out_dir is None else Path(row.out_dir)
    if folder is None:
        return None
    path = folder / value
    return path if path.exists() else None


def _instance(row: JobRow) -> Tuple[Any, ...]:
    mesh = row.spec["mesh"]
    return (mesh.get("path") or mesh.get("name"), row.spec.get("config_index"), row.spec.get("seed"),
            row.spec.get("protocol"))


def _grid_cells(rows: List[JobRow], source: Optional[ArtifactSource] = None,
                ) -> Tuple[Dict[Tuple[str, str], Path], List[str], Set[Tuple[str, str]]]:
    """Pick, per source class, the instance with the most successful targets (from the records alone); return its
    renders, the classes and the ``(source, target)`` cells whose attack failed. Only the chosen instances' jobs are
    looked up in ``source`` (regenerated when it regenerates)."""
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
            benign = _art(r, "benign_images", 0, source)
            if benign is not None:
                cells.setdefault((src, src), benign)
            adv = _art(r, "adversarial_images", 0, source)
            if adv is not None:
                cells[(src, r.spec["target"])] = adv
                if not r.record.get("success"):
                    failed.add((src, r.spec["target"]))
    return cells, classes, failed


def _load_pair(row: JobRow, source: Optional[ArtifactSource] = None,
               ) -> Optional[Tuple[np.ndarray, np.ndarray, np.ndarray]]:
    import trimesh

    benign, adv = _art(row, "benign_mesh", 0, source), _art(row, "adversarial_mesh", 0, source)
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


#: The example of the paper's Fig. 3 (flow directions on an aeroplane attacked towards "bicycle"): the flow figures
#: show this attack when a victim has a successful one, else the attack chosen by :func:`_flow_order`.
PAPER_FLOW_EXAMPLE = ("aeroplane", "bicycle")


def _flow_order(row: JobRow) -> Tuple[Any, ...]:
    """Sort key of the flow figures' candidates: the paper's example first, then a successful attack on the densest
    mesh with the largest flow (the clearest picture of the flow field)."""
    rec = row.record or {}
    paper = (row.spec.get("source_class"), row.spec.get("target")) == PAPER_FLOW_EXAMPLE and bool(rec.get("success"))
    return (not paper, not rec.get("success"), -(rec.get("num_vertices") or 0),
            -((rec.get("distances") or {}).get("max_displacement") or 0.0), row.job_id)


def _flow_pair(rows: List[JobRow], source: ArtifactSource,
               ) -> Optional[Tuple[JobRow, Tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """The first candidate (in :func:`_flow_order`) whose meshes are on this machine; else the first one,
    regenerated when ``source`` regenerates (one job, not every candidate)."""
    ordered = sorted(rows, key=_flow_order)
    for row in ordered:
        if source.folder(row, regenerate=False) is not None:
            pair = _load_pair(row, source)
            if pair is not None:
                return row, pair
    if ordered and source.root is not None:
        pair = _load_pair(ordered[0], source)
        if pair is not None:
            return ordered[0], pair
    return None


def _flow_figures(rows: List[JobRow], fig_dir: Path, out: ReportOutput,
                  source: Optional[ArtifactSource] = None) -> None:
    """Flow heatmaps (rendered and canonical view), quiver plot and flow vs curvature of one shape attack per victim
    (the paper's Fig. 3)."""
    from meshadv.experiments import figures

    if source is None:
        source = ArtifactSource(Path("."), None)
    by_victim: Dict[str, List[JobRow]] = defaultdict(list)
    for row in rows:
        if row.spec.get("perturbation") == "shape" and not row.record.get("skipped"):
            by_victim[victim_label(row.spec)].append(row)
    for victim, vrows in sorted(by_victim.items()):
        found = _flow_pair(vrows, source)
        if found is None:
            continue
        row, (v, va, f) = found
        view = row.spec["views"][0]
        label = f"{victim}: {row.spec['source_class']} → {row.spec['target']}" + (
            "" if row.record.get("success") else " (attack failed)")
        slug = _slug(victim)
        out.figures.append(figures.flow_heatmaps(v, va, f, fig_dir / f"flow_heatmap_{slug}.png",
                                                 view=view, title=label))
        out.figures.append(figures.flow_quiver(v, va, f, fig_dir / f"flow_quiver_{slug}.png",
                                               title=f"{label}: flow directions"))
        path, corr = figures.curvature_scatter(v, va, f, fig_dir / f"curvature_{slug}.png",
                                               curvature=_curvature(v, f), eye=figures.camera_eye(view),
                                               title=label)
        out.figures.append(path)
        out.correlations[victim] = {**corr, "job_id": row.job_id}


#: A section a caller adds to the report: ``section(done_rows, out_dir) -> (markdown, files written)``; the
#: Markdown closes the README (``""``: no section). The report command composes them (the perceptual proxies of
#: :mod:`meshadv.study`), so this package imports neither ``meshadv.study`` nor ``meshadv.transfer``.
ReportSection = Callable[[List[JobRow], Path], Tuple[str, List[Path]]]


def write_report(db_path: Union[str, Path], out_dir: Union[str, Path], *, figures: bool = True,
                 transfer_rows: Sequence[Dict[str, Any]] = (), transfer_markdown: str = "",
                 sections: Sequence[ReportSection] = (), artifacts: Optional[Union[str, Path]] = None,
                 use_stored: bool = True, threads: int = 1, assume: Optional[Dict[str, Any]] = None) -> ReportOutput:
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
        artifacts: where the artefacts the figures need are regenerated when they are not on this machine
            (:class:`ArtifactSource`; only the jobs a figure uses); ``None``: never regenerate.
        use_stored: use the artefact folders the database records (``False``: every figure from regenerated
            artefacts, e.g. to check that the database reproduces them).
        threads: intra-op threads of each regeneration.
        assume: the sweep's defaults for records that do not pin them (:func:`meshadv.experiments.regenerate.
            pinned_spec`).

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
    mixed = attacked_misclassified(done)
    t2 = table2(done)
    t2_classes = table2(done, per_class=True)
    for name, table in (("table1", t1), ("table1_benign_correct", t1_correct), ("table2", t2),
                        ("table2_per_class", t2_classes)):
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

        source = ArtifactSource(db, artifacts, use_stored=use_stored, threads=threads, assume=assume)
        for (victim, perturbation), grows in sorted(groups.items()):
            cells, classes, failed = _grid_cells(grows, source)
            if cells:
                out.figures.append(render_grid(cells, classes, fig_dir / f"grid_{_slug(victim)}_{perturbation}.png",
                                               title=f"{perturbation} attacks on {victim} (rows: benign class, "
                                                     f"columns: target; diagonal: benign; red: attack failed)",
                                               failed=failed))
        _flow_figures(single, fig_dir, out, source)
        out.regenerations = dict(source.checks)
        if out.regenerations:
            out.tables.extend(_write_regenerations(out.out_dir, out.regenerations, done))
    extra = []
    for section in sections:
        text, files = section(done, out.out_dir)
        out.tables.extend(files)
        if text:
            extra.append(text)
    settings = {"database": str(db.resolve()), "meta": meta, "report_versions": environment_versions(),
                "counts": out.counts, "correlations": out.correlations}
    if out.regenerations:
        settings["regenerated_with"] = {"threads": threads, "assume": assume or {}}
    (out.out_dir / "settings.json").write_text(json.dumps(settings, indent=2, sort_keys=True), encoding="utf-8")
    _write_readme(out, t1, t1_correct if mixed else None, t2, meta, _run_stats(done), transfer, comparison)
    for text in extra:  # the callers' sections close the README
        with open(out.out_dir / "README.md", "a", encoding="utf-8") as fh:
            fh.write("\n" + text)
    return out


def _write_regenerations(out_dir: Path, checks: Dict[str, Dict[str, Any]], done: List[JobRow]) -> List[Path]:
    """``regeneration.md`` / ``regeneration.csv``: per regenerated job, stored vs regenerated success, steps and
    distance; returns the files."""
    specs = {r.job_id: r.spec for r in done}
    header = ["job", "victim", "type", "source", "target", "stored success", "regenerated success",
              "stored distance", "regenerated distance", "relative difference", "matches", "CPU s"]
    table = []
    for jid, c in sorted(checks.items(), key=lambda kv: (victim_label(specs.get(kv[0], {"victim": "?"})),
                                                            str(specs.get(kv[0], {}).get("perturbation")),
                                                            str(specs.get(kv[0], {}).get("source_class")),
                                                            str(specs.get(kv[0], {}).get("target")))):
        spec = specs.get(jid, {})
        a, b = (c.get("stored") or {}).get("distance"), (c.get("regenerated") or {}).get("distance")
        rel = abs(b - a) / abs(a) if isinstance(a, (int, float)) and isinstance(b, (int, float)) and a else None
        table.append([jid, victim_label(spec) if spec else "?", spec.get("perturbation"), spec.get("source_class"),
                      spec.get("target"), (c.get("stored") or {}).get("success"),
                      (c.get("regenerated") or {}).get("success"), a, b, rel, c.get("matches"), c.get("cpu_s")])
    n = len(table)
    same_success = sum(1 for r in table if r[5] == r[6])
    matches = sum(1 for r in table if r[10])
    rels = sorted(r[9] for r in table if r[9] is not None)
    notes = sorted({note for c in checks.values() for note in c.get("notes", [])})

    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.3g}"
        return "" if v is None else str(v)

    lines = ["## Regenerated artefacts", "",
             f"The figures' artefacts of {n} job(s) were regenerated from the database (stored spec and seed, "
             f"`meshadv regenerate`): success equal in {same_success}/{n}, success, steps and distance equal "
             f"(distance to 1e-3 relative) in {matches}/{n}"
             + (f"; relative distance difference median {rels[len(rels) // 2]:.2g}, largest {rels[-1]:.2g}"
                if rels else "") + ".", ""]
    if notes:
        lines += ["Not pinned by the database (today's defaults used):", ""] + [f"- {t}" for t in notes] + [""]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in table]
    md = out_dir / "regeneration.md"
    md.write_text("\n".join(lines) + "\n", encoding="utf-8")
    import csv

    path = out_dir / "regeneration.csv"
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        writer.writerows(table)
    return [md, path]


def settings_mix(done: List[JobRow]) -> List[str]:
    """Warnings for table groups (victim, type) whose attacks ran with different effective settings.

    A spec names only what its config sets; a sweep resumed after a default changed (an update rule's options, the
    victim's ``optimize``) runs its remaining jobs with the new default, and Table 1 would pool both. The records say
    what each job ran with (``attack_config``, ``victim_optimize``; records from before they were recorded count as
    one "not recorded" setting).

    Returns:
        One line per group with more than one setting (empty when every group is uniform).
    """
    groups: Dict[Tuple[str, str], Dict[str, int]] = defaultdict(lambda: defaultdict(int))
    for r in done:
        rec = r.record or {}
        if rec.get("skipped"):
            continue
        config = rec.get("attack_config")
        if isinstance(config, dict):  # the seed is the instance's, not a setting
            config = {k: v for k, v in config.items() if k != "seed"}
        key = json.dumps({"attack_config": config, "victim_optimize": rec.get("victim_optimize")}, sort_keys=True)
        groups[(victim_label(r.spec), str(r.spec.get("perturbation")))][key] += 1
    lines = []
    for (victim, perturbation), counts in sorted(groups.items()):
        if len(counts) > 1:
            sizes = ", ".join(str(n) for n in sorted(counts.values(), reverse=True))
            lines.append(f"- WARNING: {victim}, {perturbation}: the attacks ran with {len(counts)} different effective "
                         f"settings (attack_config / victim_optimize; {sizes} attacks): a default changed while the "
                         "sweep was resumed, and the tables pool them")
    return lines


def _run_stats(done: List[JobRow]) -> List[str]:
    """Lines on benign accuracy and attack cost per victim and type, then :func:`settings_mix`'s warnings."""
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
    return lines + settings_mix(done)


def figure_caption(name: str) -> str:
    """The caption of a report figure from its file name, with the paper's figure it regenerates."""
    stem = Path(name).stem
    if stem.startswith("grid_"):
        return ("the paper's Fig. 2: rows are benign classes (per class the instance with the most successful "
                "targets), columns target classes; the diagonal is the benign render (green frame), the other cells "
                "the adversarial render towards the column's class (\"failed\" in red: the attack did not succeed)")
    if stem.startswith("flow_heatmap_"):
        return ("the paper's Fig. 3, heatmaps: per-face flow magnitude |v_adv - v| on the benign mesh, in the attack's "
                "(rendered) view and in the canonical view (azimuth 135°, elevation 45°), colour scale 0 to the "
                "largest vertex flow")
    if stem.startswith("flow_quiver_"):
        return ("the paper's Fig. 3, quiver plot: flow directions (unit arrows, coloured by magnitude) of the "
                "vertices nearest the most displaced one")
    if stem.startswith("curvature_"):
        return ("the paper's Fig. 3, flow vs. curvature: per-vertex flow magnitude against |mean curvature|, "
                "coloured by distance to the camera (correlations below)")
    return ""


def attacked_misclassified(done: List[Any]) -> bool:
    """Whether a single-view attack of ``done`` ran on a benign render its victim got wrong (then Table 1 is also
    written over the benign-correct instances only). Multi-view jobs are not benign-filtered; Table 2 counts theirs.
    """
    return any(r.record.get("benign_correct") is False and not r.record.get("skipped")
               and r.spec.get("kind", "single") == "single" for r in done)


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
        lines += ["## Table 2: multi-view robustness (success on unseen views)", "", to_markdown(t2),
                  "Per class and target: [table2_per_class.md](table2_per_class.md).", ""]
    if transfer:
        lines += [transfer, ""]
    if comparison:
        lines += [comparison, ""]
    if out.figures:
        lines += ["## Figures", ""]
        lines += [f"- [{p.name}](figures/{p.name}): {figure_caption(p.name)}" for p in out.figures]
        lines.append("")
    if out.regenerations:
        same = sum(1 for c in out.regenerations.values() if c.get("matches"))
        lines += [f"The figures use regenerated artefacts of {len(out.regenerations)} job(s); {same} reproduce "
                  "their stored success, steps and distance: regeneration.md.", ""]
    for victim, corr in out.correlations.items():
        line = (f"Flow magnitude vs. mean curvature ({victim}, job {corr['job_id']}): Pearson r = "
                f"{corr['pearson']:.3f}, Spearman ρ = {corr['spearman']:.3f} over {corr['vertices']} vertices")
        if "spearman_camera_distance" in corr:
            line += (f"; flow vs. distance to the camera: Spearman ρ = {corr['spearman_camera_distance']:.3f} "
                     "(negative: more flow nearer the camera)")
        lines.append(line + ".")
    lines += ["", f"Distances: {'; '.join(f'{k} → ' + ', '.join(v) for k, v in DISTANCE_NAMES.items())} "
              "(the first of each is the paper's measure). "
              "Settings and versions: settings.json.", ""]
    (out.out_dir / "README.md").write_text("\n".join(lines), encoding="utf-8")
