"""``meshadv report``: the tables (Markdown + CSV), the figures (PNG) and the run's settings from a results database.

Output folder layout::

    README.md                  summary: counts, Table 1, Table 2, figure list, correlations, definitions
    table1.md / table1.csv     best / average / worst case per victim and perturbation type
    table1_benign_correct.*    the same over instances whose benign render was classified correctly (written when
                               the sweep also attacked misclassified ones, benign_correct_only = false)
    table1_pairs.md / .csv     Table 1's attacks per source and target class (successful / attacks), where misses are
    table2.md / table2.csv     multi-view robustness (when the sweep had multi-view jobs)
    table2_per_class.*         the same per class and target (the paper's Table 2 pools the classes of a cell)
    paper_comparison.md        Tables 1-3 beside the paper's numbers (meshadv.experiments.paper), shortfalls
    protocols.md / .csv        an extra protocol's attacks beside the main attack's on the same inputs (when the
                               sweep ran one: meshadv.experiments.protocols)
    figures/grid_<victim>_<type>.png        classes x classes renders (diagonal benign, failed attacks labelled)
    figures/cells/<job>_<render>.png        the grids' cell renders, kept small, so that a report re-run from the
                                            database alone can draw a grid again without the run's artefacts
    figures/flow_heatmap_<victim>.png       flow magnitude, rendered and canonical views
    figures/flow_quiver_<victim>.png        flow directions around the most displaced vertex
    figures/curvature_<victim>.png          flow magnitude vs. mean curvature (+ correlation in README)
    regeneration.md / .csv     when figures used regenerated artefacts: stored vs regenerated record per job
    proxies.csv                SSIM / PSNR of benign vs. adversarial render per attack (meshadv.study.proxies)
    settings.json              the sweep config, database meta (versions at sweep time) and versions now
"""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union


from meshadv.experiments.artifact_source import ArtifactSource
from meshadv.experiments.compare import paper_comparison
from meshadv.experiments.protocols import protocol_section
from meshadv.experiments.provenance import environment_versions
from meshadv.experiments.retries import is_retry, superseded_retries, with_retried_transfers, with_retries
from meshadv.experiments.figures import render_grid
from meshadv.experiments.report_figures import (
    PAPER_FLOW_EXAMPLE,
    STAMP_KEY,
    flow_figures,
    grid_cells,
    grid_choice,
    grid_stamp,
    is_current,
    slug_of,
)
from meshadv.experiments.store import JobRow, ResultStore
from meshadv.experiments.config import stored_retry_stages
from meshadv.util.atomic import write_text_atomic
from meshadv.util.paths import relative_path
from meshadv.util.png import add_png_text
from meshadv.experiments.tables import (
    DISTANCE_NAMES,
    PAPER_WORST,
    attack_rows,
    instance_key,
    labelled_by_protocol,
    pair_success,
    pair_success_markdown,
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
paper's own attacks lie above it too). A mean or median alone hides a tail of visibly broken meshes.
Rows "victim [name]" are an extra protocol's attacks; "victim [retry]" the retries alone (each a main attack that
failed, run again from its benign mesh with the sweep's [attack.retry] budget), "victim [retry k]" those of a later
retry stage (a stage k-1 retry that failed, run again with stage k's options) and "victim [+retry]" every main
attack, counted by the first of its retries that succeeded where it failed (meshadv.experiments.retries).""".format(
    shape=PAPER_WORST["shape"], texture=PAPER_WORST["texture"])


@dataclass
class ReportOutput:
    """What :func:`write_report` wrote.

    Attributes:
        out_dir: the report folder. tables: written table files. figures: written figure files.
        correlations: per victim, the flow-magnitude / mean-curvature correlations.
        counts: job counts per state.
        regenerations: per job whose artefacts the figures took from a regeneration, its check against the stored
            record (:class:`ArtifactSource`).
        superseded: job id -> state of the retries left out because the config's retry stages changed since
            they were made (:func:`meshadv.experiments.retries.superseded_retries`).
    """

    out_dir: Path
    tables: List[Path] = field(default_factory=list)
    figures: List[Path] = field(default_factory=list)
    correlations: Dict[str, Dict[str, float]] = field(default_factory=dict)
    counts: Dict[str, int] = field(default_factory=dict)
    regenerations: Dict[str, Dict[str, Any]] = field(default_factory=dict)
    superseded: Dict[str, str] = field(default_factory=dict)


#: A section a caller adds to the report: ``section(done_rows, out_dir) -> (markdown, files written)``; the
#: Markdown closes the README (``""``: no section). The report command composes them (the perceptual proxies of
#: :mod:`meshadv.study`), so this package imports neither ``meshadv.study`` nor ``meshadv.transfer``.
ReportSection = Callable[[List[JobRow], Path], Tuple[str, List[Path]]]


def write_report(db_path: Union[str, Path], out_dir: Union[str, Path], *, figures: bool = True,
                 transfer_rows: Sequence[Dict[str, Any]] = (),
                 transfer_section: Optional[Callable[[List[Dict[str, Any]]], str]] = None,
                 sections: Sequence[ReportSection] = (), artifacts: Optional[Union[str, Path]] = None,
                 use_stored: bool = True, threads: int = 1, assume: Optional[Dict[str, Any]] = None,
                 redraw: bool = False) -> ReportOutput:
    """Write the tables, figures and settings of a sweep's results database.

    The full report (with the Mitsuba transfer rows and the perceptual proxies) is composed by
    :func:`meshadv.commands.report.write_full_report`.

    Args:
        db_path: the results database (``results.db``).
        out_dir: the report folder (created).
        figures: also draw the figures.
        transfer_rows: Mitsuba transfer rows (``meshadv.transfer.results.load_transfer_rows``) for the paper
            comparison's Table 3; an extra protocol's rows are named as in Table 1 (:func:`labelled_by_protocol`).
        transfer_section: the transfer section (written to ``transfer.md`` and into the README) of those rows, so
            named (``meshadv.transfer.results.transfer_report``); ``None`` or no rows: none.
        sections: extra sections, in order (see :data:`ReportSection`), after the built-in one comparing an extra
            protocol with the main attack (:func:`meshadv.experiments.protocols.protocol_section`).
        artifacts: where the artefacts the figures need are rebuilt from the perturbations the database keeps, or
            regenerated from the stored spec and seed for jobs it keeps none of, when they are not on this machine
            (:class:`ArtifactSource`; only the jobs a figure uses); ``None``: rebuilt next to the database
            (``<its folder>/jobs/..``), never regenerated.
        use_stored: use the artefact folders the database records (``False``: every figure from regenerated
            artefacts, e.g. to check that the database reproduces them).
        threads: intra-op threads of each regeneration.
        assume: the sweep's defaults for records that do not pin them (:func:`meshadv.experiments.regenerate.
            pinned_spec`).
        redraw: draw every figure again (so does ``use_stored=False``). By default a figure whose PNG in
            ``out_dir`` records that it was drawn from the same jobs and outcomes (``report_figures.grid_stamp``,
            ``flow_stamp``) is kept, so that a report re-run on a machine without the artefacts does not regenerate
            them (a grid drawn with cells missing records nothing).

    Returns:
        A :class:`ReportOutput`.

    Raises:
        FileNotFoundError: ``db_path`` does not exist. ValueError: ``db_path`` is a folder.
    """
    db = Path(db_path)
    if db.is_dir():
        raise ValueError(f"results database {db} is a folder; give the results.db file in it")
    if not db.is_file():
        raise FileNotFoundError(f"results database {db} does not exist")
    out = ReportOutput(out_dir=Path(out_dir))
    out.out_dir.mkdir(parents=True, exist_ok=True)
    with ResultStore(db, read_only=True) as store:
        rows = store.rows()
        meta = store.meta()
        out.counts = store.counts()
    # retries of stages the config no longer has are left out, so that a parent has one retry per stage
    superseded = superseded_retries(stored_retry_stages(meta.get("config_text")), rows)
    out.superseded = {r.job_id: r.state for r in rows if r.job_id in superseded}
    done = [r for r in rows if r.state == "done" and r.record is not None and r.job_id not in superseded]
    combined = [*done, *with_retries(done)]  # + each main attack with its retry: the victims' [+retry] rows
    attacks, attacks_correct = attack_rows(combined), attack_rows(combined, benign_correct_only=True)
    t1, t1_correct = table1(attacks), table1(attacks_correct)
    mixed = attacked_misclassified(done)
    pairs = pair_success(attacks_correct if mixed else attacks)
    t2 = table2(done)
    t2_classes = table2(done, per_class=True)
    for name, table in (("table1", t1), ("table1_benign_correct", t1_correct), ("table2", t2),
                        ("table2_per_class", t2_classes)):
        if not table and name != "table1" or name == "table1_benign_correct" and not mixed:
            continue
        for ext, text in (("md", to_markdown(table)), ("csv", to_csv(table))):
            out.tables.append(write_text_atomic(out.out_dir / f"{name}.{ext}", text))
    if pairs:
        out.tables.append(write_text_atomic(out.out_dir / "table1_pairs.md", pair_success_markdown(pairs)))
        out.tables.append(write_text_atomic(out.out_dir / "table1_pairs.csv", to_csv(pairs)))
    specs = {r.job_id: r.spec for r in done}
    transfer_rows = [r for r in transfer_rows if r.get("case_id") not in superseded]
    transfer_rows = [*labelled_by_protocol(transfer_rows, specs), *with_retried_transfers(transfer_rows, specs)]
    transfer = transfer_section(transfer_rows) if transfer_section and transfer_rows else ""
    comparison = paper_comparison(t1_correct if mixed else t1, t2, transfer_rows)
    out.tables.append(write_text_atomic(out.out_dir / "paper_comparison.md", comparison))
    if transfer:
        out.tables.append(write_text_atomic(out.out_dir / "transfer.md", transfer))
    if figures:
        fig_dir = out.out_dir / "figures"
        # the figures show the main attacks and the extra protocols; a retry is drawn in neither
        single = [r for r in done if r.spec.get("kind", "single") == "single" and not r.record.get("skipped")
                  and not is_retry(r.spec)]
        # a job whose folder is not here is rebuilt from its stored perturbation (next to the database unless told
        # where); one without a perturbation is regenerated only into a folder given for it (an attack per job)
        root = artifacts if artifacts is not None else db.parent
        source = ArtifactSource(db, root, use_stored=use_stored, threads=threads, assume=assume,
                                regenerate_missing=artifacts is not None)
        reuse = use_stored and not redraw
        cache = fig_dir / "cells" if use_stored else None  # --no-stored: every render regenerated, none cached
        out.figures.extend(_grids(single, fig_dir, source, reuse=reuse, cache=cache))
        flow_paths, out.correlations = flow_figures(single, fig_dir, source, redraw=not reuse)
        out.figures.extend(flow_paths)
        out.regenerations = {job: c for job, c in source.checks.items() if not c.get("rebuilt")}
        if out.regenerations:
            out.tables.extend(_write_regenerations(out.out_dir, out.regenerations, done))
    extra = []
    for section in (protocol_section, *sections):
        text, files = section(done, out.out_dir)
        out.tables.extend(files)
        if text:
            extra.append(text)
    settings = {"database": relative_path(db, out.out_dir), "meta": meta, "report_versions": environment_versions(),
                "counts": out.counts, "correlations": out.correlations, "superseded_retries": out.superseded}
    if out.regenerations:
        settings["regenerated_with"] = {"threads": threads, "assume": assume or {}}
    write_text_atomic(out.out_dir / "settings.json", json.dumps(settings, indent=2, sort_keys=True))
    # the callers' sections close the README (written once, atomically, with them)
    _write_readme(out, t1, t1_correct if mixed else None, t2, meta, _run_stats(done), transfer, comparison, extra,
                  pairs)
    return out


def _grids(single: List[JobRow], fig_dir: Path, source: ArtifactSource, *, reuse: bool,
           cache: Optional[Path]) -> List[Path]:
    """The 7x7 grid of each (victim, type) of the single-view jobs: kept when ``reuse`` and its PNG records the
    stamp of the jobs and outcomes it would show, else drawn (from ``cache``'s cell renders, else the artefacts) and
    stamped when no cell is missing. Returns the grids."""
    groups: Dict[Tuple[str, str], List[JobRow]] = defaultdict(list)
    for r in single:
        groups[(victim_label(r.spec), r.spec["perturbation"])].append(r)
    written = []
    for (victim, perturbation), grows in sorted(groups.items()):
        path = fig_dir / f"grid_{slug_of(victim)}_{perturbation}.png"
        title = (f"{perturbation} attacks on {victim} (rows: benign class, columns: target; diagonal: benign; "
                 "red: attack failed)")
        choice = grid_choice(grows)
        stamp = grid_stamp(choice, title)
        if reuse and is_current([path], stamp):  # drawn from the same jobs and outcomes already
            written.append(path)
            continue
        cells, classes, failed = grid_cells(grows, source, cache=cache, choice=choice)
        if not cells:
            continue
        written.append(render_grid(cells, classes, path, title=title, failed=failed))
        if all((src, src) in cells and (src, r.spec["target"]) in cells
               for src, inst_rows in choice[0].items() for r in inst_rows):  # no cell missing: worth keeping
            add_png_text(path, {STAMP_KEY: stamp})
    return written


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
             f"`meshadv regenerate`): success equal in {same_success}/{n}, success, steps, distance and first "
             f"successful step equal (distance to 1e-3 relative) in {matches}/{n}"
             + (f"; relative distance difference median {rels[len(rels) // 2]:.2g}, largest {rels[-1]:.2g}"
                if rels else "") + ".", ""]
    if notes:
        lines += ["Not pinned by the database (today's defaults used):", ""] + [f"- {t}" for t in notes] + [""]
    if matches < n:
        from meshadv.experiments.regenerate import compute_note

        first = next(c for c in checks.values() if not c.get("matches"))
        lines += ["Where a record is not reproduced: " + compute_note(first.get("stored")) + " (of the first such "
                  "job).", ""]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in table]
    md = write_text_atomic(out_dir / "regeneration.md", "\n".join(lines) + "\n")
    import csv
    import io

    buffer = io.StringIO(newline="")
    writer = csv.writer(buffer)
    writer.writerow(header)
    writer.writerows(table)
    return [md, write_text_atomic(out_dir / "regeneration.csv", buffer.getvalue())]


def settings_mix(done: List[JobRow]) -> List[str]:
    """Warnings for table groups (victim, type) whose attacks ran with different effective settings.

    A spec names only what its config sets; a sweep resumed after a default changed (an update rule's options, the
    victim's ``optimize``) runs its remaining jobs with the new default, and Table 1 would pool both. The records say
    what each job ran with (``attack_config``, ``victim_optimize``; records from before they were recorded count as
    one "not recorded" setting). A cap ceiling recorded as ``None`` (unbounded) equals one the record does not name.

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
            cap = config.get("perceptibility_cap")
            if isinstance(cap, dict):  # an unbounded ceiling is the same setting as one a record predates
                config["perceptibility_cap"] = {k: v for k, v in cap.items() if v is not None}
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
        instances = {instance_key(r.spec): bool(r.record.get("benign_correct"))
                     for r in rows if "benign_correct" in r.record}
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
                  meta: Dict[str, Any], stats: List[str], transfer: str = "", comparison: str = "",
                  extra: Sequence[str] = (), pairs: Sequence[Any] = ()) -> None:
    """README.md (atomically): counts, the tables (Table 1's ``pairs`` after it), figures and definitions, then the
    sections ``extra``."""
    c = out.counts
    lines = [f"# Results: {meta.get('name', 'sweep')}", "",
             f"Jobs: {c.get('total', 0)} total, {c.get('done', 0)} done ({c.get('successes', 0)} successful), "
             f"{c.get('failed', 0)} failed, {c.get('pending', 0) + c.get('running', 0)} not finished.", ""]
    if out.superseded:
        finished = sum(state == "done" for state in out.superseded.values())
        lines += [f"{len(out.superseded)} retries were made by retry stages the config no longer has ({finished} of "
                  "them finished, the others will not run) and are left out of every table (settings.json lists "
                  "them).", ""]
    if meta.get("command"):
        lines += ["Command: `" + meta["command"] + "`", ""]
    lines += stats + [""] if stats else []
    lines += ["## Table 1: best / average / worst case", "", to_markdown(t1), CASE_DEFINITIONS, ""]
    if t1_correct is not None:
        lines += ["### Table 1, benign-correct instances only (the paper's protocol)", "",
                  "Only the instances whose benign render the victim classified as their class:", "",
                  to_markdown(t1_correct)]
    if pairs:
        lines += ["### Table 1 by source and target class", "",
                  "Every attack of Table 1 counted per class pair (bold: a pair with a failed attack), so that a "
                  "shortfall can be traced to the pairs it comes from; the paper reports only the pooled cases.",
                  "", pair_success_markdown(pairs)]
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
    text = "\n".join(lines) + "".join("\n" + section for section in extra)
    write_text_atomic(out.out_dir / "README.md", text)
